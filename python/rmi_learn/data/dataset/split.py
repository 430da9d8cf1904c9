"""The grouped train/validation/test split of runs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import polars as pl

SPLITS: tuple[str, ...] = ("train", "val", "test")
FRACTIONS = (0.7, 0.1, 0.2)


def grouped_split(params: pl.DataFrame, seed: int = 0) -> list[str]:
    """Assign each run (row of ``params``, with ``size_cm, porosity, F_hold``) to
    ``train``/``val``/``test`` so that runs sharing (size, porosity, F_hold) stay together and
    groups split 70/10/20 within each size (see the module docstring). Deterministic in
    ``seed``; independent of row order."""
    out = ["train"] * params.height
    sizes = params["size_cm"].to_list()
    keys = list(zip(sizes, params["porosity"].to_list(), params["F_hold"].to_list(), strict=True))
    for size in sorted(set(sizes)):
        groups = sorted({kk for kk in keys if kk[0] == size})
        n = len(groups)
        n_val = math.floor(FRACTIONS[1] * n + 0.5)
        n_test = math.floor(FRACTIONS[2] * n + 0.5)
        if n >= 3:
            n_val, n_test = max(n_val, 1), max(n_test, 1)
        elif n == 2:
            n_val, n_test = 0, 1
        else:
            n_val, n_test = 0, 0
        rng = np.random.default_rng([int(seed), int(size)])
        perm = rng.permutation(n)
        assign: dict[tuple[Any, ...], str] = {}
        for rank, gi in enumerate(perm):
            assign[groups[gi]] = (
                "val" if rank < n_val else "test" if rank < n_val + n_test else "train"
            )
        for i, kk in enumerate(keys):
            if kk[0] == size:
                out[i] = assign[kk]
    return out
