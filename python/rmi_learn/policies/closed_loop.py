"""Closed-loop execution of ranked action chunks in the simulator (the *real* Table III).

``rmi rank`` reports the terminal water error that the world model W_T predicts for the chunk
it selected itself, which is biased toward W_T. This module executes the original (collected),
first-sample and selected chunks of ``chunks_<objective>.npz`` in the SPH engine and measures
the retained water they really leave after the last command.

Replay. The engine is deterministic (one config gives bit-identical trajectories, whatever the
thread count), so a window's starting state is rebuilt from the run's stored config
(``rmi.config``): ``rmi_sph.Trial(config)`` is stepped with the scripted controller to the
anchor. The anchor ``t`` of a window in the npz is the *kept-row index* within the run's
learning rows (``frames.parquet`` column ``t``, after resampling to 20 ms and dropping the
settle, waiting and done rows and the first close row), not a grid index. It is mapped to the
grid index ``k`` by redoing that row selection on the run file
(:func:`rmi_learn.data.dataset.resample_run` and
:func:`~rmi_learn.data.dataset.select_learning_rows`), and the anchor is simulated time
``k * CONTROL_DT`` = ``round(k * 0.02 / dt)`` engine steps.
Before any chunk runs, the replayed observation at the anchor is compared with the stored
record there (every channel except the pad loads, which run files average over the record
interval); a difference means the run came from another engine or config and stops the
command (:class:`ClosedLoopError`).

Execution. The state at the anchor is saved once per window (``get_state``); each chunk then
starts from it (``set_state``). Command ``i`` of a chunk (``i`` = 0..31, the action rows
``t..t+31`` of the window) is applied with ``set_action`` and held for one control step of
``round(0.02 / dt)`` engine steps, so the chunk covers ``[t_k, t_k + 0.64 s)``; ``M_L`` is read
after the 32nd command, at the time of the goal row ``t + 32``. The chunks are force
setpoints (``schema.CONTROL_ACTIONS``), clipped to [0, FORCE_LIMIT_N] (the gripper's limit,
N) and sent with ``set_action(F_target)``: the engine's force regulation (paper Eq. 5b) runs
every engine step toward the setpoint, its guards acting on the force limit and minimum width
as always. The phase sequence (lift, waiting, squeeze), the lift gate and the grasp-failure
checks keep running under external commands. During the close phase the collected command is
F_target = 0 with a closing speed, which a force setpoint cannot express.

Phase timing is not fixed by the window: the lift gate of the hold phase watches the grip
loads, so a chunk in the hold can open it earlier, later or not at all; grasp failures
(dropped, slipped out) end the trial early. Each row records the phase reached
(``phase_end``) next to the collected one (``goal_phase``), and ``failure``.

The original chunk is executed from the run file's own commands (f64, identical to the npz
chunk up to its float32 rounding, which is checked); its real error against the goal measures
what the 20 ms zero-order hold of the commands loses (the replay error).

Outputs in ``out_dir``: ``closed_loop_windows.parquet`` (one row per window and chunk,
checkpointed atomically after every window so that an interrupted run resumes; a window
whose replay raised is recorded as ``replay_failed`` and, the engine being deterministic,
not retried),
``table_closed_loop.md`` and ``table_closed_loop.json``. Water is in kg in stored data and in
grams in tables.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn import __version__
from rmi_learn.data.dataset import resample_run, select_learning_rows
from rmi_learn.data.runs import atomic_write_bytes, atomic_write_json, json_safe, read_run
from rmi_learn.data.schema import (
    ACTIONS,
    CONTROL_ACTION_INDEX,
    CONTROL_ACTIONS,
    CONTROL_DT,
    FORCE_LIMIT_N,
    OBS,
)
from rmi_learn.data.sweep import INDEX_FILE
from rmi_learn.errors import InputError

#: Policy objectives whose chunk files ``rmi rank`` writes (``chunks_<objective>.npz``).
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")
LABELS = {"diffusion": "Diffusion policy", "flow": "Flow matching"}
#: Chunks executed per window; ``original`` is shared by the objectives.
CHUNKS: tuple[str, ...] = ("original", "first", "selected")
COMMAND_MODES: tuple[str, ...] = ("force",)
WINDOWS_FILE = "closed_loop_windows.parquet"
TABLE_STEM = "table_closed_loop"
#: Keys every chunk file must hold (see ``rmi rank``).
NPZ_KEYS: tuple[str, ...] = (
    "size_cm",
    "run_id",
    "t",
    "goal_kg",
    "water_now_kg",
    "original",
    "first",
    "selected",
    "index",
)
#: Engine limits of an external force setpoint (N).
FORCE_RANGE = (0.0, FORCE_LIMIT_N)
#: Channels a run file averages over the record interval; the replay check skips them
#: because ``Trial.observation()`` gives the loads of the last step.
AVERAGED_CHANNELS = frozenset({"F_meas", "F_L", "F_R", "alpha_F"})
#: The npz holds float32 values converted from standardised units; these tolerances only
#: absorb that rounding (a different window or run differs by far more).
_KG_TOL = 1e-5  # kg
_FORCE_TOL = 1e-3  # N
_REL_TOL = 1e-4
_TIME_TOL = 1e-9  # s, grid time vs record time


class ClosedLoopError(InputError, ValueError):
    """Inputs that cannot be executed (missing files, unknown runs, npz/run mismatch, a
    replay that does not reproduce the stored record); the ``rmi`` commands report it with
    exit code 2."""


# --------------------------------------------------------------------------------------
# Inputs


@dataclass(frozen=True)
class Window:
    """One ranked window: the run, the sponge size (cm), the anchor's kept-row index ``t``
    and, per objective, the row of that objective's npz holding its chunks."""

    run_id: str
    size_cm: int
    t: int
    rows: tuple[tuple[str, int], ...]


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


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_chunks(chunks_dir: str | os.PathLike[str]) -> dict[str, dict[str, np.ndarray]]:
    """Read ``chunks_<objective>.npz`` of every objective present in ``chunks_dir``.

    Returns objective -> arrays (``original``/``first``/``selected`` (n, H, 2) in N and m/s,
    ``goal_kg``/``water_now_kg`` (n,) kg, ``t`` kept-row index, ``run_id``, ``size_cm``,
    ``index`` and, when present, ``J_M_samples`` (n, K) predicted errors in g). Raises
    :class:`ClosedLoopError` if there is none or one lacks a key or has inconsistent shapes.
    """
    root = Path(chunks_dir)
    if not root.is_dir():
        raise ClosedLoopError(f"--chunks {root} is not a directory")
    out: dict[str, dict[str, np.ndarray]] = {}
    for obj in OBJECTIVES:
        path = root / f"chunks_{obj}.npz"
        if not path.exists():
            continue
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: np.asarray(z[k]) for k in z.files}
        except (OSError, ValueError) as exc:
            raise ClosedLoopError(f"{path}: not a readable npz file ({exc})") from exc
        missing = [k for k in NPZ_KEYS if k not in arrays]
        if missing:
            raise ClosedLoopError(f"{path} lacks {missing} (write it with `rmi rank`)")
        n = arrays["t"].shape[0]
        for k in ("original", "first", "selected"):
            a = arrays[k]
            nu = len(CONTROL_ACTIONS)
            if a.ndim != 3 or a.shape[0] != n or a.shape[2] != nu:
                raise ClosedLoopError(
                    f"{path}: {k!r} has shape {a.shape}, expected ({n}, H, {nu}) force setpoints"
                    " (chunk files of earlier versions held [F_target, v_cmd]: rank again)"
                )
        if not arrays["original"].shape == arrays["first"].shape == arrays["selected"].shape:
            raise ClosedLoopError(f"{path}: original, first and selected differ in shape")
        for k in ("size_cm", "run_id", "goal_kg", "water_now_kg", "index"):
            if arrays[k].shape[:1] != (n,):
                raise ClosedLoopError(f"{path}: {k!r} has {arrays[k].shape[0]} rows, not {n}")
        out[obj] = arrays
    if not out:
        names = ", ".join(f"chunks_{o}.npz" for o in OBJECTIVES)
        raise ClosedLoopError(f"no chunk file in {root} (expected {names} from `rmi rank`)")
    horizons = {a["original"].shape[1] for a in out.values()}
    if len(horizons) != 1:
        raise ClosedLoopError(f"the chunk files disagree on the chunk length: {sorted(horizons)}")
    return out


def load_index(sweep_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Run id -> run file path of every completed run of a sweep (``index.parquet``)."""
    root = Path(sweep_dir)
    index = root / INDEX_FILE
    if not index.exists():
        raise ClosedLoopError(f"--runs {root} has no {INDEX_FILE} (give a sweep output directory)")
    df = pl.read_parquet(index)
    for col in ("run_id", "path"):
        if col not in df.columns:
            raise ClosedLoopError(f"{index} has no {col!r} column")
    if "status" in df.columns:
        df = df.filter(pl.col("status") == "ok")
    out: dict[str, Path] = {}
    for rid, p in zip(df["run_id"].to_list(), df["path"].to_list(), strict=True):
        path = Path(p)
        out[str(rid)] = path if path.is_absolute() else root / path
    return out


def select_windows(
    chunks: Mapping[str, Mapping[str, np.ndarray]], max_windows: int = 4
) -> list[Window]:
    """The windows to execute: the union over objectives of the ranked windows (same run and
    anchor = same window), per size sorted by (run id, t) and thinned to ``max_windows``
    evenly spaced ones (``0``: all), in the same way ``rmi rank --max-windows`` thins."""
    found: dict[tuple[str, int], dict[str, Any]] = {}
    for obj, a in chunks.items():
        for i, (rid, t, size) in enumerate(
            zip(a["run_id"].tolist(), a["t"].tolist(), a["size_cm"].tolist(), strict=True)
        ):
            key = (str(rid), int(t))
            entry = found.setdefault(key, {"size": int(size), "rows": {}})
            if entry["size"] != int(size):
                raise ClosedLoopError(
                    f"window {key} has size {entry['size']} cm in one chunk file and "
                    f"{int(size)} cm in {obj}"
                )
            entry["rows"].setdefault(obj, i)
    out: list[Window] = []
    for size in sorted({e["size"] for e in found.values()}):
        keys = sorted(k for k, e in found.items() if e["size"] == size)
        idx = np.arange(len(keys))
        if max_windows and len(keys) > max_windows:
            idx = np.unique(np.linspace(0, len(keys) - 1, max_windows).round()).astype(np.int64)
        for i in idx.tolist():
            rid, t = keys[i]
            rows = tuple(sorted(found[(rid, t)]["rows"].items()))
            out.append(Window(rid, size, t, rows))
    return out


def load_track(path: Path) -> RunTrack:
    """Read a run file and keep its learning rows exactly as ``build_dataset`` does."""
    try:
        df, meta = read_run(path)
    except (OSError, ValueError) as exc:
        raise ClosedLoopError(f"cannot read run file {path}: {exc}") from exc
    config = meta.get("config") or {}
    if not config:
        raise ClosedLoopError(f"{path} holds no trial config (rmi.config metadata)")
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
        exact=(near <= _TIME_TOL)[keep],
        phase=grid["phase"][keep],
        obs=np.stack([grid[n][keep] for n in OBS], axis=1),
        actions=np.stack([grid[n][keep] for n in ACTIONS], axis=1),
    )


def _close(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    return bool(np.allclose(a, b, rtol=_REL_TOL, atol=atol))


def check_window(
    track: RunTrack, window: Window, chunks: Mapping[str, Mapping[str, np.ndarray]], h: int
) -> None:
    """Check that ``window`` of the npz files is the run's kept rows ``t..t+h``: one segment
    (no removed waiting phase inside), the same size, goal, current water and original
    commands (within float32 rounding). Raises :class:`ClosedLoopError` naming the mismatch."""
    t, n = window.t, track.k.size
    where = f"window (run {window.run_id}, t={t})"
    if track.size_cm != window.size_cm:
        raise ClosedLoopError(
            f"{where}: the npz says {window.size_cm} cm, the run file {track.size_cm} cm"
        )
    if t < 0 or t + h >= n:
        raise ClosedLoopError(
            f"{where}: the run has {n} learning rows, the window needs rows {t}..{t + h}"
        )
    if track.k[t + h] - track.k[t] != h:
        raise ClosedLoopError(
            f"{where}: rows {t}..{t + h} are not {h} consecutive 20 ms steps (they cross the "
            "removed waiting phase): the npz does not index this run's learning rows"
        )
    goal = track.water[t + h]
    for obj, i in window.rows:
        a = chunks[obj]
        src = f"{where}, chunks_{obj}.npz row {i}"
        if not _close(np.float64(a["goal_kg"][i]), goal, _KG_TOL):
            raise ClosedLoopError(
                f"{src}: goal {float(a['goal_kg'][i]):.6f} kg, but the run holds "
                f"M_L = {goal:.6f} kg at t+{h}; the chunk files come from another sweep"
            )
        if not _close(np.float64(a["water_now_kg"][i]), track.water[t], _KG_TOL):
            raise ClosedLoopError(
                f"{src}: water_now {float(a['water_now_kg'][i]):.6f} kg, but the run holds "
                f"M_L = {track.water[t]:.6f} kg at t; the chunk files come from another sweep"
            )
        orig = a["original"][i].astype(np.float64)
        rec = track.actions[t : t + h, list(CONTROL_ACTION_INDEX)]
        if not _close(orig, rec, _FORCE_TOL):
            raise ClosedLoopError(
                f"{src}: the original chunk differs from the run's recorded commands at rows "
                f"{t}..{t + h - 1}; the chunk files come from another sweep"
            )


# --------------------------------------------------------------------------------------
# Trial


def _sim_module() -> Any:
    import rmi_sph

    return rmi_sph


def control_substeps(dt: float, control_dt: float = CONTROL_DT) -> int:
    """Engine steps per control step; raises if ``control_dt`` is not a whole number of
    steps of ``dt`` (s), since the grid times would then fall between engine steps."""
    n = round(control_dt / dt)
    if n < 1 or abs(n * dt - control_dt) > 1e-9 * max(1.0, control_dt):
        raise ClosedLoopError(f"dt = {dt} s does not divide the control step {control_dt} s")
    return int(n)


def _obs_vector(obs: Mapping[str, Any]) -> np.ndarray:
    return np.asarray([float(obs[n]) for n in OBS], dtype=np.float64)


def check_anchor(sim: Any, track: RunTrack, window: Window) -> None:
    """Compare the replayed observation at the anchor with the stored record (all channels of
    y except the interval-averaged pad loads, and the phase); exact equality is required when
    a record falls on the grid time. Raises :class:`ClosedLoopError` on any difference."""
    t = window.t
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
            raise ClosedLoopError(
                f"replaying run {window.run_id} to t = {track.k[t] * CONTROL_DT:.2f} s gives "
                f"{name} = {float(a)!r}, the run file holds {float(b)!r}: the run was made "
                "with another engine build or config (deterministic replay failed)"
            )
    if str(sim.phase) != str(track.phase[t]):
        raise ClosedLoopError(
            f"replaying run {window.run_id} to t = {track.k[t] * CONTROL_DT:.2f} s is in "
            f"phase {sim.phase!r}, the run file in {track.phase[t]!r}"
        )


def execute_chunk(
    sim: Any,
    state: bytes,
    chunk: np.ndarray,
    substeps: int,
    command: str,
    recorded: np.ndarray | None = None,
) -> dict[str, Any]:
    """Restore ``state`` and apply the force setpoints of ``chunk`` (H, 1) (N), each held for
    ``substeps`` engine steps; the engine's force loop regulates the closing speed
    (``command`` ``force``, the only mode).

    Returns ``status`` (``ok``, ``unstable``, ``error``, ``invalid_chunk``), ``M_L`` (kg
    after the last command, None unless ok), ``phase`` and ``failure`` at the end, and,
    when ``recorded`` (H, 2) holds the recorded M_L (kg) and F_meas (N) at the ends of the
    H control steps, ``dev_M_L_max_g`` (g) and ``dev_F_rms_N`` (N), the deviation from the
    recorded trajectory (loads averaged over each control step).
    """
    rmi_sph = _sim_module()
    out: dict[str, Any] = {
        "status": "ok",
        "M_L": None,
        "phase": None,
        "failure": None,
        "dev_M_L_max_g": None,
        "dev_F_rms_N": None,
        "error": None,
    }
    if not np.all(np.isfinite(chunk)):
        out["status"] = "invalid_chunk"
        out["error"] = "the chunk holds non-finite commands"
        return out
    sim.set_state(state)
    sim.take_record()  # starts the load-averaging interval at the anchor
    traj = np.empty((chunk.shape[0], 2))
    try:
        for i, f in enumerate(chunk[:, 0].tolist()):
            sim.set_action(min(max(f, FORCE_RANGE[0]), FORCE_RANGE[1]))
            sim.step(substeps)
            rec = sim.take_record()
            traj[i] = (rec["M_L"], rec["F_meas"])
    except rmi_sph.SimulationUnstableError as exc:
        out["status"] = "unstable"
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out
    except rmi_sph.RmiError as exc:
        out["status"] = "error"
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out
    out["M_L"] = float(traj[-1, 0])
    out["phase"] = str(sim.phase)
    out["failure"] = sim.failure
    if recorded is not None:
        out["dev_M_L_max_g"] = float(1000.0 * np.max(np.abs(traj[:, 0] - recorded[:, 0])))
        out["dev_F_rms_N"] = float(np.sqrt(np.mean((traj[:, 1] - recorded[:, 1]) ** 2)))
    return out


# --------------------------------------------------------------------------------------
# Results table

#: Columns of ``closed_loop_windows.parquet`` and their types.
ROW_SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "size_cm": pl.Int64,
    "t": pl.Int64,
    "k": pl.Int64,
    "anchor_time_s": pl.Float64,
    "anchor_phase": pl.String,
    "goal_phase": pl.String,
    "objective": pl.String,
    "chunk": pl.String,
    "sample_index": pl.Int64,
    "command": pl.String,
    "goal_kg": pl.Float64,
    "water_now_kg": pl.Float64,
    "M_L_real_kg": pl.Float64,
    "err_real_g": pl.Float64,
    "err_pred_g": pl.Float64,
    "status": pl.String,
    "failure": pl.String,
    "phase_end": pl.String,
    "dev_M_L_max_g": pl.Float64,
    "dev_F_rms_N": pl.Float64,
    "error": pl.String,
    "wall_s": pl.Float64,
    "replay_wall_s": pl.Float64,
}


def _rows_frame(rows: Sequence[Mapping[str, Any]]) -> pl.DataFrame:
    return pl.DataFrame(
        {c: pl.Series(c, [r.get(c) for r in rows], dtype=d) for c, d in ROW_SCHEMA.items()}
    )


def _read_checkpoint(path: Path, fingerprint: str) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    try:
        meta = pl.read_parquet_metadata(path)
        df = pl.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same advice
        raise ClosedLoopError(f"{path} is not readable ({exc}); delete it to start over") from exc
    if meta.get("rmi.closed_loop.fingerprint") != fingerprint:
        raise ClosedLoopError(
            f"{path} holds results of other inputs (chunk files or --command differ); "
            "use another --out or delete that file to start over"
        )
    if set(df.columns) != set(ROW_SCHEMA):
        raise ClosedLoopError(f"{path} has other columns than this version writes; delete it")
    return df.to_dicts()


def _write_checkpoint(path: Path, rows: Sequence[Mapping[str, Any]], meta: dict[str, str]) -> None:
    df = _rows_frame(rows)
    atomic_write_bytes(path, lambda f: df.write_parquet(f, metadata=meta))


def _mean(xs: Sequence[float]) -> float | None:
    return float(np.mean(xs)) if xs else None


def _std(xs: Sequence[float]) -> float | None:
    return float(np.std(xs)) if xs else None


def summarise(rows: Sequence[Mapping[str, Any]], windows: Sequence[Window]) -> dict[str, Any]:
    """Per size and objective: mean real terminal error (g) of the original, first and
    selected chunks over the windows where all three executed, its standard deviation, the
    W_T-predicted errors of the same windows, the fraction of windows where the selected
    chunk is strictly better (and tied) in reality, the ratio selected / first of the mean
    real errors, grasp failures, chunks that end in another controller phase than the
    collected trajectory at the goal row (e.g. a hold whose lift gate did not open), and
    chunks that could not be executed."""
    wanted = {(w.run_id, w.t) for w in windows}
    by_key: dict[tuple[str, int, str | None, str], Mapping[str, Any]] = {}
    for r in rows:
        if (r["run_id"], r["t"]) in wanted:
            by_key[(r["run_id"], r["t"], r["objective"], r["chunk"])] = r
    out: dict[str, Any] = {}
    for size in sorted({w.size_cm for w in windows}):
        ws = [w for w in windows if w.size_cm == size]
        orig = [by_key.get((w.run_id, w.t, None, "original")) for w in ws]
        ok_orig = [r for r in orig if r is not None and r["status"] == "ok"]
        entry: dict[str, Any] = {
            "n_windows": len(ws),
            "original": {
                "n": len(ok_orig),
                "real_g": _mean([r["err_real_g"] for r in ok_orig]),
                "real_sd_g": _std([r["err_real_g"] for r in ok_orig]),
                "dev_F_rms_N": _mean([r["dev_F_rms_N"] for r in ok_orig]),
                "dev_M_L_max_g": _mean([r["dev_M_L_max_g"] for r in ok_orig]),
                "failures": sum(1 for r in ok_orig if r["failure"]),
                "phase_differs": sum(1 for r in ok_orig if r["phase_end"] != r["goal_phase"]),
            },
        }
        for obj in OBJECTIVES:
            trip = []
            not_run = 0
            for w, o in zip(ws, orig, strict=True):
                if obj not in dict(w.rows):
                    continue
                f = by_key.get((w.run_id, w.t, obj, "first"))
                s = by_key.get((w.run_id, w.t, obj, "selected"))
                if o is None or f is None or s is None:
                    not_run += 1
                    continue
                if any(r["status"] != "ok" for r in (o, f, s)):
                    not_run += 1
                    continue
                trip.append((o, f, s))
            if not trip and not not_run:
                continue
            fr = [f["err_real_g"] for _, f, _ in trip]
            sr = [s["err_real_g"] for _, _, s in trip]
            fp = [f["err_pred_g"] for _, f, _ in trip if f["err_pred_g"] is not None]
            sp = [s["err_pred_g"] for _, _, s in trip if s["err_pred_g"] is not None]
            mf, ms = _mean(fr), _mean(sr)
            entry[obj] = {
                "n": len(trip),
                "not_executed": not_run,
                "original_real_g": _mean([o["err_real_g"] for o, _, _ in trip]),
                "first_real_g": mf,
                "first_real_sd_g": _std(fr),
                "selected_real_g": ms,
                "selected_real_sd_g": _std(sr),
                "first_pred_g": _mean(fp) if len(fp) == len(trip) else None,
                "selected_pred_g": _mean(sp) if len(sp) == len(trip) else None,
                "selected_beats_first": _mean([float(s < f) for f, s in zip(fr, sr, strict=True)]),
                "tied": _mean([float(s == f) for f, s in zip(fr, sr, strict=True)]),
                "ratio_selected_first": (ms / mf) if mf and ms is not None else None,
                "failures_first": sum(1 for _, f, _ in trip if f["failure"]),
                "failures_selected": sum(1 for _, _, s in trip if s["failure"]),
                "phase_differs_first": sum(
                    1 for _, f, _ in trip if f["phase_end"] != f["goal_phase"]
                ),
                "phase_differs_selected": sum(
                    1 for _, _, s in trip if s["phase_end"] != s["goal_phase"]
                ),
            }
        out[str(size)] = entry
    return out


def _fmt(v: float | None, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _markdown(summary: Mapping[str, Any], info: Mapping[str, Any]) -> str:
    sizes = list(summary)
    objs = [o for o in OBJECTIVES if any(o in summary[s] for s in sizes)]
    head = "| Method | " + " | ".join(f"{s} cm" for s in sizes) + " |"
    rule = "|---|" + "|".join(":---:" for _ in sizes) + "|"
    lines = [
        "**Closed-loop terminal water error |M_L - g| (g), executed in the simulator "
        f"(command mode `{info['command']}`, {info['chunk_steps']} commands of 20 ms)**",
        "",
        head,
        rule,
        "| Original controller action (replayed at 20 ms) | "
        + " | ".join(_fmt(summary[s]["original"]["real_g"]) for s in sizes)
        + " |",
    ]
    for o in objs:
        for label, key in ((f"{LABELS[o]}, first sample", "first"), (f"{LABELS[o]} + W_T", "sel")):
            field = "first_real_g" if key == "first" else "selected_real_g"
            lines.append(
                f"| {label} | "
                + " | ".join(_fmt(summary[s].get(o, {}).get(field)) for s in sizes)
                + " |"
            )
    lines.append(
        "| Windows | " + " | ".join(str(summary[s]["original"]["n"]) for s in sizes) + " |"
    )
    lines += [
        "",
        "**Real (simulated) against W_T-predicted error of the same windows (g)**",
        "",
        "| Policy | Size | n | first: predicted | first: real | selected: predicted | "
        "selected: real | real selected / first | selected better (tied) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for o in objs:
        for s in sizes:
            e = summary[s].get(o)
            if e is None:
                continue
            lines.append(
                f"| {LABELS[o]} | {s} cm | {e['n']} | {_fmt(e['first_pred_g'])} | "
                f"{_fmt(e['first_real_g'])} | {_fmt(e['selected_pred_g'])} | "
                f"{_fmt(e['selected_real_g'])} | {_fmt(e['ratio_selected_first'])} | "
                f"{_fmt(e['selected_beats_first'])} ({_fmt(e['tied'])}) |"
            )
    lines += [
        "",
        "Replay fidelity of the original chunk (recorded commands held for 20 ms): mean RMS "
        "deviation of the grip load from the recorded one "
        + ", ".join(f"{s} cm {_fmt(summary[s]['original']['dev_F_rms_N'])} N" for s in sizes)
        + "; mean largest deviation of M_L over the chunk "
        + ", ".join(f"{s} cm {_fmt(summary[s]['original']['dev_M_L_max_g'])} g" for s in sizes)
        + "; windows whose replay ends in another phase than the collected run "
        + ", ".join(
            f"{s} cm {summary[s]['original']['phase_differs']}/{summary[s]['original']['n']}"
            for s in sizes
        )
        + ".",
        "",
        f"Goal g: the collected M_L at t + {info['chunk_steps']}. Sweep `{info['sweep']}`, chunks "
        f"`{info['chunks']}`. Predicted values are `J_M` of `rmi rank` (biased toward W_T, "
        "which selected the chunk).",
    ]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------
# Driver


def _fingerprint(chunks_dir: Path, objectives: Iterable[str], command: str) -> str:
    parts = [f"command={command}"]
    parts += [f"{o}={_sha256(chunks_dir / f'chunks_{o}.npz')}" for o in sorted(objectives)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _window_rows(
    sim: Any,
    state: bytes,
    track: RunTrack,
    window: Window,
    chunks: Mapping[str, Mapping[str, np.ndarray]],
    h: int,
    substeps: int,
    command: str,
    replay_wall: float,
) -> list[dict[str, Any]]:
    t = window.t
    base = _window_base(track, window, h, command, replay_wall)
    goal = base["goal_kg"]
    recorded = np.stack(
        [track.water[t + 1 : t + h + 1], track.obs[t + 1 : t + h + 1, OBS.index("F_meas")]],
        axis=1,
    )
    jobs: list[tuple[str | None, str, np.ndarray, int | None, float | None]] = [
        (None, "original", track.actions[t : t + h, list(CONTROL_ACTION_INDEX)], None, None)
    ]
    for obj, i in window.rows:
        a = chunks[obj]
        sel = int(a["index"][i])
        jm = a.get("J_M_samples")
        jobs.append((obj, "first", a["first"][i], 0, None if jm is None else _finite(jm[i, 0])))
        jobs.append(
            (obj, "selected", a["selected"][i], sel, None if jm is None else _finite(jm[i, sel]))
        )
    rows = []
    for objective, which, chunk, sample, pred in jobs:
        t0 = time.perf_counter()
        res = execute_chunk(
            sim, state, np.asarray(chunk, dtype=np.float64), substeps, command, recorded
        )
        m = res["M_L"]
        rows.append(
            {
                **base,
                "objective": objective,
                "chunk": which,
                "sample_index": sample,
                "M_L_real_kg": m,
                "err_real_g": None if m is None else 1000.0 * abs(m - goal),
                "err_pred_g": pred,
                "status": res["status"],
                "failure": res["failure"],
                "phase_end": res["phase"],
                "dev_M_L_max_g": res["dev_M_L_max_g"],
                "dev_F_rms_N": res["dev_F_rms_N"],
                "error": res["error"],
                "wall_s": time.perf_counter() - t0,
            }
        )
    return rows


def _window_base(
    track: RunTrack, window: Window, h: int, command: str, replay_wall: float
) -> dict[str, Any]:
    """The columns every row of a window shares: where it is, its goal (kg) and the replay."""
    t = window.t
    return {
        "run_id": window.run_id,
        "size_cm": window.size_cm,
        "t": t,
        "k": int(track.k[t]),
        "anchor_time_s": float(track.k[t] * CONTROL_DT),
        "anchor_phase": str(track.phase[t]),
        "goal_phase": str(track.phase[t + h]),
        "command": command,
        "goal_kg": float(track.water[t + h]),
        "water_now_kg": float(track.water[t]),
        "replay_wall_s": replay_wall,
    }


def _failed_rows(
    track: RunTrack, window: Window, h: int, command: str, error: str, wall: float
) -> list[dict[str, Any]]:
    """Rows of a window whose replay to the anchor failed: every chunk not executed."""
    base = {
        **_window_base(track, window, h, command, wall),
        "status": "replay_failed",
        "error": error,
        "wall_s": 0.0,
    }
    rows = [{**base, "objective": None, "chunk": "original"}]
    for obj, _ in window.rows:
        rows += [{**base, "objective": obj, "chunk": c} for c in ("first", "selected")]
    return rows


def run_closed_loop(
    sweep_dir: str | os.PathLike[str],
    chunks_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    max_windows: int = 4,
    threads: int = 1,
    command: str = "force",
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Execute the original, first and selected chunks of ``chunks_dir`` (``rmi rank``
    output) in the simulator, starting from deterministic replays of the runs of
    ``sweep_dir`` (a sweep output with ``index.parquet``), and write the closed-loop tables
    to ``out_dir`` (see the module docstring).

    ``max_windows``: windows per sponge size, evenly spaced (0: every ranked window).
    ``threads``: engine threads per simulation (results do not depend on it). ``command``:
    ``both`` (F_target and v_cmd) or ``force`` (F_target, engine force regulation).
    Windows already in ``out_dir/closed_loop_windows.parquet`` are not executed again.
    Returns the summary written to ``table_closed_loop.json``. Raises
    :class:`ClosedLoopError` for unusable inputs.
    """
    if command not in COMMAND_MODES:
        raise ClosedLoopError(f"command must be one of {COMMAND_MODES}, got {command!r}")
    if max_windows < 0:
        raise ClosedLoopError("max_windows must be >= 0 (0: all windows)")
    if threads < 1:
        raise ClosedLoopError("threads must be >= 1")
    say = log or (lambda _msg: None)
    sweep, cdir, out = Path(sweep_dir), Path(chunks_dir), Path(out_dir)
    chunks = load_chunks(cdir)
    index = load_index(sweep)
    h = next(iter(chunks.values()))["original"].shape[1]
    windows = select_windows(chunks, max_windows)
    unknown = sorted({w.run_id for w in windows} - set(index))
    if unknown:
        raise ClosedLoopError(
            f"{len(unknown)} run(s) of the chunk files are not completed runs in "
            f"{sweep / INDEX_FILE}, e.g. {unknown[0]!r}: give the sweep the dataset was built from"
        )
    for rid in sorted({w.run_id for w in windows}):
        if not index[rid].exists():
            raise ClosedLoopError(f"run file {index[rid]} of {rid} is missing")

    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / WINDOWS_FILE
    fingerprint = _fingerprint(cdir, chunks, command)
    meta = {
        "rmi.closed_loop.fingerprint": fingerprint,
        "rmi.version": __version__,
        "rmi.closed_loop.command": command,
    }
    rows = _read_checkpoint(ckpt, fingerprint)
    done = {(r["run_id"], r["t"]) for r in rows}
    pending = [w for w in windows if (w.run_id, w.t) not in done]
    say(
        f"closed-loop: {len(windows)} windows ({len(windows) - len(pending)} already done), "
        f"objectives {sorted(chunks)}, command {command}"
    )

    rmi_sph = _sim_module()
    from tqdm.auto import tqdm  # type: ignore[import-untyped]

    by_run: dict[str, list[Window]] = {}
    for w in pending:
        by_run.setdefault(w.run_id, []).append(w)
    # Every input check that needs no simulation runs before the first (long) replay, so a
    # bad input stops the command at once rather than hours later.
    tracks: dict[str, RunTrack] = {}
    configs: dict[str, dict[str, Any]] = {}
    for rid, run_windows in by_run.items():
        track = load_track(index[rid])
        for w in run_windows:
            check_window(track, w, chunks, h)
        try:
            cfg = rmi_sph.validate_config(track.config)
        except rmi_sph.ConfigError as exc:
            raise ClosedLoopError(
                f"the stored config of run {rid} is refused by this engine: {exc}"
            ) from exc
        control_substeps(float(cfg["dt"]))
        tracks[rid] = track
        configs[rid] = cfg
    bar = tqdm(
        total=len(windows),
        initial=len(windows) - len(pending),
        desc="closed-loop",
        unit="window",
        disable=not progress,
        dynamic_ncols=True,
    )
    t_start = time.perf_counter()
    try:
        for rid in sorted(by_run):
            track = tracks[rid]
            run_windows = sorted(by_run[rid], key=lambda w: w.t)
            sim = rmi_sph.Trial(configs[rid], num_threads=threads)
            substeps = control_substeps(float(sim.dt))
            autonomous: bytes | None = None
            for w in run_windows:
                t0 = time.perf_counter()
                target = round(float(track.k[w.t]) * CONTROL_DT / float(sim.dt))
                error = None
                try:
                    if autonomous is not None:
                        sim.set_state(autonomous)
                    if target < sim.step_count:
                        raise ClosedLoopError("windows out of order")  # pragma: no cover
                    sim.step(target - sim.step_count)
                    state = sim.get_state()
                except rmi_sph.RmiError as exc:
                    error = f"{type(exc).__name__}: {exc}"
                replay_wall = time.perf_counter() - t0
                if error is not None:
                    new = _failed_rows(track, w, h, command, error, replay_wall)
                    autonomous = None
                else:
                    check_anchor(sim, track, w)
                    autonomous = state
                    new = _window_rows(
                        sim, state, track, w, chunks, h, substeps, command, replay_wall
                    )
                rows.extend(new)
                _write_checkpoint(ckpt, rows, meta)
                bar.set_postfix_str(f"{rid} t={w.t}", refresh=False)
                bar.update(1)
                if error is not None:
                    # The autonomous trajectory of this run is lost: its later windows fail too.
                    for rest in run_windows[run_windows.index(w) + 1 :]:
                        rows.extend(_failed_rows(track, rest, h, command, error, 0.0))
                        _write_checkpoint(ckpt, rows, meta)
                        bar.update(1)
                    break
    finally:
        bar.close()
    wall = time.perf_counter() - t_start

    summary = summarise(rows, windows)
    n_exec = len(pending)
    info = {
        "sweep": str(sweep),
        "chunks": str(cdir),
        "command": command,
        "threads": threads,
        "max_windows": max_windows,
        "chunk_steps": h,
        "control_dt_s": CONTROL_DT,
        "objectives": sorted(chunks),
        "unit": "g",
        "goal": "collected M_L at t + H (kg in data, g in the table)",
        "note": "real error executed in the simulator; *_pred_g are W_T's own predictions",
    }
    payload = {
        **info,
        "sizes": summary,
        "windows_total": len(windows),
        "windows_executed_now": n_exec,
        "wall_s": wall,
        "wall_s_per_window": (wall / n_exec) if n_exec else None,
        "version": __version__,
    }
    table3 = cdir / "table3_ranking.json"
    if table3.exists():
        # W_T's predictions over every ranked window (Table III of `rmi rank`), for comparison;
        # the per-window predictions of the executed windows are in `sizes`.
        try:
            payload["rank_table3_predicted"] = json.loads(table3.read_text())["rows"]
        except (ValueError, KeyError):
            pass
    atomic_write_json(out / f"{TABLE_STEM}.json", json_safe(payload))
    md = _markdown(summary, info)
    atomic_write_bytes(out / f"{TABLE_STEM}.md", lambda f: f.write(md.encode("utf-8")))
    say(f"closed-loop: {n_exec} windows executed in {wall:.1f} s -> {out}")
    return payload


def _finite(x: Any) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None


__all__ = [
    "ClosedLoopError",
    "RunTrack",
    "Window",
    "check_anchor",
    "check_window",
    "control_substeps",
    "execute_chunk",
    "load_chunks",
    "load_index",
    "load_track",
    "run_closed_loop",
    "select_windows",
    "summarise",
]
