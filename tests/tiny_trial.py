"""The small, fast trial the binding, environment and VTK tests share: the 8 cm sponge at
r = 1 cm, dt = 2 ms, with short phases (holding 20 N, squeezing 150 N, porosity 0.8) and a
permeable foam (1e-9 m^2, the default is 3e-11) so that its 0.4 s of contact expels water and
the liquid bookkeeping has something to count."""

from __future__ import annotations

from typing import Any

import rmi_sph

TINY: dict[str, Any] = dict(
    dt=2e-3,
    settle_time=0.05,
    ramp_time=0.1,
    hold_time=0.1,
    wait_time=0.05,
    squeeze_ramp_time=0.1,
    squeeze_hold_time=0.1,
    material={"permeability": 1e-9},
)


def tiny_config(**kw: Any) -> dict[str, Any]:
    """The tiny trial config; keyword arguments override `TINY` or add `trial_config` ones."""
    return rmi_sph.trial_config(8, 0.8, 20.0, 150.0, 0.01, **{**TINY, **kw})


def records_until(sim: Any, phase: str, substeps: int) -> list[dict[str, Any]]:
    """Step ``sim`` one control step (``substeps`` engine steps) at a time until its phase is
    ``phase``; the records from the start, the last one at the first step in ``phase``."""
    recs = [sim.take_record()]
    while sim.phase != phase:
        sim.step(substeps)
        recs.append(sim.take_record())
    return recs
