"""Executing force-setpoint chunks in the engine (rmi_learn.sim.execute): the same state and
chunk give the same bits, setpoints are clipped to the gripper's range, and a chunk with a
non-finite setpoint is refused before any step."""

from __future__ import annotations

import numpy as np
import pytest

import rmi_sph
from rmi_learn.closed_loop.execute import execute_chunk
from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.sim.execute import clip_force, execute_forces, run_forces
from rmi_learn.sim.replay import control_substeps
from tiny_trial import tiny_config

H = 8


@pytest.fixture(scope="module")
def anchored() -> tuple[rmi_sph.Trial, bytes, int]:
    """A tiny trial stepped into its hold, its state saved there."""
    sim = rmi_sph.Trial(tiny_config(), num_threads=1)
    sim.step(round(0.2 / sim.dt))
    return sim, sim.get_state(), control_substeps(float(sim.dt))


def test_clip_force_keeps_setpoints_in_the_grippers_range() -> None:
    assert clip_force(-3.0) == 0.0 and clip_force(FORCE_LIMIT_N + 1.0) == FORCE_LIMIT_N
    assert clip_force(42.5) == 42.5


def test_a_chunk_executed_twice_gives_the_same_bits(
    anchored: tuple[rmi_sph.Trial, bytes, int],
) -> None:
    sim, state, sub = anchored
    chunk = np.linspace(20.0, 200.0, H)
    a = execute_forces(sim, state, chunk, sub, keep_records=True)
    b = execute_forces(sim, state, chunk, sub, keep_records=True)
    assert a.status == b.status == "ok" and len(a.records) == H
    assert a.M_L == b.M_L and a.peak_force_N == b.peak_force_N and a.phase == b.phase
    assert [r["M_L"] for r in a.records] == [r["M_L"] for r in b.records]
    assert a.M_L == a.records[-1]["M_L"]
    assert a.peak_force_N == max(r["F_meas"] for r in a.records)
    # The same commands applied from the restored state by hand.
    sim.set_state(state)
    sim.take_record()
    c = run_forces(sim, chunk, sub)
    assert c.M_L == a.M_L and c.records == []


def test_the_closed_loop_executes_chunks_the_same_way(
    anchored: tuple[rmi_sph.Trial, bytes, int],
) -> None:
    sim, state, sub = anchored
    chunk = np.linspace(20.0, 200.0, H)
    e = execute_forces(sim, state, chunk, sub, keep_records=True)
    res = execute_chunk(sim, state, chunk[:, None], sub, "force")
    assert res["status"] == "ok" and res["M_L"] == e.M_L
    assert res["phase"] == e.phase and res["failure"] == e.failure


def test_non_finite_setpoints_are_refused_with_each_callers_wording(
    anchored: tuple[rmi_sph.Trial, bytes, int],
) -> None:
    sim, state, sub = anchored
    chunk = np.full(H, 50.0)
    chunk[3] = np.nan
    e = execute_forces(sim, state, chunk, sub)
    assert e.status == "invalid_chunk" and e.M_L is None
    assert e.error == "the chunk holds non-finite setpoints"
    res = execute_chunk(sim, state, chunk[:, None], sub, "force")
    assert res["status"] == "invalid_chunk" and res["M_L"] is None
    assert res["error"] == "the chunk holds non-finite commands"
