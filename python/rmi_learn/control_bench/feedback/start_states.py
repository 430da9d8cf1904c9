"""A run's start states: replayed once from the run's own trial and kept on disk, so that the
release probes, the tuning and the test executions of one run share one replay.

The engine continues a restored state bit-identically, so an episode from a state read back
is the episode from the state replayed. A file is named by a hash of what the replay depends
on (the engine's version, the run's config, the start ticks, the history kept and the steps
replayed past the last tick); one that does not match, or cannot be read, is replayed again.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import rmi_sph
from rmi_learn.control_bench.feedback.held_out import RunInfo, substeps_of
from rmi_learn.data.runs import atomic_write_bytes

#: The folder of a benchmark's output that holds the start states while it runs.
STATES_DIR = "start_states"


@dataclass
class Snapshot:
    """A start state: its bytes, the true records of the control steps up to it, and the
    logged controller's next setpoints (N)."""

    tick: int
    state: bytes
    history: list[dict[str, Any]]
    scripted: list[float]


@dataclass(frozen=True)
class Replay:
    """What one run's replay keeps: every start ``ticks`` of the run (whatever their role),
    ``ahead`` control steps past the last (the logged setpoints the scripted controller
    repeats; 0 when no test state needs them), the control steps of history per state, and
    the folder the states are kept in (None: not kept)."""

    ticks: tuple[int, ...]
    ahead: int
    history: int
    folder: Path | None = None


def replay(run: RunInfo, spec: Replay, threads: int) -> tuple[Any, list[Snapshot]]:
    """Step the run's own trial tick by tick and keep each start tick's state; returns the
    trial too, which the episodes restore their states into."""
    sim = rmi_sph.Trial(run.config, num_threads=threads)
    n = substeps_of(run)
    records: list[dict[str, Any]] = [sim.take_record()]
    pending = sorted(spec.ticks)
    snaps: dict[int, tuple[bytes, list[dict[str, Any]]]] = {}
    for k in range(1, pending[-1] + spec.ahead + 1):
        sim.step(n)
        records.append(sim.take_record())
        if k in pending:
            snaps[k] = (sim.get_state(), records[max(0, k + 1 - spec.history) : k + 1])
    return sim, [
        Snapshot(
            k,
            snaps[k][0],
            snaps[k][1],
            [float(r["F_target"]) for r in records[k + 1 : k + 1 + spec.ahead]],
        )
        for k in pending
    ]


def _path(run: RunInfo, spec: Replay) -> Path:
    assert spec.folder is not None
    what = [rmi_sph.__version__, run.config, sorted(spec.ticks), spec.ahead, spec.history]
    key = hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:20]
    return spec.folder / f"{key}.npz"


def _save(path: Path, snaps: Sequence[Snapshot]) -> None:
    arrays: dict[str, Any] = {"ticks": np.array([s.tick for s in snaps], dtype=np.int64)}
    for s in snaps:
        arrays[f"state_{s.tick}"] = np.frombuffer(s.state, dtype=np.uint8)
        arrays[f"history_{s.tick}"] = np.array(json.dumps(s.history))
        arrays[f"scripted_{s.tick}"] = np.array(s.scripted, dtype=np.float64)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, lambda f: f.write(buf.getvalue()))


def _load(path: Path) -> list[Snapshot] | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            return [
                Snapshot(
                    int(k),
                    z[f"state_{k}"].tobytes(),
                    json.loads(str(z[f"history_{k}"])),
                    [float(x) for x in z[f"scripted_{k}"]],
                )
                for k in z["ticks"]
            ]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def start_states(
    run: RunInfo, spec: Replay, ticks: Sequence[int], threads: int
) -> tuple[Any, list[Snapshot]]:
    """The trial of ``run`` and its states at ``ticks`` (a subset of ``spec.ticks``), read
    from ``spec.folder`` when an earlier phase kept them, else replayed (and kept)."""
    path = _path(run, spec) if spec.folder is not None else None
    snaps = _load(path) if path is not None and path.exists() else None
    if snaps is None:
        sim, snaps = replay(run, spec, threads)
        if path is not None:
            _save(path, snaps)
    else:
        sim = rmi_sph.Trial(run.config, num_threads=threads)
    wanted = set(ticks)
    return sim, [s for s in snaps if s.tick in wanted]


__all__ = ["STATES_DIR", "Replay", "Snapshot", "replay", "start_states"]
