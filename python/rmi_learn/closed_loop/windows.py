"""The closed-loop experiment's inputs: the chunk files of ``rmi rank``, the windows to
execute, and the check that a window of those files is the run's own rows."""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.schema import CONTROL_ACTION_INDEX, CONTROL_ACTIONS
from rmi_learn.errors import InputError
from rmi_learn.sim.replay import ReplayError, RunTrack

#: Policy objectives whose chunk files ``rmi rank`` writes (``chunks_<objective>.npz``).
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")
#: Chunks executed per window; ``original`` is shared by the objectives.
CHUNKS: tuple[str, ...] = ("original", "first", "selected")
COMMAND_MODES: tuple[str, ...] = ("force",)
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
#: The npz holds float32 values converted from standardised units; these tolerances only
#: absorb that rounding (a different window or run differs by far more).
_KG_TOL = 1e-5  # kg
_FORCE_TOL = 1e-3  # N
_REL_TOL = 1e-4


class ClosedLoopError(InputError, ValueError):
    """Inputs that cannot be executed (missing files, unknown runs, npz/run mismatch, a
    replay that does not reproduce the stored record); the ``rmi`` commands report it with
    exit code 2."""


@contextmanager
def as_closed_loop_error() -> Iterator[None]:
    """Report a stored run that cannot be replayed as a :class:`ClosedLoopError` (same
    message): to the closed loop's callers, such a run is an input it cannot execute."""
    try:
        yield
    except ReplayError as exc:
        raise ClosedLoopError(str(exc)) from exc


@dataclass(frozen=True)
class Window:
    """One ranked window: the run, the sponge size (cm), the anchor's kept-row index ``t``
    and, per objective, the row of that objective's npz holding its chunks."""

    run_id: str
    size_cm: int
    t: int
    rows: tuple[tuple[str, int], ...]


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


__all__ = [
    "CHUNKS",
    "COMMAND_MODES",
    "NPZ_KEYS",
    "OBJECTIVES",
    "ClosedLoopError",
    "Window",
    "as_closed_loop_error",
    "check_window",
    "load_chunks",
    "select_windows",
]
