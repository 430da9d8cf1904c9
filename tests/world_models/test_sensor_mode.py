"""World models that read the gripper's sensors instead of y_t: the GRU models' estimate of
the state, the weight-estimate persistence they are compared with, their training and
evaluation, and the settings the mode refuses."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from rmi_learn.cli import main
from rmi_learn.data.dataset import load_dataset
from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS
from rmi_learn.errors import InputError
from rmi_learn.planning.scorers import can_score
from rmi_learn.sensing import STANDARD_GRAVITY, SensorModel
from rmi_learn.world_models import build, load
from rmi_learn.world_models.common import WATER
from rmi_learn.world_models.training import train
from rmi_learn.world_models.weight_persistence import WeightPersistenceWM

torch.set_num_threads(1)


def _sensor_batch(data: Path, n: int = 6, **kw: object) -> dict[str, torch.Tensor]:
    ws = load_dataset(data).windows("train", observation_mode="sensors", **kw)  # type: ignore[arg-type]
    return ws.batch(np.linspace(0, len(ws) - 1, n).round().astype(np.int64))


def test_a_sensor_mode_gru_estimates_the_state_and_forecasts_y_t(
    synthetic_dataset_dir: Path,
) -> None:
    torch.manual_seed(0)
    net = build({"kind": "ac-gru", "hidden": 16, "u_embed": 8, "observation_mode": "sensors"})
    assert net.n_inputs == len(SENSOR_INPUTS)
    b = _sensor_batch(synthetic_dataset_dir)
    out = net.predict(b["hist"], b["hist_mask"], b["actions"][:, :8])
    assert out["z"].shape == (6, 8, 18) and out["p_friction"].shape == (6, 8, 4)
    z0 = net.estimate_state(b["hist"], b["hist_mask"])
    assert z0.shape == (6, 18) and torch.isfinite(z0).all()
    # The differentiable loop and the inference rollout are the same equations.
    with torch.enable_grad():
        ref = net.forecast(b["hist"], b["hist_mask"], b["actions"][:, :8])["z"]
    torch.testing.assert_close(out["z"], ref.detach(), rtol=1e-5, atol=1e-5)
    # Its config rebuilds it: the same weights give the same forecast.
    again = build(net.config())
    again.load_state_dict(net.state_dict())
    torch.testing.assert_close(again.predict(b["hist"], b["hist_mask"], b["actions"][:, :8])["z"],
                               out["z"])  # fmt: skip


def test_the_estimate_of_the_water_starts_from_the_wrist_load_s_weight(
    synthetic_dataset_dir: Path,
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    model = SensorModel.noiseless(0)
    view = ds.sensor_view(model)
    wz, dry = SENSOR_INPUTS.index("W_z"), SENSOR_INPUTS.index("m_dry")
    water_mean, water_std = float(ds.stats.z_mean[WATER]), float(ds.stats.z_std[WATER])
    reading = [view.mean[wz], view.std[wz], view.mean[dry], view.std[dry], water_mean, water_std]
    net = build({"kind": "ac-gru", "hidden": 16, "u_embed": 8, "observation_mode": "sensors",
                 "weight_reading": [float(v) for v in reading]})  # fmt: skip
    with torch.no_grad():  # an estimate head that adds nothing
        net.estimate.weight.zero_()
        net.estimate.bias.zero_()
    ws = ds.windows("train", observation_mode="sensors", sensors=model, anchor_phases=("squeeze",))
    idx = np.arange(min(len(ws), 16))
    b = ws.batch(idx)
    rows = ws.anchors[idx][:, None] + np.arange(-15, 1)
    w_z = ds.frames["W_z"].to_numpy()[rows].mean(axis=1)
    m_dry = view.values[ws.anchors[idx], dry]
    want = (-w_z / STANDARD_GRAVITY - m_dry - water_mean) / water_std
    z0 = net.estimate_state(b["hist"], b["hist_mask"]).detach()
    np.testing.assert_allclose(z0[:, WATER].numpy(), want, rtol=1e-4, atol=1e-4)
    assert torch.all(z0[:, [i for i in range(18) if i != WATER]] == 0)
    assert build(net.config()).weight_reading == net.weight_reading
    for bad in ([1.0, 0.0, 1.0, 1.0, 1.0, 1.0], [1.0] * 5, [float("nan")] * 6, "x"):
        with pytest.raises(ValueError, match="weight_reading must be six finite numbers"):
            build({"kind": "ac-gru", "observation_mode": "sensors", "weight_reading": bad})
    with pytest.raises(ValueError, match="weight_reading applies to observation_mode 'sensors'"):
        build({"kind": "ac-gru", "weight_reading": reading})


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"model": "arx"}, "observation_mode 'sensors' is taken by ac-gru, state-gru, not arx"),
        ({"model": "transformer"}, "not transformer"),
        ({"model": "ac-gru", "state_groups": "LS"}, "state_groups must be ALL"),
    ],
)
def test_the_sensor_mode_refuses_models_and_groups_that_read_y_t(
    tmp_path: Path, synthetic_dataset_dir: Path, kwargs: dict[str, str], says: str
) -> None:
    model = kwargs.pop("model")
    with pytest.raises(InputError, match=says):
        train(model, synthetic_dataset_dir, tmp_path / "out", observation_mode="sensors",
              progress=False, **kwargs)  # type: ignore[arg-type]  # fmt: skip
    assert not (tmp_path / "out").exists()
    with pytest.raises(InputError, match="sensors applies to observation_mode 'sensors' only"):
        train("ac-gru", synthetic_dataset_dir, tmp_path / "out", sensors=SensorModel(),
              progress=False)  # fmt: skip


def test_the_weight_persistence_reads_the_water_off_the_wrist_load(
    synthetic_dataset_dir: Path,
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    model = SensorModel.noiseless(0)
    weight = WeightPersistenceWM.from_dataset(ds, model)
    ws = ds.windows("train", observation_mode="sensors", sensors=model, anchor_phases=("squeeze",))
    idx = np.arange(min(len(ws), 32))
    b = ws.batch(idx)
    rows = ws.anchors[idx][:, None] + np.arange(-15, 1)
    w_z = ds.frames["W_z"].to_numpy()[rows].mean(axis=1)
    dry = dict(zip(ds.runs["run"].to_list(), ds.runs["m_dry"].to_list(), strict=True))
    m_dry = np.array([dry[r] for r in ds.row_run[ws.anchors[idx]]])
    water = -w_z / STANDARD_GRAVITY - m_dry - weight.offset
    want = (water - ds.stats.z_mean[WATER]) / ds.stats.z_std[WATER]
    got = weight.predict(b["hist"], b["hist_mask"], b["actions"])["z"]
    np.testing.assert_allclose(got[:, 0, WATER].numpy(), want, rtol=1e-4, atol=1e-4)
    assert torch.equal(got[:, 0], got[:, -1])  # persisted over the horizon


def test_train_and_eval_in_the_sensor_mode_from_the_command_line(
    tmp_path: Path, synthetic_dataset_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "ac-gru-sensors"
    sensors = '{"wrist_N": 0.1, "latency_ticks": 2, "seed": 5}'
    argv = ["train-wm", "--model", "ac-gru", "--data", str(synthetic_dataset_dir), "--out",
            str(run), "--observation-mode", "sensors", "--sensors", sensors, "--debug",
            "--no-progress", "--threads", "1"]  # fmt: skip
    assert main(argv) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["model"]["observation_mode"] == "sensors"
    assert cfg["extra"]["sensors"]["wrist_N"] == 0.1
    assert cfg["extra"]["sensors"]["latency_ticks"] == 2
    assert cfg["extra"]["sensor_stats"]["names"] == list(SENSOR_INPUTS)
    assert len(cfg["model"]["weight_reading"]) == 6
    model, _ = load(run)
    assert model.observation_mode == "sensors"
    # The planners score chunks from y_t histories: they refuse it by name.
    with pytest.raises(InputError, match="reads observation_mode 'sensors'; this takes"):
        load(run, observation_mode="privileged")
    assert "reads the sensors" in str(can_score(model, 32))
    # A resume with another sensor model is refused by name.
    other = [*argv[:-6], "--sensors", '{"wrist_N": 0.2}', "--debug", "--resume", "--no-progress"]
    capsys.readouterr()
    assert main(other) == 2
    assert "sensors" in capsys.readouterr().err
    out = tmp_path / "tables"
    assert main(["eval-wm", "--runs", str(run), "--data", str(synthetic_dataset_dir), "--out",
                 str(out), "--no-latency", "--max-windows", "64"]) == 0  # fmt: skip
    table = (out / "table_sensors.md").read_text()
    for row in ("Baseline (y_t)", "Weight estimate (sensors)", "AC-GRU-WM (sensors)"):
        assert f"| {row} |" in table
    rows = json.loads((out / "table_sensors.json").read_text())["rows"]
    assert {r["size_cm"] for r in rows} == {8, 10, 12}
    assert all(np.isfinite(r["water_now_mae_g"]) and np.isfinite(r["water_mae_g@32"]) for r in rows)
    assert all(r["water_now_mae_g"] == 0.0 for r in rows if r["method"] == "Baseline (y_t)")
    assert "| AC-GRU-WM (sensors) |" in (out / "table2.md").read_text()


def test_validation_can_be_kept_to_the_squeeze(tmp_path: Path, synthetic_dataset_dir: Path) -> None:
    run = tmp_path / "squeeze"
    train("ac-gru", synthetic_dataset_dir, run, observation_mode="sensors",
          val_phases=("squeeze",), epochs=1, progress=False)  # fmt: skip
    extra = json.loads((run / "config.json").read_text())["extra"]
    ds = load_dataset(synthetic_dataset_dir)
    want = len(ds.windows("val", anchor_phases=("squeeze",)))
    assert extra["val_phases"] == ["squeeze"] and extra["n_val"] == want
    assert 0 < want < len(ds.windows("val"))
    with pytest.raises(InputError, match="cannot resume .*val_phases"):
        train("ac-gru", synthetic_dataset_dir, run, observation_mode="sensors", epochs=1,
              resume=True, progress=False)  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--observation-mode", "camera"], "--observation-mode: invalid choice: 'camera'"),
        (["--sensors", '{"wrist_N": -1}'], r"sensors.wrist_N must be in \[0, 10.0\]"),
        (["--sensors", '{"latency_ticks": 99}'], "sensors.latency_ticks must be an integer"),
        (["--sensors", '{"lag": 1}'], "sensors has unknown field 'lag'"),
        (["--sensors", "{"], "not a JSON object"),
        (["--val-phases", "done"], "--val-phases: invalid choice: 'done'"),
    ],
)
def test_bad_sensor_options_are_one_line_and_status_2(
    tmp_path: Path,
    synthetic_dataset_dir: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    says: str,
) -> None:
    argv = ["train-wm", "--model", "ac-gru", "--data", str(synthetic_dataset_dir), "--out",
            str(tmp_path / "out"), "--debug", *extra]  # fmt: skip
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert re.search(says, capsys.readouterr().err.splitlines()[-1])
    assert not (tmp_path / "out").exists()
