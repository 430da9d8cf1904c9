"""World-model training: the forecast horizon of the training windows (``--horizon``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from rmi_learn.errors import InputError
from rmi_learn.world_models import load
from rmi_learn.world_models.training import train

torch.set_num_threads(1)


def test_a_32_step_lookahead_model_learns_from_32_step_windows(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    out = tmp_path / "arx"
    summary = train("arx", synthetic_dataset_dir, out, model_args={"horizon": 32},
                    progress=False)  # fmt: skip
    assert summary["select_metric"] == "val_water_mae_g@32"
    assert math.isfinite(summary["best_metric"])
    model, cfg = load(out)
    assert cfg["extra"]["horizon"] == 32 and model.fixed_horizon == 32
    # More windows fit a run at 32 steps than at 64.
    default = train("arx", synthetic_dataset_dir, tmp_path / "arx64", progress=False)
    assert default["select_metric"] == "val_water_mae_g@64"
    n64 = json.loads((tmp_path / "arx64" / "config.json").read_text())["extra"]["n_train"]
    assert cfg["extra"]["n_train"] > n64


def test_a_recurrent_model_trains_on_the_horizon_asked_for(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    out = tmp_path / "gru"
    summary = train("ac-gru", synthetic_dataset_dir, out, horizon=16, epochs=1, debug=True,
                    progress=False, model_args={"hidden": 8, "layers": 1})  # fmt: skip
    assert summary["select_metric"] == "val_water_mae_g@16"
    assert json.loads((out / "config.json").read_text())["extra"]["horizon"] == 16


def test_a_horizon_other_than_a_lookahead_models_own_is_refused(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    with pytest.raises((InputError, ValueError), match="fixed horizon 32"):
        train("arx", synthetic_dataset_dir, tmp_path / "x", model_args={"horizon": 32},
              horizon=16, debug=True, progress=False)  # fmt: skip
    assert not (tmp_path / "x").exists()
