"""The protocol benchmark's Markdown (control_bench.feedback.report): each fold's estimator
line gives the sensor estimators' errors and, when the protocol has ``pi-settle``, the
settle regression's errors with each training group left out, and with the planners the
settled-water model's input set and errors."""

from __future__ import annotations

from typing import Any

from rmi_learn.control_bench.feedback.report import markdown


def _result(settle: bool, plan: bool = False) -> dict[str, Any]:
    rep: dict[str, Any] = {
        "weight_rms_kg": 0.008,
        "width_rms_kg": 0.006,
        "learned_rms_kg": 0.005,
        "learned_cv_rms_kg": {"0.1": 0.007, "1.0": 0.0065},
        "rows": 300,
    }
    if settle:
        rep |= {
            "settle_rms_kg": 0.002,
            "settle_left_out_rms_kg": {"0.5/80": 0.0031, "0.7/80": 0.0024},
            "settle_target_std_kg": 0.0075,
            "probes": 90,
        }
    if plan:
        rep |= {
            "plan_inputs": "grip",
            "plan_rms_kg": 0.0021,
            "plan_left_out_rms_kg": {"0.5/80": 0.004, "0.7/80": 0.0052},
            "plan_left_out_start_rms_kg": {"0.5/80": 0.0033, "0.7/80": 0.0047},
            "plan_rows": 1770,
        }
    return {
        "protocol": {"name": "p", "references": {}, "tasks": []},
        "protocol_digest": "0" * 64,
        "summary": [],
        "estimators": {"8": {"0.5/150": rep}},
        "gains": {"8": {"0.5/150": {"pi-settle": [150000.0, 0.0]}}},
    }


def test_the_estimator_line_gives_the_settle_fit_only_when_there_is_one() -> None:
    line = next(x for x in markdown(_result(True)).splitlines() if x.startswith("- 8 cm"))
    assert "learned 5.00 (left-out training group 6.50) over 300 rows" in line
    assert "after the release 2.00 (each training group left out 2.40-3.10; target spread" in line
    assert "over 90 probes" in line
    plain = next(x for x in markdown(_result(False)).splitlines() if x.startswith("- 8 cm"))
    assert plain.endswith("over 300 rows")


def test_the_estimator_line_gives_the_settled_water_models_inputs_and_errors() -> None:
    line = next(x for x in markdown(_result(True, True)).splitlines() if x.startswith("- 8 cm"))
    assert line.endswith(
        "settled-water model on grip 2.10 (each training group left out 4.00-5.20, "
        "from a probe's start 3.30-4.70) over 1770 path rows"
    )
