"""Executing a window's chunks from its anchor, and the rows they give."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from rmi_learn.closed_loop.windows import Window
from rmi_learn.data.schema import CONTROL_ACTION_INDEX, CONTROL_DT, OBS
from rmi_learn.sim.execute import execute_forces
from rmi_learn.sim.replay import RunTrack


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
    (``command`` ``force``, the only mode; see :func:`rmi_learn.sim.execute.execute_forces`).

    Returns ``status`` (``ok``, ``unstable``, ``error``, ``invalid_chunk``), ``M_L`` (kg
    after the last command, None unless ok), ``phase`` and ``failure`` at the end, and,
    when ``recorded`` (H, 2) holds the recorded M_L (kg) and F_meas (N) at the ends of the
    H control steps, ``dev_M_L_max_g`` (g) and ``dev_F_rms_N`` (N), the deviation from the
    recorded trajectory (loads averaged over each control step).
    """
    out: dict[str, Any] = {
        "status": "ok",
        "M_L": None,
        "phase": None,
        "failure": None,
        "dev_M_L_max_g": None,
        "dev_F_rms_N": None,
        "error": None,
    }
    # Checked before the state is touched, with this experiment's own wording.
    if not np.all(np.isfinite(chunk)):
        out["status"] = "invalid_chunk"
        out["error"] = "the chunk holds non-finite commands"
        return out
    e = execute_forces(sim, state, chunk[:, 0], substeps, keep_records=True)
    if e.status != "ok":
        out["status"], out["error"] = e.status, e.error
        return out
    traj = np.asarray([(r["M_L"], r["F_meas"]) for r in e.records], dtype=np.float64)
    out["M_L"] = float(traj[-1, 0])
    out["phase"] = e.phase
    out["failure"] = e.failure
    if recorded is not None:
        out["dev_M_L_max_g"] = float(1000.0 * np.max(np.abs(traj[:, 0] - recorded[:, 0])))
        out["dev_F_rms_N"] = float(np.sqrt(np.mean((traj[:, 1] - recorded[:, 1]) ** 2)))
    return out


def window_rows(
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
    """Execute the original chunk and every objective's first and selected chunk of
    ``window`` from the anchor ``state``: one row each."""
    t = window.t
    base = window_base(track, window, h, command, replay_wall)
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


def window_base(
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


def failed_rows(
    track: RunTrack, window: Window, h: int, command: str, error: str, wall: float
) -> list[dict[str, Any]]:
    """Rows of a window whose replay to the anchor failed: every chunk not executed."""
    base = {
        **window_base(track, window, h, command, wall),
        "status": "replay_failed",
        "error": error,
        "wall_s": 0.0,
    }
    rows = [{**base, "objective": None, "chunk": "original"}]
    for obj, _ in window.rows:
        rows += [{**base, "objective": obj, "chunk": c} for c in ("first", "selected")]
    return rows


def _finite(x: Any) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None


__all__ = ["execute_chunk", "failed_rows", "window_base", "window_rows"]
