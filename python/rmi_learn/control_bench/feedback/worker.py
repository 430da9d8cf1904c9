"""The work on one run: replay it once to its start states, then execute every controller
from each state. Runs are independent, so a pool of processes shares them; each result row
is bit-identical whatever the pool's size or the engine's thread count."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmi_learn.control_bench.feedback.episode import Controller, Episode, Plant, run_episode
from rmi_learn.control_bench.feedback.estimators import (
    Estimator,
    LearnedEstimate,
    PrivilegedEstimate,
    WeightEstimate,
    WidthEstimate,
)
from rmi_learn.control_bench.feedback.fitting import Fits, run_key
from rmi_learn.control_bench.feedback.held_out import RunInfo, fold_of, substeps_of
from rmi_learn.control_bench.feedback.laws import PI, Fixed, Hold
from rmi_learn.control_bench.feedback.release import (
    SETTLE_CONTROLLER,
    SettleEstimate,
    probe_rows,
)
from rmi_learn.control_bench.feedback.settle_planner import (
    CONSTANT_CONTROLLER,
    PLANNERS,
    SettlePlanner,
)
from rmi_learn.control_bench.feedback.start_states import Replay, Snapshot, start_states
from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.sensing import SensorModel, dry_mass
from rmi_learn.sim.execute import clip_force


@dataclass
class RunJob:
    """What one run's worker needs: the run, its start ticks and roles, the protocol's
    settings, the fits of each fold its states serve (tuning: every other group's fold;
    test: its own), for test states, its fold's tuned gains per estimator, and the replay
    that gives its start states."""

    run: RunInfo
    ticks: list[tuple[int, str]]
    protocol: dict[str, Any]
    sensors: SensorModel
    fits: dict[str, Fits]
    replay: Replay
    gains: dict[str, tuple[float, float]] = field(default_factory=dict)
    threads: int = 1


def _key(job: RunJob, tick: int, task: int) -> tuple[int, ...]:
    return (*run_key(job.run), tick, task)


class StateWork:
    """The executions from one start state."""

    def __init__(self, job: RunJob, plant: Plant, snap: Snapshot, m_dry: float) -> None:
        self.job, self.plant, self.snap, self.m_dry = job, plant, snap, m_dry
        p = job.protocol
        self.horizon, self.settle = int(p["horizon"]), int(p["settle_ticks"])

    def estimator(self, name: str, fits: Fits | None) -> Estimator:
        """The estimator of PI controller ``name`` with a fold's ``fits``."""
        if name == "pi-privileged":
            return PrivilegedEstimate()
        assert fits is not None
        if name == "pi-weight":
            return WeightEstimate(self.m_dry, fits.weight_offset_kg)
        if name == "pi-width":
            return WidthEstimate(fits.width.a, fits.width.b, self.m_dry)
        if name == SETTLE_CONTROLLER:
            assert fits.settle is not None
            return SettleEstimate(fits.settle, self.m_dry, self.plant.hold_N)
        return LearnedEstimate(fits.learned.model, self.m_dry)

    def run(
        self,
        controller: Controller,
        sensing: bool,
        settle: bool,
        task: int = 0,
        horizon: int | None = None,
        keep_seen: bool = False,
    ) -> Episode:
        """``controller`` for ``horizon`` control steps (default: the protocol's), then the
        settle if asked; ``task`` keys the sensor noise."""
        return run_episode(
            self.plant,
            self.snap.state,
            self.snap.history,
            controller,
            self.horizon if horizon is None else horizon,
            self.settle if settle else 0,
            self.job.sensors if sensing else None,
            _key(self.job, self.snap.tick, task),
            keep_seen=keep_seen,
        )

    def constant(self, c: float, settle: bool) -> Episode:
        return self.run(Fixed([c]), False, settle)

    def goal(self, lo: Episode, hi: Episode, attr: str, task: int) -> float | None:
        a, b = getattr(lo, attr), getattr(hi, attr)
        if a is None or b is None:
            return None
        rng = np.random.default_rng(
            [int(self.job.protocol["goal_seed"]), *_key(self.job, self.snap.tick, task)]
        )
        return float(rng.uniform(min(a, b), max(a, b)))

    def pi(
        self,
        name: str,
        fits: Fits | None,
        goal: float,
        gains: tuple[float, float],
        settle: bool,
        task: int,
    ) -> Episode:
        law = PI(
            self.estimator(name, fits), goal, gains[0], gains[1], self.plant.lo_N, self.plant.hi_N
        )
        return self.run(law, name != "pi-privileged", settle, task)

    def plan(self, name: str, fits: Fits, goal: float, task: int, settle: bool) -> Episode:
        """``mpc-settle`` or ``model-constant`` toward the goal ``goal`` (kg) of the water
        after the settle (its plans assume one), the settle executed if asked."""
        assert fits.plan is not None
        spec = self.job.protocol["settle_model"]
        replan = self.horizon if name == CONSTANT_CONTROLLER else int(spec["replan_ticks"])
        law = SettlePlanner(
            fits.plan,
            self.m_dry,
            self.plant.hold_N,
            goal,
            self.horizon,
            self.plant.lo_N,
            self.plant.hi_N,
            int(spec["candidates"]),
            replan,
        )
        return self.run(law, True, settle, task)


def _row(
    job: RunJob,
    snap: Snapshot,
    role: str,
    task: str,
    goal: float | None,
    ctrl: str,
    e: Episode,
    **kw: Any,
) -> dict[str, Any]:
    attr = "M_L_reach" if task == "reach" else "M_L_settle"
    m = getattr(e, attr)
    return {
        "run_id": job.run.run_id,
        "size_cm": job.run.size_cm,
        "porosity": job.run.porosity,
        "F_hold": job.run.F_hold,
        "F_squeeze": job.run.F_squeeze,
        "seed": job.run.seed,
        "tick": snap.tick,
        "role": role,
        "fold": kw.get("fold", fold_of(job.run)),
        "task": task,
        "goal_kg": goal,
        "controller": ctrl,
        "status": e.status,
        "M_L_kg": m,
        "abs_error_g": None if (m is None or goal is None) else abs(m - goal) * 1e3,
        "peak_force_N": e.peak_force_N,
        "ki": kw.get("ki"),
        "kp": kw.get("kp"),
        "setpoint_N": kw.get("setpoint_N"),
        "error": e.error,
    }


def _bisect(
    work: StateWork,
    lo: float,
    hi: float,
    goal: float,
    attr: str,
    steps: int,
    seen: dict[float, Episode],
) -> tuple[float, Episode]:
    """Executed bisection over constant setpoints (M_L falls as the grip rises), starting
    from the executions ``seen``; returns the best executed constant and its episode."""
    a, b = lo, hi
    for _ in range(steps):
        c = 0.5 * (a + b)
        if c not in seen:
            seen[c] = work.constant(c, work.settle > 0)
        m = getattr(seen[c], attr)
        if m is None:
            break
        a, b = (c, b) if m > goal else (a, c)
    ok = {c: e for c, e in seen.items() if getattr(e, attr) is not None}
    best = min(sorted(ok), key=lambda c: abs(getattr(ok[c], attr) - goal))
    return best, ok[best]


def tuning_rows(work: StateWork, role: str) -> list[dict[str, Any]]:
    """Every PI gain candidate on the reach goal (horizon only), for the tuning; the
    settle-predicting loop's candidates on the settle goal (the settle included)."""
    job, snap = work.job, work.snap
    lo, hi = work.plant.lo_N, work.plant.hi_N
    names = [c for c in job.protocol["controllers"] if c.startswith("pi-")]
    settles = SETTLE_CONTROLLER in names
    e_lo, e_hi = work.constant(lo, settles), work.constant(hi, settles)
    goal = work.goal(e_lo, e_hi, "M_L_reach", 0)
    settle_goal = work.goal(e_lo, e_hi, "M_L_settle", 1) if settles else None
    rows: list[dict[str, Any]] = []
    if goal is None:
        return [
            _row(
                job,
                snap,
                role,
                "reach",
                None,
                "oracle-constant",
                e_lo if e_lo.status != "ok" else e_hi,
            )
        ]
    for name in names:
        # The privileged loop needs no fit: one execution serves every fold.
        fold_fits: dict[str | None, Fits | None] = (
            {None: None} if name == "pi-privileged" else dict(job.fits.items())
        )
        task, target = ("settle", settle_goal) if name == SETTLE_CONTROLLER else ("reach", goal)
        if target is None:
            continue
        settle = task == "settle"
        for fold, fits in fold_fits.items():
            for ki in job.protocol["pi"]["ki"]:
                for kp in job.protocol["pi"]["kp"]:
                    e = work.pi(name, fits, target, (ki, kp), settle, int(settle))
                    rows.append(
                        _row(job, snap, role, task, target, name, e, ki=ki, kp=kp, fold=fold)
                    )
    return rows


def test_rows(work: StateWork, role: str) -> list[dict[str, Any]]:
    """Every listed controller on each task's goal."""
    job, snap, p = work.job, work.snap, work.job.protocol
    lo, hi = work.plant.lo_N, work.plant.hi_N
    seen = {lo: work.constant(lo, True), hi: work.constant(hi, True)}
    ctrls = p["controllers"]
    shared: dict[str, Episode] = {}
    if "hold" in ctrls:
        shared["hold"] = work.run(Hold(), True, True)
    if "scripted" in ctrls:
        shared["scripted"] = work.run(Fixed(snap.scripted), True, True)
    rows: list[dict[str, Any]] = []
    for ti, task in enumerate(p["tasks"]):
        attr = "M_L_reach" if task == "reach" else "M_L_settle"
        goal = work.goal(seen[lo], seen[hi], attr, ti)
        for name, e in shared.items():
            rows.append(_row(job, snap, role, task, goal, name, e))
        if goal is None:
            continue
        if "oracle-constant" in ctrls:
            c, e = _bisect(work, lo, hi, goal, attr, int(p["bisection_steps"]), seen)
            rows.append(_row(job, snap, role, task, goal, "oracle-constant", e, setpoint_N=c))
        fits = job.fits[fold_of(job.run)]
        for name in (c for c in ctrls if c.startswith("pi-")):
            ki, kp = job.gains[name]
            e = work.pi(name, fits, goal, (ki, kp), task == "settle", ti)
            rows.append(_row(job, snap, role, task, goal, name, e, ki=ki, kp=kp))
        for name in (c for c in ctrls if c in PLANNERS):
            e = work.plan(name, fits, goal, ti, task == "settle")
            rows.append(_row(job, snap, role, task, goal, name, e))
    return rows


def _states(job: RunJob) -> list[StateWork]:
    """The run's start states (replayed, or kept by an earlier phase); one
    :class:`StateWork` per tick."""
    p = job.protocol
    sim, snaps = start_states(job.run, job.replay, [k for k, _ in job.ticks], job.threads)
    m_dry = dry_mass(sim)
    lo = clip_force(float(p["setpoint_low_fraction"]) * job.run.F_hold)
    plant = Plant(sim, substeps_of(job.run), lo, FORCE_LIMIT_N, job.run.F_hold)
    return [StateWork(job, plant, snap, m_dry) for snap in snaps]


def run_job(job: RunJob) -> list[dict[str, Any]]:
    """All rows of one run's start states (tuning rows when its ticks are tuning ones)."""
    roles = dict(job.ticks)
    rows: list[dict[str, Any]] = []
    for work in _states(job):
        role = roles[work.snap.tick]
        rows += tuning_rows(work, role) if role == "tuning" else test_rows(work, role)
    return rows


def probe_job(job: RunJob) -> list[dict[str, Any]]:
    """The release probes of one run's tuning states
    (:mod:`rmi_learn.control_bench.feedback.release`)."""
    path = bool(set(PLANNERS) & set(job.protocol["controllers"]))
    return [row for work in _states(job) for row in probe_rows(work, path)]


__all__ = ["RunJob", "StateWork", "probe_job", "run_job"]
