"""Model weights: their count (:func:`count_parameters`), a CPU copy of a model's tensors and
the safetensors files of a run directory (:func:`save_weights`, :func:`load_weights`)."""

from __future__ import annotations

import os
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from rmi_learn.errors import InputError
from rmi_learn.trainer.run_files import CONFIG_FILE


def count_parameters(model: torch.nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def state_tensors(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """A CPU copy of the tensors of ``model``'s state dict (for checkpoints and weight files)."""
    return {k: v.detach().cpu().clone().contiguous() for k, v in model.state_dict().items()}


def save_weights(tensors: dict[str, torch.Tensor], path: str | Path) -> None:
    """Write a dict of tensors as safetensors (atomically: a temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    save_file({k: v.detach().cpu().clone().contiguous() for k, v in tensors.items()}, str(tmp))
    os.replace(tmp, path)


def load_weights(
    model: torch.nn.Module, out_dir: str | Path, which: str = "model", strict: bool = True
) -> torch.nn.Module:
    """Load ``out_dir/<which>.safetensors`` (``model``: the selected weights, ``last``: the
    latest, ``model.ema``: EMA weights) into ``model`` and return it."""
    path = Path(out_dir) / f"{which}.safetensors"
    try:
        tensors = load_file(str(path))
    except SafetensorError as exc:
        raise InputError(f"{path}: damaged weights file ({exc}); train the run again") from exc
    try:
        model.load_state_dict(tensors, strict=strict)
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        raise InputError(f"{path}: weights do not fit the model of {CONFIG_FILE}: {first}") from exc
    return model
