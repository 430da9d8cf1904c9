"""The settings of world-model training (``rmi train-wm``): the models and state groups it
knows, the per-model optimisation defaults, the settings a resume must repeat (and their
values in runs that predate them), the loss scales, the debug subsets and the validation
metric that selects the weights. Imports no torch: the command line reads it to build its
options."""

from __future__ import annotations

from typing import Any

from rmi_learn.world_models.horizons import HORIZON_STEPS

MODEL_CHOICES = ("baseline", "state-gru", "ac-gru", "arx", "ac-mlp", "transformer")
GROUP_CHOICES = ("LS", "LS+G", "LS+G+C", "ALL")

#: Optimisation defaults of the GRU and MLP models (paper Sec. IV, supplement S3), with the
#: change-scaled loss (see ``--loss-scale``).
_GRU_MLP_DEFAULTS: dict[str, Any] = {
    "lr": 1e-3,
    "optimizer": "adam",
    "select": "val_water_mae_g@64",
    "loss_scale": "change",
}


#: Per-model optimisation defaults (paper Sec. IV, supplement S3).
DEFAULTS: dict[str, dict[str, Any]] = {
    "state-gru": _GRU_MLP_DEFAULTS,
    "ac-gru": _GRU_MLP_DEFAULTS,
    "ac-mlp": _GRU_MLP_DEFAULTS,
    "transformer": {
        "lr": 3e-4,
        "optimizer": "adamw",
        "weight_decay": 1e-2,
        "select": "val_water_mae_g_mean",
        "water_weight": 8.0,
    },
}
#: Settings of a run that ``--resume`` must repeat (they shape the data or the loss).
RESUME_FIXED = (
    "size_cm",
    "state_groups",
    "shuffle_actions",
    "debug",
    "tf_epochs",
    "water_weight",
    "huber_delta",
    "loss_scale",
    "horizon",
    "observation_mode",
    "sensors",
    "val_phases",
)
#: Huber threshold of the loss in standardised units (torch's default).
HUBER_DELTA = 1.0
#: Values of those settings in runs written before they were recorded.
RESUME_LEGACY: dict[str, Any] = {
    "huber_delta": HUBER_DELTA,
    "loss_scale": "state",
    "horizon": 64,
    "observation_mode": "privileged",
    "sensors": None,
    "val_phases": None,
}
#: How the continuous channels' errors are scaled in the loss (see ``--loss-scale``).
LOSS_SCALES = ("state", "change")
#: Debug mode: windows kept from each split, batch size, teacher-forcing decay epochs.
DEBUG_TRAIN_WINDOWS = 256
DEBUG_VAL_WINDOWS = 32


def select_metric(metric: str, horizon: int) -> str:
    """The validation metric that selects the weights for windows of ``horizon`` steps: a
    water error at step 64 becomes the one at the largest reported step within the horizon
    (a 32-step lookahead model is chosen at 0.64 s)."""
    if not metric.startswith("val_water_mae_g@"):
        return metric
    step = max((s for s in HORIZON_STEPS if s <= horizon), default=HORIZON_STEPS[0])
    return f"val_water_mae_g@{step}"
