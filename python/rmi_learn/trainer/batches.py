"""The batches of an epoch: its data order, fixed by (seed, epoch) so that a resume replays
it (:func:`epoch_order`), and one batch of a data set moved to the device
(:func:`fetch_batch`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch.utils.data import default_collate


def epoch_order(n: int, seed: int, epoch: int) -> np.ndarray:
    """Data order of one epoch: a permutation fixed by (seed, epoch), so resumes replay it."""
    g = np.random.default_rng([seed, epoch, 0x5EED])
    return g.permutation(n)


def fetch_batch(
    data: Any, indices: np.ndarray, device: str | torch.device = "cpu"
) -> dict[str, Any]:
    """Batch ``indices`` of ``data``: ``data.batch(indices)`` if it exists, else ``data[i]``
    collated with torch's default collate; tensors are moved to ``device``."""
    if hasattr(data, "batch"):
        batch = data.batch(indices)
    else:
        batch = default_collate([data[int(i)] for i in indices])
    return {
        k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v)
        for k, v in batch.items()
    }
