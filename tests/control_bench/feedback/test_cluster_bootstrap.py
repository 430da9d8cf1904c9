"""Summaries that respect clustering (control_bench.feedback.clusters): runs are resampled
whole, ratios and paired counts are taken against the reference of the same mode."""

from __future__ import annotations

import numpy as np

from rmi_learn.control_bench.feedback.clusters import TIE_G, cluster_bootstrap, summarise_cell

MODES = {"ref": "sensors", "a": "sensors", "p": "privileged"}


def _rows(ctrl: str, errs: list[float], runs: list[str]) -> list[dict]:
    return [
        {"controller": ctrl, "run_id": r, "tick": i, "abs_error_g": e}
        for i, (e, r) in enumerate(zip(errs, runs, strict=True))
    ]


def test_a_constant_sample_has_a_point_interval() -> None:
    v = np.full(6, 2.5)
    lo, hi = cluster_bootstrap(v, list("aabbcc"), np.mean, np.random.default_rng(0), 200)
    assert lo == hi == 2.5


def test_states_of_one_run_move_together() -> None:
    # Two runs: one of 10 states at 0, one of 10 at 1. Resampling runs gives means 0, 0.5 or
    # 1 only; resampling states independently would give many values in between.
    v = np.r_[np.zeros(10), np.ones(10)]
    runs = ["r0"] * 10 + ["r1"] * 10
    rng = np.random.default_rng(1)
    seen = {cluster_bootstrap(v, runs, np.mean, rng, 100)[0] for _ in range(5)}
    assert seen <= {0.0, 0.5}


def test_ratios_and_paired_counts_are_against_the_modes_reference() -> None:
    runs = ["r0", "r0", "r1", "r2"]
    rows = _rows("ref", [2.0, 4.0, 2.0, 2.0], runs) + _rows(
        "a", [1.0, 2.0, 1.0, 2.0 + TIE_G / 2], runs
    )
    rows += _rows("p", [0.1, 0.1, 0.1, 0.1], runs)
    lines = {
        x["controller"]: x
        for x in summarise_cell(rows, ["ref", "a", "p"], {"sensors": "ref"}, MODES, 200, 0)
    }
    a = lines["a"]
    assert a["states"] == 4 and a["runs"] == 3
    assert a["ratio_to_reference"] == np.mean([1.0, 2.0, 1.0, 2.0 + TIE_G / 2]) / 2.5
    assert a["wins_ties_losses"] == [3, 1, 0]
    assert "ratio_to_reference" not in lines["ref"]
    assert lines["p"]["median_g"] == 0.1


def test_failed_executions_are_counted_not_scored() -> None:
    rows = _rows("ref", [1.0, 2.0], ["r0", "r1"]) + [
        {"controller": "a", "run_id": "r0", "tick": 0, "abs_error_g": None},
        {"controller": "a", "run_id": "r1", "tick": 1, "abs_error_g": 3.0},
    ]
    a = summarise_cell(rows, ["ref", "a"], {"sensors": "ref"}, MODES, 100, 0)[1]
    assert a["failed"] == 1 and a["states"] == 1 and a["median_g"] == 3.0
