"""Folds and start states of the protocol benchmark (control_bench.feedback.held_out): one fold
per (porosity, F_hold) group, tuning states from distinct runs of each group, test states in
the start phases with at most ``max_per_run`` a run, the same draw for the same seed."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from rmi_learn.control_bench.feedback.held_out import (
    RunInfo,
    draw_states,
    fold_of,
    folds,
    run_ticks,
)
from rmi_learn.data.runs import iter_run_files, read_run

STATES = {
    "phases": ["squeeze"],
    "tuning_per_group": 2,
    "test_per_size": 10,
    "max_per_run": 2,
    "seed": 3,
}


def _runs(root: Path) -> list[RunInfo]:
    out = []
    for path in sorted(iter_run_files(root)):
        _, meta = read_run(path)
        p = meta["params"]
        rid = str(path.relative_to(root).parent)
        out.append(
            RunInfo(
                rid,
                path,
                int(p["size_cm"]),
                float(p["porosity"]),
                float(p["F_hold"]),
                float(p["F_squeeze"]),
                int(p["seed"]),
                dict(meta.get("config") or {}),
            )
        )
    return out


def test_every_group_is_one_fold(synthetic_runs_dir: Path) -> None:
    runs = _runs(synthetic_runs_dir)
    for size in {r.size_cm for r in runs}:
        assert folds(runs, size) == sorted({fold_of(r) for r in runs if r.size_cm == size})


def test_states_are_spread_over_runs_in_the_start_phases(synthetic_runs_dir: Path) -> None:
    runs = _runs(synthetic_runs_dir)
    ticks = draw_states(runs, STATES, room=8)
    assert ticks == draw_states(runs, STATES, room=8)
    info = {r.run_id: r for r in runs}
    for size in {r.size_cm for r in runs}:
        test = [t for t in ticks if t.role == "test" and info[t.run_id].size_cm == size]
        assert len(test) == STATES["test_per_size"]
        assert max(Counter(t.run_id for t in test).values()) <= STATES["max_per_run"]
        assert len({(t.run_id, t.tick) for t in test}) == len(test)
        tune = [t for t in ticks if t.role == "tuning" and info[t.run_id].size_cm == size]
        per_group = Counter(fold_of(info[t.run_id]) for t in tune)
        assert set(per_group.values()) <= {1, 2}
        assert len({t.run_id for t in tune}) == len(tune)
    for t in ticks:
        assert t.tick in set(run_ticks(info[t.run_id], ["squeeze"], 8).tolist())
