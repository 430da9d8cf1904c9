"""The learning dataset (paper Sec. V, S4): resampled frames, grouped split, statistics,
windows.

``build_dataset(run_dir, out_dir, seed=0)`` turns a directory of run files into a cached
on-disk dataset; ``load_dataset(out_dir)`` opens it; ``Dataset.windows(split)`` gives a
``torch.utils.data.Dataset`` of (history, action chunk, future) windows.

Processing, in order:

1. Run selection: only runs whose outcome has ``lift_success`` and ``stable_squeeze``.
2. Resampling to the global grid ``t_k = k * CONTROL_DT`` (20 ms; ``k`` integer, so every run
   shares the grid), for the grid times inside the recorded span. Continuous channels (the 18
   entries of z, both recorded commands, ``time``) are *linearly interpolated* at the grid time
   between the two bracketing records (a record that falls on the grid time, within 1e-9 s,
   is taken as is). ``v_res`` is NaN at a grid time unless both bracketing records are
   finite. Categorical channels (``c``, ``r_*``, ``phase``) take the value of the last record
   at or before the grid time (zero-order hold), so they stay exact 0/1 labels. Interpolation
   was chosen over bin averaging so that a grid sample is the state *at* ``t_k`` and the
   action at ``t_k`` is the command issued then, with no half-step shift between them.
3. Row selection: grid rows whose phase is not in ``LEARNING_PHASES`` are dropped (settle,
   the duplicated waiting phase, done), and so is the first grid row of ``close`` (the
   initial velocity command). Dropping ``waiting`` leaves a gap in time between ``lift`` and
   ``squeeze``; the kept rows of a run therefore form contiguous *segments*, and a window
   never spans two segments (nor, a fortiori, two runs).
4. Grouped split: runs sharing (size, porosity, F_hold) form a group; within each size the
   groups are shuffled with ``numpy.random.default_rng([seed, size_cm])`` and
   ``round(0.1 n)`` go to validation and ``round(0.2 n)`` to test (each at least one when
   there are at least three groups), the rest to training (70/10/20 of groups).
5. Statistics: mean and population standard deviation of the 18 continuous channels (NaN
   ignored) and the learned action F_target (``CONTROL_ACTIONS``) over the kept rows of the
   training runs only. A channel that is constant in training gets a divisor of 1.

Cached form written to ``out_dir``: ``frames.parquet`` (kept rows, raw SI values, with
``run``, ``t`` row index within the run, ``k`` grid index, ``segment``), ``runs.parquet``
(one row per run: number, id, parameters, split, row counts), ``stats.json`` and
``dataset.json`` (build facts and counts). They are written whole or not at all: into a
temporary directory inside ``out_dir``, then moved in together, ``dataset.json`` last.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn import __version__
from rmi_learn.data import staging
from rmi_learn.data.runs import (
    PARAM_KEYS,
    atomic_write_bytes,
    atomic_write_json,
    iter_run_files,
    read_run,
    run_id,
)
from rmi_learn.data.schema import (
    ACTIONS,
    CONTINUOUS,
    CONTINUOUS_INDEX,
    CONTROL_ACTIONS,
    CONTROL_DT,
    FRICTION_SLICE,
    HISTORY,
    HORIZON,
    LEARNING_PHASES,
    OBS,
    checked_seed,
)
from rmi_learn.errors import InputError, input_errors

try:  # torch is in the `learn` extra; building the cache does not need it.
    import torch
    from torch.utils.data import Dataset as _TorchDataset
except ImportError:  # pragma: no cover - exercised only without torch
    torch = None  # type: ignore[assignment]
    _TorchDataset = object  # type: ignore[assignment,misc]

#: Categorical channels of y (held, never interpolated or standardised).
CATEGORICAL: tuple[str, ...] = tuple(n for n in OBS if n not in CONTINUOUS)
#: Index of retained water M_L within the 18 continuous channels.
WATER_INDEX = CONTINUOUS.index("M_L")
SPLITS: tuple[str, ...] = ("train", "val", "test")
FRACTIONS = (0.7, 0.1, 0.2)
FORMAT_VERSION = 1
_TOL = 1e-9  # s, grid-time matching tolerance


# --------------------------------------------------------------------------------------
# Resampling


def resample_run(df: pl.DataFrame, dt: float = CONTROL_DT) -> dict[str, np.ndarray]:
    """Resample one run's rows to the global grid ``k * dt`` (s) inside its recorded span.

    Returns arrays keyed ``k`` (int64 grid index), ``time`` (= ``k * dt``), ``phase`` (str),
    every name in OBS and ACTIONS. Continuous channels are linearly interpolated; a
    value is NaN if either bracketing record is NaN (only ``v_res`` may be). Categorical
    channels (c, r_*, phase) take the last record at or before the grid time.
    """
    t = df["time"].to_numpy().astype(np.float64)
    if t.size == 0:
        raise ValueError("empty run")
    k0 = math.ceil(t[0] / dt - 1e-6)
    k1 = math.floor(t[-1] / dt + 1e-6)
    k = np.arange(k0, k1 + 1, dtype=np.int64)
    grid = k * dt
    # Continuous: bracketing records lo <= grid <= hi.
    hi = np.searchsorted(t, grid - _TOL, side="left")
    hi = np.clip(hi, 0, t.size - 1)
    exact = np.abs(t[hi] - grid) <= _TOL
    lo = np.clip(hi - 1, 0, t.size - 1)
    span = t[hi] - t[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        wgt = np.where(span > 0, (grid - t[lo]) / np.where(span > 0, span, 1.0), 0.0)
    # Categorical: last record at or before the grid time.
    held = np.searchsorted(t, grid + _TOL, side="right") - 1
    held = np.clip(held, 0, t.size - 1)

    out: dict[str, np.ndarray] = {"k": k, "time": grid.copy()}
    out["phase"] = df["phase"].to_numpy().astype(str)[held]
    for name in OBS + ACTIONS:
        x = df[name].to_numpy().astype(np.float64)
        if name in CATEGORICAL:
            out[name] = x[held]
        else:
            interp = x[lo] * (1.0 - wgt) + x[hi] * wgt
            out[name] = np.where(exact, x[hi], interp)
    return out


def select_learning_rows(phase: np.ndarray) -> np.ndarray:
    """Boolean mask of grid rows kept for learning: phase in LEARNING_PHASES, minus the first
    grid row of ``close`` (the initial velocity command)."""
    keep = np.isin(phase, np.asarray(LEARNING_PHASES))
    close = np.flatnonzero(phase == "close")
    if close.size:
        keep[close[0]] = False
    return keep


# --------------------------------------------------------------------------------------
# Split


def grouped_split(params: pl.DataFrame, seed: int = 0) -> list[str]:
    """Assign each run (row of ``params``, with ``size_cm, porosity, F_hold``) to
    ``train``/``val``/``test`` so that runs sharing (size, porosity, F_hold) stay together and
    groups split 70/10/20 within each size (see the module docstring). Deterministic in
    ``seed``; independent of row order."""
    out = ["train"] * params.height
    sizes = params["size_cm"].to_list()
    keys = list(zip(sizes, params["porosity"].to_list(), params["F_hold"].to_list(), strict=True))
    for size in sorted(set(sizes)):
        groups = sorted({kk for kk in keys if kk[0] == size})
        n = len(groups)
        n_val = math.floor(FRACTIONS[1] * n + 0.5)
        n_test = math.floor(FRACTIONS[2] * n + 0.5)
        if n >= 3:
            n_val, n_test = max(n_val, 1), max(n_test, 1)
        elif n == 2:
            n_val, n_test = 0, 1
        else:
            n_val, n_test = 0, 0
        rng = np.random.default_rng([int(seed), int(size)])
        perm = rng.permutation(n)
        assign: dict[tuple[Any, ...], str] = {}
        for rank, gi in enumerate(perm):
            assign[groups[gi]] = (
                "val" if rank < n_val else "test" if rank < n_val + n_test else "train"
            )
        for i, kk in enumerate(keys):
            if kk[0] == size:
                out[i] = assign[kk]
    return out


# --------------------------------------------------------------------------------------
# Statistics


@dataclass
class Stats:
    """Standardisation statistics from the training split: ``z_mean, z_std`` (18,) in the
    units of CONTINUOUS, ``u_mean, u_std`` (1,) in N (``CONTROL_ACTIONS``: F_target).
    ``*_std`` is the divisor used (population std, or 1 for a channel constant in training)."""

    z_mean: np.ndarray
    z_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray

    @staticmethod
    def _apply(x: Any, scale: np.ndarray, shift: np.ndarray, inverse: bool) -> Any:
        if torch is not None and isinstance(x, torch.Tensor):
            s = torch.as_tensor(scale, dtype=x.dtype, device=x.device)
            m = torch.as_tensor(shift, dtype=x.dtype, device=x.device)
        else:
            arr = np.asarray(x)
            dtype = arr.dtype if np.issubdtype(arr.dtype, np.floating) else np.float64
            sa, ma = scale.astype(dtype), shift.astype(dtype)
            return arr * sa + ma if inverse else (arr - ma) / sa
        return x * s + m if inverse else (x - m) / s

    def standardise_z(self, x: Any) -> Any:
        """(x - z_mean) / z_std over the last axis (18 continuous channels)."""
        return self._apply(x, self.z_std, self.z_mean, inverse=False)

    def destandardise_z(self, x: Any) -> Any:
        """x * z_std + z_mean over the last axis: back to SI units (torch or numpy)."""
        return self._apply(x, self.z_std, self.z_mean, inverse=True)

    def standardise_u(self, x: Any) -> Any:
        """(u - u_mean) / u_std over the last axis (F_target, N)."""
        return self._apply(x, self.u_std, self.u_mean, inverse=False)

    def destandardise_u(self, x: Any) -> Any:
        """u * u_std + u_mean over the last axis: back to N (torch or numpy)."""
        return self._apply(x, self.u_std, self.u_mean, inverse=True)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict with channel names."""
        return {
            "z_names": list(CONTINUOUS),
            "u_names": list(CONTROL_ACTIONS),
            "z_mean": self.z_mean.tolist(),
            "z_std": self.z_std.tolist(),
            "u_mean": self.u_mean.tolist(),
            "u_std": self.u_std.tolist(),
        }

    def check(self) -> None:
        """Raise ValueError naming the field unless every mean is finite and every standard
        deviation finite and > 0: anything else turns the standardised rows into NaN or
        infinity, and a model trained or acting on them into NaN."""
        for key in ("z_mean", "u_mean"):
            if not np.all(np.isfinite(getattr(self, key))):
                raise ValueError(f"statistics field {key!r} must be finite")
        for key in ("z_std", "u_std"):
            value = getattr(self, key)
            if not np.all(np.isfinite(value) & (value > 0)):
                raise ValueError(f"statistics field {key!r} must be finite and > 0")

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Stats:
        """Inverse of :meth:`to_json`; refuses statistics of other channel names and values
        :meth:`check` refuses."""
        if list(d["z_names"]) != list(CONTINUOUS):
            raise ValueError("stats.json channel names differ from rmi_learn.data.schema")
        if list(d["u_names"]) != list(CONTROL_ACTIONS):
            raise ValueError(
                f"stats.json has actions {list(d['u_names'])}, this version learns "
                f"{list(CONTROL_ACTIONS)} (force setpoints): rebuild the dataset with "
                "`rmi dataset` and retrain the models on it"
            )
        stats = cls(
            *(np.asarray(d[k], dtype=np.float64) for k in ("z_mean", "z_std", "u_mean", "u_std"))
        )
        stats.check()
        return stats


def read_stats(path: Path) -> Stats:
    """The statistics file of a built dataset (``stats.json``, see :meth:`Stats.from_json`);
    one that is not the statistics of a built dataset of this version (another channel, a
    missing field, a value :meth:`Stats.check` refuses) raises
    :class:`~rmi_learn.errors.InputError` naming it."""
    d = json.loads(path.read_text())
    try:
        return Stats.from_json(d)
    except KeyError as exc:
        raise InputError(f"{path}: statistics field {exc} is missing") from exc
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from exc


def compute_stats(z: np.ndarray, u: np.ndarray) -> Stats:
    """Statistics of training rows ``z`` (N, 18) and ``u`` (N, 2); NaN ignored."""
    if z.shape[0] == 0:
        raise ValueError("no training rows to compute statistics from")

    def mean_std(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        finite = np.isfinite(x)
        cnt = finite.sum(axis=0)
        xs = np.where(finite, x, 0.0)
        mean = np.divide(xs.sum(axis=0), cnt, out=np.zeros(x.shape[1]), where=cnt > 0)
        var = np.divide(
            (np.where(finite, x - mean, 0.0) ** 2).sum(axis=0),
            cnt,
            out=np.zeros(x.shape[1]),
            where=cnt > 0,
        )
        std = np.sqrt(var)
        tiny = std <= 1e-12 * np.maximum(1.0, np.abs(mean))
        return mean, np.where(tiny, 1.0, std)

    zm, zs = mean_std(z)
    um, us = mean_std(u)
    return Stats(zm, zs, um, us)


# --------------------------------------------------------------------------------------
# Build


def _collect(run_dir: Path) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Read every run file; return the kept runs (resampled rows) and exclusion counts."""
    kept: list[dict[str, Any]] = []
    counts = {"run_files": 0, "lift_failed": 0, "squeeze_unstable": 0, "no_rows": 0}
    for path in iter_run_files(run_dir):
        counts["run_files"] += 1
        df, meta = read_run(path)
        outcome, params = meta["outcome"], meta["params"]
        if not outcome.get("lift_success", False):
            counts["lift_failed"] += 1
            continue
        if not outcome.get("stable_squeeze", False):
            counts["squeeze_unstable"] += 1
            continue
        grid = resample_run(df)
        keep = select_learning_rows(grid["phase"])
        if not keep.any():
            counts["no_rows"] += 1
            continue
        rows = {name: arr[keep] for name, arr in grid.items()}
        kept.append(
            {
                "run_id": run_id(params),
                "path": path.relative_to(run_dir).as_posix(),
                "params": {k: params[k] for k in PARAM_KEYS},
                "rows": rows,
            }
        )
    kept.sort(key=lambda r: r["run_id"])
    return kept, counts


def build_dataset(
    run_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], seed: int = 0
) -> Path:
    """Build the cached learning dataset from the run files under ``run_dir`` (searched
    recursively for ``run.parquet``) into ``out_dir`` and return ``out_dir``.

    See the module docstring for the selection, resampling, split and statistics rules.
    Raises FileNotFoundError if ``run_dir`` is not a directory, ValueError if ``seed`` is
    not in [0, SEED_MAX], no run qualifies or the training split is empty.
    """
    seed = checked_seed(seed)
    run_dir, out = Path(run_dir), Path(out_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir} is not a directory of runs")
    kept, counts = _collect(run_dir)
    if not kept:
        raise ValueError(f"no run under {run_dir} completed lift and squeeze with a stable grasp")

    params = pl.DataFrame([r["params"] for r in kept]).with_columns(
        pl.col("size_cm").cast(pl.Int64),
        pl.col("porosity").cast(pl.Float64),
        pl.col("F_hold").cast(pl.Float64),
        pl.col("F_squeeze").cast(pl.Float64),
        pl.col("seed").cast(pl.Int64),
    )
    split = grouped_split(params, seed)

    frames: list[pl.DataFrame] = []
    seg_base = 0
    n_rows, n_segs = [], []
    for i, r in enumerate(kept):
        rows = r["rows"]
        n = rows["k"].size
        seg = np.concatenate([[0], np.cumsum(np.diff(rows["k"]) != 1)]).astype(np.int64)
        cols: dict[str, Any] = {
            "run": np.full(n, i, dtype=np.int32),
            "t": np.arange(n, dtype=np.int32),
            "k": rows["k"],
            "segment": seg + seg_base,
            "time": rows["time"],
            "phase": rows["phase"],
        }
        cols.update({name: rows[name] for name in OBS + ACTIONS})
        frames.append(pl.DataFrame(cols))
        seg_base += int(seg[-1]) + 1
        n_rows.append(n)
        n_segs.append(int(seg[-1]) + 1)
    frame = pl.concat(frames)

    runs = params.with_columns(
        pl.Series("run", np.arange(len(kept), dtype=np.int32)),
        pl.Series("run_id", [r["run_id"] for r in kept]),
        pl.Series("path", [r["path"] for r in kept]),
        pl.Series("split", split),
        pl.Series("n_rows", n_rows, dtype=pl.Int64),
        pl.Series("n_segments", n_segs, dtype=pl.Int64),
    ).select("run", "run_id", *PARAM_KEYS, "split", "n_rows", "n_segments", "path")

    train_runs = np.flatnonzero(np.asarray(split) == "train")
    if train_runs.size == 0:
        raise ValueError("the training split is empty")
    train = frame.filter(pl.col("run").is_in(train_runs.tolist()))
    stats = compute_stats(
        train.select(CONTINUOUS).to_numpy().astype(np.float64),
        train.select(CONTROL_ACTIONS).to_numpy().astype(np.float64),
    )

    per_split = {
        s: {
            "runs": int(runs.filter(pl.col("split") == s).height),
            "rows": int(runs.filter(pl.col("split") == s)["n_rows"].sum()),
        }
        for s in SPLITS
    }
    info = {
        "format": FORMAT_VERSION,
        "version": __version__,
        "source": str(run_dir.resolve()),
        "seed": seed,
        "dt": CONTROL_DT,
        "learning_phases": list(LEARNING_PHASES),
        "resampling": "linear interpolation (continuous), zero-order hold (categorical)",
        "counts": {**counts, "kept": len(kept), "rows": frame.height},
        "splits": per_split,
    }
    _write_build(out, frame, runs, stats, info)
    return out


#: The files of a built dataset in the order they are moved into place: ``dataset.json``
#: last, as it marks a complete build.
BUILD_FILES = ("frames.parquet", "runs.parquet", "stats.json", "dataset.json")


def _write_build(
    out: Path, frame: pl.DataFrame, runs: pl.DataFrame, stats: Stats, info: dict[str, Any]
) -> None:
    """Write the dataset's files into ``out``, whole or not at all: they are written into a
    temporary directory inside ``out`` and moved in together, so an error (a full disk)
    leaves an existing ``out`` as it was and removes an ``out`` this build created."""
    made = staging.make_dirs(out)
    try:
        staging.remove_stale_temporaries(out)
        tmp = staging.temporary_dir(out, "build")
        try:
            frames_data, runs_data = staging.parquet_bytes(frame), staging.parquet_bytes(runs)
            atomic_write_bytes(tmp / "frames.parquet", lambda f: f.write(frames_data))
            atomic_write_bytes(tmp / "runs.parquet", lambda f: f.write(runs_data))
            atomic_write_json(tmp / "stats.json", stats.to_json())
            atomic_write_json(tmp / "dataset.json", info)
            staging.move_in(tmp, out, list(BUILD_FILES))
        except OSError as exc:
            staging.raise_named_for(exc, tmp, out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        staging.remove_made_dirs(made)
        raise


# --------------------------------------------------------------------------------------
# Load and windows


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
        self.frames = read_table(self.root / "frames.parquet", ("run", "t", "segment", *OBS))
        f = self.frames
        self.run_ids: list[str] = self.runs.sort("run")["run_id"].to_list()
        self.row_run = f["run"].to_numpy().astype(np.int64)
        self.row_t = f["t"].to_numpy().astype(np.int64)
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
    ) -> WindowSet:
        """All stride-1 windows of ``split`` (and ``size_cm``): anchor rows t with history
        rows t-L+1..t and future rows t+1..t+H in one contiguous segment of one run."""
        if history < 1 or horizon < 1:
            raise ValueError("history and horizon must be positive")
        runs = self.split_runs(split, size_cm)
        gidx = np.arange(self.row_run.size)
        ok = (
            np.isin(self.row_run, runs)
            & (gidx - history + 1 >= self.seg_first)
            & (gidx + horizon <= self.seg_last)
        )
        return WindowSet(self, np.flatnonzero(ok), history, horizon)


class WindowSet(_TorchDataset):  # type: ignore[type-arg]
    """Windows of a :class:`Dataset` as a map-style ``torch.utils.data.Dataset``.

    ``ws[i]`` and ``ws.batch(indices)`` return dicts of tensors (``batch`` adds a leading N):
    ``hist`` (L, 23) float32: y standardised on continuous channels, c and r_* raw 0/1,
    invalid -> 0; ``hist_mask`` (L, 23) 1 where the raw value was finite; ``actions``
    (H, 1) standardised F_target at t..t+H-1; ``target`` (H, 18) standardised z at t+1..t+H,
    invalid -> 0; ``target_mask`` (H, 18); ``target_c`` (H,) 0/1; ``target_r`` (H,) int64
    friction class 0..3 (none, stick, slip, mixed); ``water_now`` () standardised M_L at t;
    ``run`` int64 run number (``run_ids[run]`` names it) and ``t`` int64 row index of the
    anchor within its run's kept rows. ``anchors`` holds the global frame rows of the anchors.
    """

    def __init__(self, data: Dataset, anchors: np.ndarray, history: int, horizon: int):
        self.data = data
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
            "hist": d.y_std[h],
            "hist_mask": d.y_mask[h],
            "actions": d.u_std[a],
            "target": d.z_std[fut],
            "target_mask": d.z_mask[fut],
            "target_c": d.c[fut],
            "target_r": d.r_class[fut],
            "water_now": d.z_std[t, WATER_INDEX],
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


@input_errors(OSError, ValueError)
def build(run_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], seed: int = 0) -> Path:
    """``rmi dataset build``: :func:`build_dataset`, with a run tree that yields no dataset
    or an output directory that cannot be written reported as
    :class:`~rmi_learn.errors.InputError`."""
    return build_dataset(run_dir, out_dir, seed=seed)


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
