"""A built dataset opened for learning: its tables, statistics and its (history, chunk,
future) windows."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.dataset.builder import FORMAT_VERSION
from rmi_learn.data.dataset.frames import WATER_INDEX
from rmi_learn.data.dataset.sensor_view import SensorView, sensor_view
from rmi_learn.data.dataset.split import SPLITS
from rmi_learn.data.dataset.stats import read_stats
from rmi_learn.data.schema import (
    CONTINUOUS_INDEX,
    CONTROL_ACTIONS,
    FRICTION_SLICE,
    HISTORY,
    HORIZON,
    OBS,
)
from rmi_learn.errors import InputError
from rmi_learn.sensing import SensorModel, check_observation_mode

try:  # torch is in the `learn` extra; a dataset opens without it; its windows need it.
    import torch
    from torch.utils.data import Dataset as _TorchDataset
except ImportError:  # pragma: no cover - exercised only without torch
    torch = None  # type: ignore[assignment]
    _TorchDataset = object  # type: ignore[assignment,misc]


def read_table(path: Path, columns: Sequence[str]) -> pl.DataFrame:
    """A table of a built dataset; a damaged file (a copy cut short, a full disk) or one
    without ``columns`` raises :class:`~rmi_learn.errors.InputError` naming it."""
    try:
        df = pl.read_parquet(path)
    except pl.exceptions.PolarsError as exc:
        raise InputError(
            f"{path}: damaged dataset file ({exc}); rebuild it with rmi dataset build"
        ) from exc
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{path}: dataset file lacks column(s) {missing}; rebuild it")
    return df


class Dataset:
    """A built dataset (see :func:`load_dataset`).

    Attributes: ``root``; ``runs`` (polars table, one row per run: ``run`` number,
    ``run_id``, parameters, ``split``, ``n_rows``); ``frames`` (polars table of the kept
    rows, raw SI values); ``stats`` (:class:`Stats`); ``info`` (dataset.json).
    """

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)
        info_path = self.root / "dataset.json"
        if not info_path.exists():
            raise FileNotFoundError(f"{self.root} is not a built dataset (no dataset.json)")
        self.info: dict[str, Any] = json.loads(info_path.read_text())
        if not isinstance(self.info, dict) or self.info.get("format") != FORMAT_VERSION:
            got = self.info.get("format") if isinstance(self.info, dict) else self.info
            raise ValueError(f"{info_path}: dataset format {got!r} != {FORMAT_VERSION}")
        self.stats = read_stats(self.root / "stats.json")
        self.runs = read_table(self.root / "runs.parquet", ("run", "run_id", "split"))
        self.frames = read_table(
            self.root / "frames.parquet", ("run", "t", "segment", "phase", *OBS)
        )
        f = self.frames
        self.run_ids: list[str] = self.runs.sort("run")["run_id"].to_list()
        self.row_run = f["run"].to_numpy().astype(np.int64)
        self.row_t = f["t"].to_numpy().astype(np.int64)
        self.row_phase = f["phase"].to_numpy().astype(str)
        seg = f["segment"].to_numpy()
        n = f.height
        # First and last global row of each row's segment (segments are contiguous rows).
        starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
        ends = np.r_[starts[1:] - 1, n - 1]
        seg_idx = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, n]))
        self.seg_first = starts[seg_idx]
        self.seg_last = ends[seg_idx]

        y = f.select(OBS).to_numpy().astype(np.float64)
        u = f.select(CONTROL_ACTIONS).to_numpy().astype(np.float64)
        mask = np.isfinite(y)
        ys = y.copy()
        ci = list(CONTINUOUS_INDEX)
        ys[:, ci] = self.stats.standardise_z(y[:, ci])
        ys[~mask] = 0.0
        self.y_std = ys.astype(np.float32)  # (N, 23)
        self.y_mask = mask.astype(np.float32)  # (N, 23)
        self.u_std = self.stats.standardise_u(u).astype(np.float32)  # (N, 1)
        self.z_std = self.y_std[:, ci]  # (N, 18)
        self.z_mask = self.y_mask[:, ci]
        self.c = y[:, OBS.index("c")].astype(np.float32)
        onehot = y[:, FRICTION_SLICE]
        self.r_class = np.argmax(onehot, axis=1).astype(np.int64)
        self._sensor_views: dict[SensorModel, SensorView] = {}

    def sensor_view(self, model: SensorModel | None = None) -> SensorView:
        """The frames as the ``sensors`` observation mode shows them under ``model``
        (default: :class:`~rmi_learn.sensing.SensorModel`'s defaults), standardised on the
        training runs; computed once per model."""
        model = SensorModel() if model is None else model
        if model not in self._sensor_views:
            train = self.split_runs("train")
            self._sensor_views[model] = sensor_view(self.root, self.frames, self.runs, train, model)
        return self._sensor_views[model]

    def split_runs(self, split: str | None = None, size_cm: int | None = None) -> np.ndarray:
        """Run numbers in ``split`` (``train``/``val``/``test``, or None for all), optionally
        of one sponge size (cm)."""
        r = self.runs
        if split is not None:
            if split not in SPLITS:
                raise ValueError(f"split must be one of {SPLITS} or None, got {split!r}")
            r = r.filter(pl.col("split") == split)
        if size_cm is not None:
            r = r.filter(pl.col("size_cm") == size_cm)
        return r["run"].to_numpy().astype(np.int64)

    def windows(
        self,
        split: str | None,
        size_cm: int | None = None,
        history: int = HISTORY,
        horizon: int = HORIZON,
        observation_mode: str = "privileged",
        sensors: SensorModel | None = None,
        anchor_phases: Sequence[str] | None = None,
    ) -> WindowSet:
        """All stride-1 windows of ``split`` (and ``size_cm``): anchor rows t with history
        rows t-L+1..t and future rows t+1..t+H in one contiguous segment of one run. Their
        history is y_t (``observation_mode="privileged"``) or what the sensors report
        (``"sensors"``, under ``sensors``: :meth:`sensor_view`); the targets are y_t's in
        either mode. ``anchor_phases`` keeps the windows whose anchor row is in one of
        those phases (e.g. ``("squeeze",)``)."""
        if history < 1 or horizon < 1:
            raise ValueError("history and horizon must be positive")
        check_observation_mode(observation_mode)
        view = self.sensor_view(sensors) if observation_mode == "sensors" else None
        runs = self.split_runs(split, size_cm)
        gidx = np.arange(self.row_run.size)
        ok = (
            np.isin(self.row_run, runs)
            & (gidx - history + 1 >= self.seg_first)
            & (gidx + horizon <= self.seg_last)
        )
        if anchor_phases is not None:
            ok &= np.isin(self.row_phase, list(anchor_phases))
        return WindowSet(self, np.flatnonzero(ok), history, horizon, view)


class WindowSet(_TorchDataset):  # type: ignore[type-arg]
    """Windows of a :class:`Dataset` as a map-style ``torch.utils.data.Dataset``.

    ``ws[i]`` and ``ws.batch(indices)`` return dicts of tensors (``batch`` adds a leading N):
    ``hist`` (L, 23) float32: y standardised on continuous channels, c and r_* raw 0/1,
    invalid -> 0; ``hist_mask`` (L, 23) 1 where the raw value was finite; ``actions``
    (H, 1) standardised F_target at t..t+H-1; ``target`` (H, 18) standardised z at t+1..t+H,
    invalid -> 0; ``target_mask`` (H, 18); ``target_c`` (H,) 0/1; ``target_r`` (H,) int64
    friction class 0..3 (none, stick, slip, mixed); ``water_now`` () standardised M_L at t;
    ``z_now`` (18,) standardised z at t and ``z_now_mask`` (18,) its validity;
    ``run`` int64 run number (``run_ids[run]`` names it) and ``t`` int64 row index of the
    anchor within its run's kept rows. ``anchors`` holds the global frame rows of the anchors.
    With a :class:`SensorView` ``view`` (the ``sensors`` mode), ``hist`` is (L, C) of its
    standardised ``SENSOR_INPUTS`` and ``hist_mask`` (L, C) ones.
    """

    def __init__(
        self,
        data: Dataset,
        anchors: np.ndarray,
        history: int,
        horizon: int,
        view: SensorView | None = None,
    ):
        self.data = data
        self.observation_mode = "privileged" if view is None else "sensors"
        self.sensors = None if view is None else view.model
        if view is None:
            self._hist, self._hist_mask = data.y_std, data.y_mask
        else:
            self._hist = view.standardised
            self._hist_mask = np.ones_like(view.standardised)
        self.anchors = anchors.astype(np.int64)
        self.history = history
        self.horizon = horizon
        self.run_ids = data.run_ids
        self._hoff = np.arange(-history + 1, 1)
        self._aoff = np.arange(0, horizon)
        self._foff = np.arange(1, horizon + 1)

    def __len__(self) -> int:
        return int(self.anchors.size)

    def _arrays(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        d = self.data
        t = self.anchors[idx]
        h = t[:, None] + self._hoff
        a = t[:, None] + self._aoff
        fut = t[:, None] + self._foff
        return {
            "hist": self._hist[h],
            "hist_mask": self._hist_mask[h],
            "actions": d.u_std[a],
            "target": d.z_std[fut],
            "target_mask": d.z_mask[fut],
            "target_c": d.c[fut],
            "target_r": d.r_class[fut],
            "water_now": d.z_std[t, WATER_INDEX],
            "z_now": d.z_std[t],
            "z_now_mask": d.z_mask[t],
            "run": d.row_run[t],
            "t": d.row_t[t],
        }

    def batch(self, indices: Sequence[int] | np.ndarray) -> dict[str, Any]:
        """Windows ``indices`` stacked along a leading axis, as torch tensors."""
        if torch is None:  # pragma: no cover
            raise ImportError("WindowSet needs torch (install the `learn` extra)")
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1:
            raise ValueError("indices must be one-dimensional")
        if idx.size and (idx.min() < -len(self) or idx.max() >= len(self)):
            raise IndexError("window index out of range")
        return {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in self._arrays(idx).items()}

    def __getitem__(self, i: int) -> dict[str, Any]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"window {i} out of range ({len(self)})")
        return {k: v[0] for k, v in self.batch([i]).items()}

    def numpy(self, indices: Sequence[int] | np.ndarray) -> dict[str, np.ndarray]:
        """Like :meth:`batch` but numpy arrays (no torch needed)."""
        return self._arrays(np.asarray(indices, dtype=np.int64))


def load_dataset(out_dir: str | os.PathLike[str]) -> Dataset:
    """Open a dataset built by :func:`build_dataset`."""
    return Dataset(out_dir)


def describe(out_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Summary of a built dataset: build facts, per-split and per-size run, row and window
    counts (L = 16, H = 64)."""
    ds = load_dataset(out_dir)
    table: dict[str, Any] = {}
    for split in SPLITS:
        for size in sorted(ds.runs["size_cm"].unique().to_list()):
            runs = ds.split_runs(split, size)
            table[f"{split}/{size}cm"] = {
                "runs": int(runs.size),
                "rows": int(np.isin(ds.row_run, runs).sum()),
                "windows": len(ds.windows(split, size)),
            }
    return {"info": ds.info, "by_split_and_size": table, "stats": ds.stats.to_json()}
