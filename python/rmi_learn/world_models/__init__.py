"""World models of the paper (Sec. IV): Baseline (and the setpoint readout), State-GRU-WM,
AC-GRU-WM, Linear-ARX, AC-MLP-WM and the causal Transformer W_T, with one interface (see
:mod:`.common`).

``build(config)`` makes a model from its JSON config; ``load(out_dir)`` rebuilds a trained
model from a run directory written by ``rmi train-wm`` (``config.json`` +
``model.safetensors``; no pickles) and returns ``(model, config)`` in eval mode. Training
is :mod:`.training` (``rmi train-wm``; its settings, which import no torch, are
:mod:`.training_settings`), evaluation :mod:`.evaluation` (``rmi eval-wm``) at the horizons
of :mod:`.horizons`, and the paper's findings checked on its records :mod:`.findings`
(no torch either).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rmi_learn.world_models.arx import LinearARX
    from rmi_learn.world_models.baseline import BaselineWM, SetpointReadoutWM
    from rmi_learn.world_models.common import WorldModel, wm_loss
    from rmi_learn.world_models.gru import ACGRUWM, StateGRUWM
    from rmi_learn.world_models.mlp import ACMLPWM
    from rmi_learn.world_models.registry import DISPLAY_NAMES, MODELS, build, load
    from rmi_learn.world_models.transformer import TransformerWM

#: Public name -> submodule. Loaded on first use, so that importing a light submodule (the
#: training settings the ``rmi`` command line reads) does not import torch.
_SOURCES = {
    "LinearARX": "arx",
    "BaselineWM": "baseline",
    "SetpointReadoutWM": "baseline",
    "WorldModel": "common",
    "wm_loss": "common",
    "ACGRUWM": "gru",
    "StateGRUWM": "gru",
    "ACMLPWM": "mlp",
    "TransformerWM": "transformer",
    "DISPLAY_NAMES": "registry",
    "MODELS": "registry",
    "build": "registry",
    "load": "registry",
}

__all__ = [
    "ACGRUWM",
    "ACMLPWM",
    "DISPLAY_NAMES",
    "MODELS",
    "BaselineWM",
    "LinearARX",
    "SetpointReadoutWM",
    "StateGRUWM",
    "TransformerWM",
    "WorldModel",
    "build",
    "load",
    "wm_loss",
]


def __getattr__(name: str) -> Any:
    if name not in _SOURCES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_SOURCES[name]}"), name)
