"""Held-out conditions and start states.

Leave one group out: per sponge size every (porosity, F_hold) group is once the test
condition of a fold whose choices (PI gains, the estimators' constants and fits) come from
the other groups' runs and states only. Start states are control steps of a run in the
protocol's start phases (the sponge lifted) with room for the horizon, drawn with the
states seed: tuning states per group, and test states spread over the runs with at most a
few per run, so that runs are the clusters of the bootstrap.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.runs import read_run, read_run_meta
from rmi_learn.data.schema import CONTROL_DT
from rmi_learn.sim.replay import control_substeps


@dataclass(frozen=True)
class RunInfo:
    """A run of the sweep: its id, file, parameters and config."""

    run_id: str
    path: Path
    size_cm: int
    porosity: float
    F_hold: float
    F_squeeze: float
    seed: int
    config: dict[str, Any]

    @property
    def group(self) -> tuple[int, float, float]:
        return (self.size_cm, self.porosity, self.F_hold)


@dataclass(frozen=True)
class StartTick:
    """A start state: control step ``tick`` (time ``tick * 20 ms``) of run ``run_id``."""

    run_id: str
    tick: int
    role: str  # "tuning" or "test"


def read_runs(index: Mapping[str, Path]) -> list[RunInfo]:
    """The runs of a sweep index, sorted by id."""
    out = []
    for rid in sorted(index):
        meta = read_run_meta(index[rid])
        p = meta["params"]
        out.append(
            RunInfo(
                rid,
                index[rid],
                int(p["size_cm"]),
                float(p["porosity"]),
                float(p["F_hold"]),
                float(p["F_squeeze"]),
                int(p["seed"]),
                dict(meta["config"]),
            )
        )
    return out


def fold_of(run: RunInfo) -> str:
    """The fold a run is tested in: its (porosity, F_hold) group, held out."""
    return f"{run.porosity:g}/{run.F_hold:g}"


def folds(runs: Sequence[RunInfo], size: int) -> list[str]:
    """The folds of one size (one per group); a size with one group has none."""
    labels = sorted({fold_of(r) for r in runs if r.size_cm == size})
    return labels if len(labels) >= 2 else []


def run_ticks(run: RunInfo, phases: Sequence[str], room: int) -> np.ndarray:
    """Control steps of ``run`` whose recorded phase is in ``phases`` and that leave
    ``room`` control steps of record after them."""
    df, _ = read_run(run.path)
    t = df["time"].to_numpy()
    ph = df["phase"].to_numpy().astype(str)
    k_end = int(np.floor(t[-1] / CONTROL_DT + 1e-6))
    ticks = np.arange(1, k_end - room + 1)
    idx = np.clip(np.searchsorted(t, ticks * CONTROL_DT - 1e-9), 0, t.size - 1)
    return ticks[np.isin(ph[idx], list(phases))]


def draw_states(runs: Sequence[RunInfo], states: Mapping[str, Any], room: int) -> list[StartTick]:
    """The protocol's states per size: ``tuning_per_group`` tuning states per group (from
    distinct runs) and ``test_per_size`` test states, at most ``max_per_run`` a run, spread
    over the runs round-robin in a seeded order."""
    out: list[StartTick] = []
    seed = int(states["seed"])
    for size in sorted({r.size_cm for r in runs}):
        if not folds(runs, size):
            continue
        mine = [r for r in runs if r.size_cm == size]
        ticks = {r.run_id: run_ticks(r, states["phases"], room) for r in mine}
        for fold in folds(runs, size):
            group = [r for r in mine if fold_of(r) == fold and ticks[r.run_id].size]
            order = np.random.default_rng([seed, size, 1, len(out)]).permutation(len(group))
            for i in order[: int(states["tuning_per_group"])]:
                r = group[i]
                k = np.random.default_rng([seed, size, 2, int(i)]).choice(ticks[r.run_id])
                out.append(StartTick(r.run_id, int(k), "tuning"))
        rng = np.random.default_rng([seed, size, 3])
        order = [mine[i] for i in rng.permutation(len(mine))]
        left = {r.run_id: [int(k) for k in rng.permutation(ticks[r.run_id])] for r in order}
        picked = 0
        for _ in range(int(states["max_per_run"])):
            for r in order:
                if picked < int(states["test_per_size"]) and left[r.run_id]:
                    out.append(StartTick(r.run_id, int(left[r.run_id].pop()), "test"))
                    picked += 1
    return out


def substeps_of(run: RunInfo) -> int:
    """Engine steps per control step of the run's config."""
    return control_substeps(float(run.config["dt"]))


__all__ = [
    "RunInfo",
    "StartTick",
    "draw_states",
    "fold_of",
    "folds",
    "read_runs",
    "run_ticks",
    "substeps_of",
]
