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


def test_a_learned_model_predicts_changes_in_units_of_the_training_windows_step_change(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    """The unit of each channel's predicted change is the step-to-step RMS change of the
    training windows; it is recorded in config.json and the loaded model applies it. The
    closed-form models keep none."""
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.world_models.common import step_scale
    from rmi_learn.world_models.training import debug_subset
    from rmi_learn.world_models.training_settings import DEBUG_TRAIN_WINDOWS

    out = tmp_path / "gru"
    train("ac-gru", synthetic_dataset_dir, out, epochs=1, debug=True, progress=False,
          model_args={"hidden": 8, "layers": 1})  # fmt: skip
    ws = debug_subset(load_dataset(synthetic_dataset_dir).windows("train"), DEBUG_TRAIN_WINDOWS, 0)
    expect = step_scale(ws)
    recorded = json.loads((out / "config.json").read_text())["model"]["delta_scale"]
    assert recorded == [float(v) for v in expect]
    model, _ = load(out)
    assert torch.equal(model.delta_scale, expect)
    train("arx", synthetic_dataset_dir, tmp_path / "arx", debug=True, progress=False)
    assert "delta_scale" not in json.loads((tmp_path / "arx" / "config.json").read_text())["model"]


def test_a_run_trained_without_a_delta_scale_loads_as_it_was_and_is_not_resumed(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    out = tmp_path / "gru"
    train("ac-gru", synthetic_dataset_dir, out, epochs=1, debug=True, progress=False,
          model_args={"hidden": 8, "layers": 1})  # fmt: skip
    cfg_path = out / "config.json"
    cfg = json.loads(cfg_path.read_text())
    del cfg["model"]["delta_scale"]  # as written before the unit of change existed
    cfg_path.write_text(json.dumps(cfg))
    model, _ = load(out)
    assert torch.equal(model.delta_scale, torch.ones(18))
    with pytest.raises(InputError, match="cannot resume .*the model configuration differs"):
        train("ac-gru", synthetic_dataset_dir, out, epochs=1, debug=True, progress=False,
              resume=True, model_args={"hidden": 8, "layers": 1})  # fmt: skip
