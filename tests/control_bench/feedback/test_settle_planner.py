"""The receding-horizon controller on the learned settled-water model
(control_bench.feedback.settle_planner): the probes' path rows end in the release rows the
settle regression reads, the plan terms vanish at the release, a fold's model never sees its
own group, the controller applies the candidate predicted to settle closest to the goal and
holds it between plans, and the protocol checks the model's fields."""

from __future__ import annotations

import copy
import json
from typing import Any

import numpy as np
import pytest
from test_release_probes import _work

from rmi_learn.control_bench.feedback.estimators import Ridge, raw_weight
from rmi_learn.control_bench.feedback.laws import Fixed
from rmi_learn.control_bench.feedback.protocol import PROTOCOL_DIR, validate
from rmi_learn.control_bench.feedback.release import probe_rows, release_features
from rmi_learn.control_bench.feedback.settle_planner import (
    FEATURE_SETS,
    SettleModel,
    SettlePlanner,
    fit_plan,
    plan_features,
)
from rmi_learn.errors import InputError
from rmi_learn.sensing import SensorModel


def test_path_rows_end_in_the_release_rows_and_share_the_settled_water() -> None:
    work = _work(1, SensorModel())
    release = probe_rows(work)
    path = probe_rows(work, path=True)
    assert [r for r in path if r["remaining"] == 0] == release
    # Two setpoints released after 3 and 8 steps: 4 + 9 rows each.
    assert len(path) == 2 * (4 + 9)
    for r in path:
        assert 0 <= r["remaining"] <= r["release_tick"] and np.all(np.isfinite(r["features"]))
    # Every row of one probe targets the same settled water: weight there minus the target.
    e = work.run(Fixed([400.0]), True, True, 100 + 3, horizon=8, keep_seen=True)
    n_past = len(work.snap.history)
    rows = [r for r in path if r["setpoint_N"] == 400.0 and r["release_tick"] == 8]
    for r in rows:
        seen = e.seen[: n_past + 8 - r["remaining"]]
        settled = raw_weight(seen, work.m_dry) - r["target_kg"]
        assert settled == pytest.approx(e.M_L_settle, rel=1e-12, abs=1e-15)


def test_the_plan_terms_vanish_at_the_release_and_measure_the_change_of_grip() -> None:
    base = np.arange(10.0)
    base[-4] = 100.0  # the last applied setpoint
    x = plan_features(base, np.array([100.0, 150.0, 150.0]), np.array([5, 5, 0]))
    assert x.shape == (3, 15)
    np.testing.assert_array_equal(x[:, :10], np.tile(base, (3, 1)))
    np.testing.assert_array_equal(x[1, 10:], [5.0, 50.0, 250.0, 2500.0, 12500.0])
    np.testing.assert_array_equal(x[0, 11:], 0.0)
    np.testing.assert_array_equal(x[2, 10:], 0.0)


def _rows(fold: str, target: float, n: int = 6) -> list[dict[str, Any]]:
    rng = np.random.default_rng(ord(fold))
    return [
        {
            "size_cm": 8,
            "fold": fold,
            "setpoint_N": 50.0 * (1 + i % 3),
            "release_tick": 8,
            "remaining": i % 4,
            "target_kg": target + 0.001 * i,
            "features": rng.normal(size=len(FEATURE_SETS["window"])).tolist(),
        }
        for i in range(n)
    ]


def test_a_folds_model_never_sees_its_own_group() -> None:
    rows = _rows("a", 0.01) + _rows("b", 0.02) + _rows("c", 0.03)
    inputs = list(FEATURE_SETS)
    fit = fit_plan(rows, 8, "a", 0.01, inputs)
    assert fit is not None and fit.report["plan_rows"] == 12
    assert set(fit.report["plan_left_out_rms_kg"]) == {"b", "c"}
    assert set(fit.report["plan_inputs_start_rms_kg"]) == set(inputs)
    poisoned = [{**r, "target_kg": 1e3} if r["fold"] == "a" else r for r in rows]
    again = fit_plan(poisoned, 8, "a", 0.01, inputs)
    assert again is not None and again.model.inputs == fit.model.inputs
    base = np.array(rows[0]["features"])
    assert again.model.outside(base, [80.0], 3) == fit.model.outside(base, [80.0], 3)
    assert fit_plan([{**r, "target_kg": None} for r in rows], 8, "a", 0.01) is None


def test_the_input_set_is_the_one_that_predicts_the_left_out_starts_best() -> None:
    """A target that only the wrist load's change explains: the sets that read it win."""
    rows = _rows("a", 0.0, 40) + _rows("b", 0.0, 40) + _rows("c", 0.0, 40)
    col = FEATURE_SETS["window"].index("change W_z")
    for r in rows:
        r["target_kg"] = 0.01 * r["features"][col]
        r["remaining"] = r["release_tick"] if r["remaining"] % 2 else r["remaining"]
    fit = fit_plan(rows, 8, "a", 1e-6, ["grip", "grip-and-wrist"])
    assert fit is not None and fit.model.inputs == "grip-and-wrist"
    scores = fit.report["plan_inputs_start_rms_kg"]
    assert scores["grip-and-wrist"] < 1e-4 < scores["grip"]


def _planner(goal: float, replan: int) -> tuple[SettlePlanner, Any]:
    """A planner on the tiny trial's squeeze whose model says: the harder and longer the
    squeeze from here, the more water stays outside (1e-5 kg per N and control step)."""
    work = _work(1, SensorModel.noiseless())
    e = work.run(Fixed([100.0]), True, False, 0, horizon=2, keep_seen=True)
    d = release_features(e.seen, work.m_dry, 20.0).size + 5
    coef = np.zeros(d)
    coef[d - 3] = 1e-5  # the d r term
    model = SettleModel(
        Ridge(np.zeros(d), np.ones(d), coef, 0.0, 1.0), SettleModel.of("window"), "window"
    )
    law = SettlePlanner(model, work.m_dry, 20.0, goal, 8, 16.0, 400.0, 5, replan)
    return law, e.seen


def test_the_planner_applies_the_candidate_predicted_to_settle_closest_to_the_goal() -> None:
    law, seen = _planner(0.0, 1)
    law.start(seen)
    now = raw_weight(seen, law.m_dry)
    # Candidates 16, 112, 208, 304, 400 N from a last setpoint of 100 N, 8 steps left.
    for c in (16.0, 112.0, 208.0, 304.0, 400.0):
        law.goal_kg = now - 1e-5 * (c - 100.0) * 8
        law.start(seen)
        assert law.act(seen[-1]) == c
        assert law.predict(np.array([c]), 8)[0] == pytest.approx(law.goal_kg, abs=1e-12)


def test_between_plans_the_planner_holds_its_setpoint() -> None:
    law, seen = _planner(0.0, 4)
    law.start(seen)
    first = law.act(seen[-1])
    law.goal_kg = 1.0  # a plan now would pick the lowest setpoint
    assert [law.act(seen[-1]) for _ in range(3)] == [first] * 3
    assert law.act(seen[-1]) == 16.0


@pytest.fixture
def raw() -> dict[str, Any]:
    return json.loads((PROTOCOL_DIR / "control.json").read_text())


def test_the_control_protocol_lists_the_planners_with_their_model(raw: dict) -> None:
    p = validate(raw)
    assert {"mpc-settle", "model-constant"} <= set(p["controllers"])
    assert "release_probes" in p.raw and p["settle_model"]["inputs"] == list(FEATURE_SETS)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda r: r.pop("settle_model"), "settle_model must be an object"),
        (lambda r: r["settle_model"].update(penalty=-1), "settle_model.penalty must be a number"),
        (lambda r: r["settle_model"].update(candidates=1), r"candidates must be an integer in"),
        (lambda r: r["settle_model"].update(inputs=["all"]), "inputs must be a non-empty list of"),
        (lambda r: r["settle_model"].update(replan_ticks=33), r"replan_ticks .* \[1, 32\]"),
        (lambda r: r.pop("release_probes"), "release_probes must be an object"),
        (
            lambda r: (r.update(tasks=["reach"]), r["controllers"].remove("pi-settle")),
            "mpc-settle needs the settle task",
        ),
        (
            lambda r: (r.pop("settle_model"), r["controllers"].remove("mpc-settle")),
            "settle_model must be an object",
        ),
    ],
)
def test_bad_model_fields_are_one_line_naming_them(raw: dict, edit: Any, message: str) -> None:
    bad = copy.deepcopy(raw)
    edit(bad)
    with pytest.raises(InputError, match=message):
        validate(bad)
