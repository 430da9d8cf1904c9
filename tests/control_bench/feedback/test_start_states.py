"""A run's start states kept between the benchmark's phases (control_bench.feedback.
start_states): a state read back continues as the replayed one, bit for bit; the file of
another replay is not used; an unreadable file is replayed again."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import rmi_sph
from rmi_learn.control_bench.feedback.held_out import RunInfo, substeps_of
from rmi_learn.control_bench.feedback.start_states import Replay, Snapshot, start_states
from tiny_trial import tiny_config


def _run() -> RunInfo:
    return RunInfo("r0", Path("r0.parquet"), 8, 0.8, 20.0, 150.0, 0, tiny_config())


def _same(a: Snapshot, b: Snapshot) -> bool:
    """Equal snapshots (a record's NaN, e.g. the slip speed without contact, included)."""
    return (a.tick, a.state, a.scripted, json.dumps(a.history)) == (
        b.tick,
        b.state,
        b.scripted,
        json.dumps(b.history),
    )


def _continue(sim: Any, state: bytes, steps: int, substeps: int) -> list[dict[str, Any]]:
    sim.set_state(state)
    out = []
    for _ in range(steps):
        sim.set_action(60.0)
        sim.step(substeps)
        out.append(sim.take_record())
    return out


def test_a_kept_state_continues_bit_identically(tmp_path: Path) -> None:
    run, spec = _run(), Replay((3, 6), 4, 3, tmp_path)
    sim, replayed = start_states(run, spec, [3, 6], 1)
    (kept,) = list(tmp_path.iterdir())
    again, read = start_states(run, spec, [6], 1)
    assert [s.tick for s in read] == [6]
    assert _same(read[0], replayed[1])
    assert len(read[0].history) == 3 and len(read[0].scripted) == 4
    n = substeps_of(run)
    ours = _continue(again, read[0].state, 3, n)
    assert json.dumps(ours) == json.dumps(_continue(sim, replayed[1].state, 3, n))
    assert list(tmp_path.iterdir()) == [kept]


def test_another_replay_or_an_unreadable_file_is_replayed(tmp_path: Path) -> None:
    run = _run()
    _, first = start_states(run, Replay((3, 6), 0, 3, tmp_path), [3, 6], 1)
    _, other = start_states(run, Replay((3, 6), 4, 3, tmp_path), [3, 6], 1)
    assert len(list(tmp_path.iterdir())) == 2
    assert [s.scripted for s in first] == [[], []] and all(len(s.scripted) == 4 for s in other)
    files = sorted(tmp_path.iterdir())
    files[0].write_bytes(b"not a state")
    files[1].write_bytes(files[1].read_bytes()[:-40])  # a zip cut short
    _, read = start_states(run, Replay((3, 6), 0, 3, tmp_path), [3], 1)
    assert len(read) == 1 and _same(read[0], first[0])
    _, read = start_states(run, Replay((3, 6), 4, 3, tmp_path), [6], 1)
    assert len(read) == 1 and _same(read[0], other[1])
    fresh = rmi_sph.Trial(tiny_config(), num_threads=1)
    assert fresh.get_state() != read[0].state
