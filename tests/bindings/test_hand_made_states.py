"""States edited by hand and sealed again with a valid checksum: a particle's mass made NaN,
0 or -1, or an id given to two particles, is refused with the `StateError` of any other bad
state, naming the field and the particle, through every way of restoring a state; it never
reaches a step (where a NaN mass made the engine panic)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import rmi_sph
from rmi_sph import engine

#: Header of an engine snapshot, alone or inside a trial state.
SNAPSHOT_MAGIC = b"RMISNAP\0"
U64 = struct.Struct("<Q")


def tiny_trial() -> rmi_sph.Trial:
    """The 8 cm sponge at r = 10 mm (about 230 particles)."""
    return rmi_sph.Trial(rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=3), num_threads=1)


def fnv1a64(data: bytes) -> int:
    """The checksum the engine seals its states with (64-bit FNV-1a)."""
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def reseal(sealed: bytes) -> bytes:
    """`sealed` with its trailing checksum recomputed as the writer computes it."""
    body = sealed[:-8]
    return body + U64.pack(fnv1a64(body))


def replace_once(data: bytes, old: bytes, new: bytes) -> bytes:
    at = data.find(old)
    assert at >= 0 and data.find(old, at + 1) < 0, "the array is not found exactly once"
    return data[:at] + new + data[at + len(old) :]


def edit_array(state: bytes, old: np.ndarray, new: np.ndarray) -> bytes:
    """`state` (an engine snapshot or a trial state holding one) with the particle array
    `old` replaced by `new`, every checksum recomputed. Arrays are stored as their length
    (u64) then their little-endian values."""
    assert old.dtype == new.dtype and old.shape == new.shape
    prefix = U64.pack(len(old))
    start = state.find(SNAPSHOT_MAGIC)
    (length,) = U64.unpack(state[start - 8 : start]) if start > 0 else (len(state),)
    snapshot = state[start : start + length]
    edited = reseal(replace_once(snapshot, prefix + old.tobytes(), prefix + new.tobytes()))
    if start == 0:
        return edited
    return reseal(state[:start] + edited + state[start + length :])


def columns(
    particles: Callable[[str], dict], kinds: tuple[str, str], key: str, dtype: str
) -> np.ndarray:
    """One column of every dynamic particle in the engine's order (water, then skeleton)."""
    return np.concatenate([particles(k)[key] for k in kinds]).astype(dtype)


def mass_edits(n: int) -> list[tuple[int, float]]:
    """(particle, mass) pairs the check must refuse: NaN water, zero water, a negative
    skeleton particle."""
    return [(3, float("nan")), (3, 0.0), (n - 1, -1.0)]


def refused(restore: Callable[[bytes], object], state: bytes, match: str) -> str:
    with pytest.raises(rmi_sph.StateError, match=match) as err:
        restore(state)
    message = str(err.value)
    assert "panic" not in message and "please report" not in message, message
    assert "\n" not in message
    return message


def trial_restores(tmp_path: Path) -> list[Callable[[bytes], object]]:
    """Every way of restoring a trial state: from_state, set_state and load."""

    def load(state: bytes) -> object:
        path = tmp_path / "edited.state"
        path.write_bytes(state)
        return rmi_sph.Trial.load(path, num_threads=1)

    return [lambda s: rmi_sph.Trial.from_state(s, num_threads=1), tiny_trial().set_state, load]


def test_trial_states_with_bad_masses_are_refused_on_every_path(tmp_path: Path) -> None:
    t = tiny_trial()
    t.step(2)
    state = t.get_state()
    masses = columns(t.particles, ("fluid", "solid"), "mass", "<f8")
    # A mass changed within its range passes: the checksum is recomputed as the writer does.
    ok = masses.copy()
    ok[3] *= 1.01
    rmi_sph.Trial.from_state(edit_array(state, masses, ok), num_threads=1).step(2)
    for restore in trial_restores(tmp_path):
        for a, mass in mass_edits(len(masses)):
            bad = masses.copy()
            bad[a] = mass
            message = refused(restore, edit_array(state, masses, bad), rf"particle {a}: `mass` = ")
            assert "kg is not accepted; expected a finite value in [" in message, message


def test_trial_states_with_a_duplicate_id_are_refused_on_every_path(tmp_path: Path) -> None:
    t = tiny_trial()
    t.step(2)
    state = t.get_state()
    ids = columns(t.particles, ("fluid", "solid"), "id", "<u4")
    bad = ids.copy()
    bad[5] = ids[4]
    for restore in trial_restores(tmp_path):
        message = refused(restore, edit_array(state, ids, bad), r"particle 5: `id` = ")
        assert "particle 4 holds it" in message and f"[0, {len(ids)})" in message, message


def test_engine_states_with_bad_masses_or_ids_are_refused() -> None:
    sim = engine.Simulation(engine.sponge(rmi_sph.SPONGE_SIZES_M[0], 0.6, 0.01), num_threads=1)
    sim.step(2)
    state = sim.get_state()
    kinds = ("fluid", "porous")
    masses = columns(sim.particles, kinds, "mass", "<f8")
    ids = columns(sim.particles, kinds, "id", "<u4")
    before = sim.get_state()
    for a, mass in mass_edits(len(masses)):
        bad = masses.copy()
        bad[a] = mass
        edited = edit_array(state, masses, bad)
        refused(
            lambda s: engine.Simulation.from_state(s, num_threads=1),
            edited,
            rf"particle {a}: `mass` = ",
        )
        refused(sim.set_state, edited, rf"particle {a}: `mass` = ")
    bad = ids.copy()
    bad[5] = ids[4]
    refused(
        lambda s: engine.Simulation.from_state(s, num_threads=1),
        edit_array(state, ids, bad),
        "`id`",
    )
    assert sim.get_state() == before
    sim.step(1)
