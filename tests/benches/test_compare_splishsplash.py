"""Round bookkeeping of benches/compare_splishsplash.py (the dam-break throughput comparison).

Only the pure summary functions are exercised: running either engine takes minutes and
SPlisHSPlasH is not a test dependency.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


def _run(ms: float, load: float | None, engine: str) -> dict[str, Any]:
    return {
        "engine": engine,
        "fluid_particles": 59319,
        "ms_per_step": ms,
        "particle_steps_per_s": 59319 / (ms * 1e-3),
        "mean_pressure_iterations": 3.5,
        "other_load": load,
    }


def _round(
    k: int,
    sph_ms: float,
    rmi_ms: float,
    sph_load: float | None = 0.01,
    rmi_load: float | None = 0.0,
) -> dict[str, Any]:
    return {
        "round": k,
        "splishsplash": _run(sph_ms, sph_load, "splishsplash-dfsph"),
        "rmi": _run(rmi_ms, rmi_load, "rmi"),
    }


def test_a_noisy_round_is_set_aside_whole_and_the_ratios_are_per_round(
    bench_script: Callable[[str], Any],
) -> None:
    m = bench_script("compare_splishsplash")
    rounds = [
        _round(1, 120.0, 50.0),
        _round(2, 100.0, 50.0),
        # My own build ran beside rmi here: its time doubled, the round says nothing.
        _round(3, 130.0, 110.0, rmi_load=1.15),
        _round(4, 90.0, 45.0, sph_load=None, rmi_load=None),
    ]
    quiet = m.quiet_rounds(rounds)
    assert [e["round"] for e in quiet] == [1, 2, 4]
    p = m.paired(rounds)
    assert p["quiet_rounds"] == 3 and p["set_aside"] == 1
    assert [r["quiet"] for r in p["rounds"]] == [True, True, False, True]
    assert p["rounds"][2]["other_load"] == pytest.approx(1.15)
    assert p["rounds"][0]["ratio"] == pytest.approx(2.4)
    assert p["median"] == pytest.approx(2.0)
    assert (p["min"], p["max"]) == (pytest.approx(2.0), pytest.approx(2.4))
    # The engines' medians come from the same rounds: the noisy rmi run is not among them.
    rmi = m.summarize([e["rmi"] for e in quiet])
    assert rmi["ms_per_step"] == pytest.approx(50.0)
    assert m.summarize([e["rmi"] for e in rounds])["ms_per_step"] == pytest.approx(50.0)
    sph = m.summarize([e["splishsplash"] for e in quiet])
    assert sph["ms_per_step"] == pytest.approx(100.0) and sph["rounds"] == 3


def test_failed_or_one_sided_rounds_give_no_ratio(bench_script: Callable[[str], Any]) -> None:
    m = bench_script("compare_splishsplash")
    rounds = [
        _round(1, 100.0, 40.0),
        {
            "round": 2,
            "splishsplash": {"error": "crashed", "other_load": 0.0},
            "rmi": _run(40, 0, "rmi"),
        },
        {"round": 3, "rmi": _run(40.0, 0.0, "rmi")},
    ]
    p = m.paired(rounds)
    assert [r["round"] for r in p["rounds"]] == [1]
    assert p["median"] == pytest.approx(2.5)


def test_no_quiet_round_leaves_no_median(bench_script: Callable[[str], Any]) -> None:
    m = bench_script("compare_splishsplash")
    rounds = [_round(1, 100.0, 50.0, sph_load=0.5), _round(2, 100.0, 50.0, rmi_load=0.2)]
    assert m.quiet_rounds(rounds) == []
    p = m.paired(rounds)
    assert p["quiet_rounds"] == 0 and p["set_aside"] == 2
    assert p["median"] is None and p["min"] is None
    # A stricter threshold is the caller's choice.
    assert m.paired(rounds, max_load=1.0)["quiet_rounds"] == 2
