"""The sensors mode's view of a dataset: the channels a gripper reads, their noise and
latency, the dry mass, and datasets built without them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from rmi_learn.data.dataset import Dataset, load_dataset
from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS
from rmi_learn.errors import InputError
from rmi_learn.sensing import SENSOR_NAMES, SensorModel


def _raw(view_hist: np.ndarray, ds: Dataset, model: SensorModel) -> np.ndarray:
    v = ds.sensor_view(model)
    return view_hist * v.std + v.mean


def test_noiseless_sensor_windows_read_the_recorded_channels_and_the_dry_mass(
    synthetic_dataset_dir: Path,
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    model = SensorModel.noiseless(0)
    ws = ds.windows("train", observation_mode="sensors", sensors=model)
    assert ws.observation_mode == "sensors" and len(ws) > 0
    idx = np.linspace(0, len(ws) - 1, 7).round().astype(np.int64)
    b = ws.numpy(idx)
    assert b["hist"].shape == (7, 16, len(SENSOR_INPUTS)) and np.all(b["hist_mask"] == 1.0)
    raw = _raw(b["hist"].astype(np.float64), ds, model)
    rows = ws.anchors[idx][:, None] + np.arange(-15, 1)
    for name in SENSOR_NAMES:
        truth = ds.frames[name].to_numpy()[rows]
        np.testing.assert_allclose(raw[..., SENSOR_INPUTS.index(name)], truth, atol=1e-4)
    dry = dict(zip(ds.runs["run"].to_list(), ds.runs["m_dry"].to_list(), strict=True))
    want = np.array([dry[r] for r in ds.row_run[ws.anchors[idx]]])
    np.testing.assert_allclose(raw[:, -1, SENSOR_INPUTS.index("m_dry")], want, rtol=1e-5)
    # The targets stay y_t's: the same as the privileged windows'.
    p = ds.windows("train").numpy(idx)
    for key in ("target", "actions", "z_now", "water_now"):
        np.testing.assert_array_equal(b[key], p[key])


def test_sensor_noise_is_seeded_and_the_latency_delays_each_segment(
    synthetic_dataset_dir: Path,
) -> None:
    ds, again = load_dataset(synthetic_dataset_dir), load_dataset(synthetic_dataset_dir)
    noisy = SensorModel(seed=3)
    a, b = ds.sensor_view(noisy).values, again.sensor_view(noisy).values
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, ds.sensor_view(SensorModel(seed=4)).values)
    late = ds.sensor_view(SensorModel.noiseless(2)).values
    true = ds.frames.select(SENSOR_NAMES).to_numpy()
    seg = ds.frames["segment"].to_numpy()
    first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    a0, a1 = first[0], first[1]
    # (F_meas is the mean of the two pad loads as read: equal to the last bit or two.)
    c = len(SENSOR_NAMES)
    np.testing.assert_allclose(late[a0 + 2 : a1, :c], true[a0 : a1 - 2], rtol=1e-12, atol=0)
    np.testing.assert_allclose(late[a0 : a0 + 2, :c], true[[a0, a0]], rtol=1e-12, atol=0)
    # A new segment starts its own delay line.
    np.testing.assert_allclose(late[a1, :c], true[a1], rtol=1e-12, atol=0)


def test_anchor_phases_keep_the_windows_anchored_in_them(synthetic_dataset_dir: Path) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    every = ds.windows("test")
    squeeze = ds.windows("test", anchor_phases=("squeeze",))
    phase = ds.frames["phase"].to_numpy().astype(str)
    assert 0 < len(squeeze) < len(every)
    assert set(phase[squeeze.anchors]) == {"squeeze"}
    assert set(squeeze.anchors) <= set(every.anchors)


def test_a_dataset_built_without_the_wrist_load_is_refused_in_the_sensor_mode(
    synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    old = tmp_path / "old"
    shutil.copytree(synthetic_dataset_dir, old)
    frames = pl.read_parquet(old / "frames.parquet").drop("W_x", "W_y", "W_z")
    frames.write_parquet(old / "frames.parquet")
    ds = load_dataset(old)
    assert len(ds.windows("train")) > 0  # y_t's windows do not need them
    with pytest.raises(InputError, match=r"needs the dataset's W_x, W_y, W_z .* rebuild it"):
        ds.windows("train", observation_mode="sensors")
    with pytest.raises(InputError, match="observation_mode must be one of privileged, sensors"):
        ds.windows("train", observation_mode="camera")
