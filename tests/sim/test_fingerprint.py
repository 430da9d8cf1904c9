"""Fingerprints of an engine state (rmi_learn.sim.fingerprint): states that differ only in
the squeeze force, which external force commands never use, share one fingerprint."""

from __future__ import annotations

import rmi_sph
from rmi_learn.sim.fingerprint import state_bytes_hash, state_fingerprint
from tiny_trial import TINY


def test_the_squeeze_force_is_left_out_of_the_fingerprint() -> None:
    a, b = (
        rmi_sph.Trial(rmi_sph.trial_config(8, 0.8, 20.0, f, 0.01, **TINY), num_threads=1)
        for f in (150.0, 120.0)
    )
    for sim in (a, b):
        sim.step(5)
    assert state_fingerprint(a) == state_fingerprint(b)
    assert state_bytes_hash(a.get_state()) != state_bytes_hash(b.get_state())
    a.step(1)
    assert state_fingerprint(a) != state_fingerprint(b)
