"""The resumable checkpoint of a run (``train_state.pt``): model, optimiser and scheduler
state, progress counters, random-number state and hook state, written atomically together
with the latest weights (``last.safetensors``)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from rmi_learn.trainer.config import TrainState
from rmi_learn.trainer.determinism import rng_state, set_rng_state
from rmi_learn.trainer.hooks import Hook
from rmi_learn.trainer.run_files import LAST_WEIGHTS, STATE_FILE
from rmi_learn.trainer.weights import save_weights, state_tensors


def save_checkpoint(
    out_dir: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    state: TrainState,
    hooks: Sequence[Hook],
) -> None:
    """Write ``out_dir/train_state.pt`` (then ``last.safetensors``)."""
    ckpt = {
        "model": state_tensors(model),
        "optimizer": optimizer.state_dict(),
        "scheduler": scheduler.state_dict(),
        "state": dataclasses.asdict(state),
        "rng": rng_state(),
        "hooks": {h.name: h.state_dict() for h in hooks},
    }
    tmp = out_dir / (STATE_FILE + ".tmp")
    torch.save(ckpt, tmp)
    os.replace(tmp, out_dir / STATE_FILE)
    save_weights(ckpt["model"], out_dir / LAST_WEIGHTS)


def load_checkpoint(
    out_dir: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    hooks: Sequence[Hook],
) -> tuple[TrainState, dict[str, Any]]:
    """Restore ``model``, ``optimizer``, ``scheduler``, ``hooks`` and the random-number
    state from ``out_dir/train_state.pt``; returns the progress counters and the saved
    random-number state (loaded with ``weights_only=True``)."""
    ckpt = torch.load(out_dir / STATE_FILE, map_location="cpu", weights_only=True)
    model.load_state_dict(ckpt["model"])
    optimizer.load_state_dict(ckpt["optimizer"])
    scheduler.load_state_dict(ckpt["scheduler"])
    state = TrainState(**ckpt["state"])
    for h in hooks:
        if h.name in ckpt["hooks"]:
            h.load_state_dict(ckpt["hooks"][h.name])
    set_rng_state(ckpt["rng"])
    rng: dict[str, Any] = ckpt["rng"]
    return state, rng
