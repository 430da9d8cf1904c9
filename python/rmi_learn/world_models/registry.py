"""The world models by name: :data:`MODELS`, :func:`build` and :func:`load`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rmi_learn.errors import InputError
from rmi_learn.trainer import CONFIG_FILE, load_weights, read_config
from rmi_learn.world_models.arx import LinearARX
from rmi_learn.world_models.baseline import BaselineWM, SetpointReadoutWM
from rmi_learn.world_models.common import WorldModel
from rmi_learn.world_models.gru import ACGRUWM, StateGRUWM
from rmi_learn.world_models.mlp import ACMLPWM
from rmi_learn.world_models.transformer import TransformerWM

#: CLI name -> class
MODELS: dict[str, type[WorldModel]] = {
    "baseline": BaselineWM,
    "setpoint-readout": SetpointReadoutWM,
    "state-gru": StateGRUWM,
    "ac-gru": ACGRUWM,
    "arx": LinearARX,
    "ac-mlp": ACMLPWM,
    "transformer": TransformerWM,
}

#: The models that can read the ``sensors`` observation mode instead of y_t.
SENSOR_MODEL_KINDS: tuple[str, ...] = tuple(sorted(k for k, c in MODELS.items() if c.takes_sensors))

#: Names used in the paper's tables.
DISPLAY_NAMES: dict[str, str] = {
    "baseline": "Baseline",
    "setpoint-readout": "Setpoint readout",
    "state-gru": "State-GRU-WM",
    "ac-gru": "AC-GRU-WM",
    "arx": "Linear-ARX",
    "ac-mlp": "AC-MLP-WM",
    "transformer": "Transformer W_T",
}


def build(config: dict[str, Any]) -> WorldModel:
    """A fresh model from ``{"kind": ..., **constructor arguments}`` and, for a trained
    model, its ``delta_scale`` (:meth:`WorldModel.set_delta_scale`); ValueError naming an
    argument of the wrong kind or out of range (see :meth:`WorldModel.check_arguments`)."""
    cfg = dict(config)
    kind = cfg.pop("kind")
    if kind not in MODELS:
        raise ValueError(f"unknown world model {kind!r}; known: {sorted(MODELS)}")
    delta_scale = cfg.pop("delta_scale", None)
    MODELS[kind].check_arguments(cfg)
    model = MODELS[kind](**cfg)
    if delta_scale is not None:
        model.set_delta_scale(delta_scale)
    return model


def load(
    out_dir: str | Path, which: str = "model", observation_mode: str | None = None
) -> tuple[WorldModel, dict[str, Any]]:
    """Load a trained world model from a ``rmi train-wm`` output directory.

    Returns ``(model, config)``: the model in eval mode with the selected weights
    (``which="last"`` for the latest), and the run's config.json (``config["model"]`` is the
    architecture, ``config["extra"]["stats"]`` the standardisation statistics of the data
    it was trained on: z_mean, z_std (18, SI units), u_mean, u_std (2,)). Inputs to the model
    are standardised exactly like ``rmi_learn.data.dataset`` windows. With
    ``observation_mode``, a model that reads the other mode is an
    :class:`~rmi_learn.errors.InputError` (the planners score chunks from y_t histories).
    """
    config = read_config(out_dir)
    try:
        model = build(config["model"])
    except (KeyError, TypeError, ValueError) as exc:
        # The architecture comes from a file: a field the constructor refuses is bad input.
        raise InputError(f"{Path(out_dir) / CONFIG_FILE}: cannot build its model: {exc}") from exc
    if observation_mode is not None and model.observation_mode != observation_mode:
        raise InputError(
            f"{out_dir}: the world model reads observation_mode {model.observation_mode!r}; "
            f"this takes a model trained with observation_mode {observation_mode!r}"
        )
    load_weights(model, out_dir, which)
    model.eval()
    return model, config
