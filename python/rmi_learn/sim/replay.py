"""Replay of a stored run to a window's anchor.

The engine is deterministic (one config gives bit-identical trajectories, whatever the
thread count), so a window's starting state is rebuilt from the run's stored config
(``rmi.config``): ``rmi_sph.Trial(config)`` is stepped with the scripted controller to the
anchor. The anchor ``t`` of a window is the *kept-row index* within the run's learning rows
(``frames.parquet`` column ``t``, after resampling to 20 ms and dropping the settle, waiting
and done rows and the first close row), not a grid index. It is mapped to the grid index
``k`` by redoing that row selection on the run file (:func:`load_track`), and the anchor is
simulated time ``k * CONTROL_DT`` = ``round(k * 0.02 / dt)`` engine steps
(:func:`anchor_step`). :func:`check_anchor` compares the replayed observation there with the
stored record.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.dataset import resample_run, select_learning_rows
from rmi_learn.data.runs import read_run
from rmi_learn.data.schema import ACTIONS, CONTROL_DT, OBS
from rmi_learn.data.sweep import INDEX_FILE
from rmi_learn.errors import InputError

#: Channels a run file averages over the record interval; the replay check skips them
#: because ``Trial.observation()`` gives the loads of the last step.
AVERAGED_CHANNELS = frozenset({"F_meas", "F_L", "F_R", "alpha_F"})
#: Grid time against record time (s): a record this close falls on the grid.
TIME_TOL = 1e-9


class ReplayError(InputError, ValueError):
    """A stored run that cannot be replayed (missing or unreadable files, no stored config, a
    control step that is no whole number of engine steps, a replay that does not reproduce
    the stored record); the ``rmi`` commands report it with exit code 2."""


@dataclass
class RunTrack:
    """A run's learning rows (resampled to 20 ms, as ``build_dataset`` keeps them).

    ``k`` grid index (time ``k * CONTROL_DT`` s), ``exact`` whether a record falls on the grid
    time (its values are the record's, not interpolated), ``phase``, ``obs`` (n, 23) in the
    order of ``schema.OBS`` (SI), ``actions`` (n, 2) F_target (N) and v_cmd (m/s).
    """

    path: Path
    config: dict[str, Any]
    size_cm: int
    k: np.ndarray
    exact: np.ndarray
    phase: np.ndarray
    obs: np.ndarray
    actions: np.ndarray

    @property
    def water(self) -> np.ndarray:
        """Retained water M_L per kept row (kg)."""
        return self.obs[:, OBS.index("M_L")]


def load_index(sweep_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Run id -> run file path of every completed run of a sweep (``index.parquet``); an
    index that is missing, unreadable (cut short) or lacks its columns raises
    :class:`ReplayError` naming it."""
    root = Path(sweep_dir)
    index = root / INDEX_FILE
    if not index.exists():
        raise ReplayError(f"--runs {root} has no {INDEX_FILE} (give a sweep output directory)")
    try:
        df = pl.read_parquet(index)
    except (OSError, pl.exceptions.PolarsError) as exc:
        raise ReplayError(
            f"{index} is not readable ({exc}); rebuild it with rmi sweep --index-only"
        ) from exc
    for col in ("run_id", "path"):
        if col not in df.columns:
            raise ReplayError(f"{index} has no {col!r} column")
    if "status" in df.columns:
        df = df.filter(pl.col("status") == "ok")
    out: dict[str, Path] = {}
    for rid, p in zip(df["run_id"].to_list(), df["path"].to_list(), strict=True):
        path = Path(p)
        out[str(rid)] = path if path.is_absolute() else root / path
    return out


def load_track(path: Path) -> RunTrack:
    """Read a run file and keep its learning rows exactly as ``build_dataset`` does."""
    try:
        df, meta = read_run(path)
    except (OSError, ValueError) as exc:
        raise ReplayError(f"cannot read run file {path}: {exc}") from exc
    config = meta.get("config") or {}
    if not config:
        raise ReplayError(f"{path} holds no trial config (rmi.config metadata)")
    grid = resample_run(df)
    keep = select_learning_rows(grid["phase"])
    rec_t = df["time"].to_numpy().astype(np.float64)
    pos = np.clip(np.searchsorted(rec_t, grid["time"]), 0, rec_t.size - 1)
    near = np.minimum(
        np.abs(rec_t[pos] - grid["time"]), np.abs(rec_t[np.maximum(pos - 1, 0)] - grid["time"])
    )
    return RunTrack(
        path=path,
        config=config,
        size_cm=int(meta["params"]["size_cm"]),
        k=grid["k"][keep],
        exact=(near <= TIME_TOL)[keep],
        phase=grid["phase"][keep],
        obs=np.stack([grid[n][keep] for n in OBS], axis=1),
        actions=np.stack([grid[n][keep] for n in ACTIONS], axis=1),
    )


def control_substeps(dt: float, control_dt: float = CONTROL_DT) -> int:
    """Engine steps per control step; raises if ``control_dt`` is not a whole number of
    steps of ``dt`` (s), since the grid times would then fall between engine steps."""
    n = round(control_dt / dt)
    if n < 1 or abs(n * dt - control_dt) > 1e-9 * max(1.0, control_dt):
        raise ReplayError(f"dt = {dt} s does not divide the control step {control_dt} s")
    return int(n)


def anchor_step(track: RunTrack, t: int, dt: float) -> int:
    """The engine step count at the anchor of kept row ``t`` for engine step ``dt`` (s)."""
    return round(float(track.k[t]) * CONTROL_DT / float(dt))


def _obs_vector(obs: Any) -> np.ndarray:
    return np.asarray([float(obs[n]) for n in OBS], dtype=np.float64)


def check_anchor(sim: Any, track: RunTrack, run_id: str, t: int) -> None:
    """Compare the replayed observation of run ``run_id`` at the anchor of kept row ``t``
    with the stored record (all channels of y except the interval-averaged pad loads, and
    the phase); exact equality is required when a record falls on the grid time. Raises
    :class:`ReplayError` on any difference."""
    if not track.exact[t]:
        return
    got = _obs_vector(sim.observation())
    want = track.obs[t]
    for j, name in enumerate(OBS):
        if name in AVERAGED_CHANNELS:
            continue
        a, b = got[j], want[j]
        same = (math.isnan(a) and math.isnan(b)) or a == b
        if not same:
            raise ReplayError(
                f"replaying run {run_id} to t = {track.k[t] * CONTROL_DT:.2f} s gives "
                f"{name} = {float(a)!r}, the run file holds {float(b)!r}: the run was made "
                "with another engine build or config (deterministic replay failed)"
            )
    if str(sim.phase) != str(track.phase[t]):
        raise ReplayError(
            f"replaying run {run_id} to t = {track.k[t] * CONTROL_DT:.2f} s is in "
            f"phase {sim.phase!r}, the run file in {track.phase[t]!r}"
        )


__all__ = [
    "AVERAGED_CHANNELS",
    "ReplayError",
    "RunTrack",
    "anchor_step",
    "check_anchor",
    "control_substeps",
    "load_index",
    "load_track",
]
