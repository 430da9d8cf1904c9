"""The benchmark's reach task on a Gymnasium environment's hand-over states, for agents that
act through the environment's observation (a model-free RL policy beside the feedback laws).

A start state is the environment's hand-over for one trial seed (``env.reset(seed=s)``).
Its goal is drawn as the benchmark draws it: uniformly between the retained water that the
lowest and the highest constant setpoint of the action range reach after ``horizon``
control steps, both executed. Every controller then runs :func:`~.episode.run_episode`
from that state: the agent through :class:`AgentController` (observations built by
:func:`rmi_learn.sim.env.observation_vector`, its actions mapped by the environment's
``physical_action``), PI on the simulator's M_L, the held setpoint, and the best of the
executed constant setpoints of a bisection (the oracle). In the ``sensors`` mode PI also
closes on the wrist load's weight estimate (``pi-weight``, its carried-water offset fitted on
the validation seeds), the feedback loop on the agent's own sensing. The score is |M_L - g|
after the horizon, on the true M_L; each seed is its own run, so every interval resamples
seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmi_learn.control_bench.feedback.clusters import TIE_G, cluster_bootstrap
from rmi_learn.control_bench.feedback.episode import Controller, Episode, Plant, Tick, run_episode
from rmi_learn.control_bench.feedback.estimators import (
    WZ_INDEX,
    PrivilegedEstimate,
    WeightEstimate,
)
from rmi_learn.control_bench.feedback.laws import PI, Fixed, Hold
from rmi_learn.sensing import dry_mass, weight_estimate
from rmi_learn.sim.env import SpongeSqueezeEnv, observation_vector, y_values

#: A policy: the environment's observation (float32) -> an action of its action space.
Policy = Callable[[np.ndarray], np.ndarray]
#: A feedback law: a start state and its goal (kg) -> the controller toward it.
Law = Callable[["Start", float], Controller]


@dataclass
class AgentController:
    """A policy of the environment's observations as a benchmark controller, toward
    ``goal_kg``; sees the sensors' reading in the ``sensors`` mode, y_t otherwise."""

    policy: Policy
    env: SpongeSqueezeEnv
    goal_kg: float

    def start(self, history: list[Tick]) -> None:
        pass

    def act(self, tick: Tick) -> float:
        goal = self.goal_kg if self.env.observe_goal else None
        obs, _ = observation_vector(y_values(tick.record), tick.observed, goal)
        return float(self.env.physical_action(self.policy(obs))[0])


@dataclass
class Start:
    """One start state: the trial ``seed``, its hand-over state and record, the plant, the
    sensor model of the environment's ``sensors`` mode (None in ``privileged``) and the dry
    sponge's mass (kg)."""

    seed: int
    state: bytes
    record: dict[str, Any]
    plant: Plant
    sensors: Any | None = None
    m_dry: float = 0.0
    constants: dict[float, Episode] = field(default_factory=dict)


def start_of(env: SpongeSqueezeEnv, seed: int) -> Start:
    """The hand-over of trial ``seed`` in ``env`` (its force-driven action range)."""
    env.reset(seed=seed)
    assert env.sim is not None
    sim = env.sim
    state = sim.get_state()
    record = dict(sim.take_record())
    sim.set_state(state)
    lo, hi = float(env.action_low[0]), float(env.action_high[0])
    hold = float(env.config["hold_force"])
    sensors = env.sensors if env.observation_mode == "sensors" else None
    plant = Plant(sim, env.substeps, lo, hi, hold)
    return Start(seed, state, record, plant, sensors, dry_mass(sim))


def execute(start: Start, controller: Controller, horizon: int, sensed: bool = True) -> Episode:
    """``controller`` from ``start`` for ``horizon`` control steps (no settle), observing
    through the start's sensor model unless ``sensed`` is False (the oracle's executions)."""
    sensors = start.sensors if sensed else None
    return run_episode(
        start.plant, start.state, [start.record], controller, horizon, 0, sensors, (start.seed,)
    )


def constant(start: Start, force_N: float, horizon: int) -> Episode:
    """The executed constant setpoint ``force_N`` (N), kept per start."""
    if force_N not in start.constants:
        start.constants[force_N] = execute(start, Fixed([force_N]), horizon, sensed=False)
    return start.constants[force_N]


def drawn_goal(start: Start, horizon: int, goal_seed: int) -> float | None:
    """The start's goal (kg), drawn within what the setpoint bounds reach; None if either
    bound's execution failed."""
    a = constant(start, start.plant.lo_N, horizon).M_L_reach
    b = constant(start, start.plant.hi_N, horizon).M_L_reach
    if a is None or b is None:
        return None
    rng = np.random.default_rng([goal_seed, start.seed])
    return float(rng.uniform(min(a, b), max(a, b)))


def oracle_constant(start: Start, goal: float, horizon: int, steps: int) -> Episode:
    """The best of the constant setpoints an executed bisection toward ``goal`` tried (the
    bounds included): an oracle that runs the simulator for every candidate."""
    a, b = start.plant.lo_N, start.plant.hi_N
    for _ in range(steps):
        c = 0.5 * (a + b)
        m = constant(start, c, horizon).M_L_reach
        if m is None:
            break
        a, b = (c, b) if m > goal else (a, c)
    ok = {c: e for c, e in start.constants.items() if e.M_L_reach is not None}
    return ok[min(sorted(ok), key=lambda c: abs(ok[c].M_L_reach - goal))]  # type: ignore[operator]


def pi_privileged(start: Start, goal: float, ki: float) -> Controller:
    """PI on the simulator's M_L (Kp = 0) within the start's setpoint bounds."""
    return PI(PrivilegedEstimate(), goal, ki, 0.0, start.plant.lo_N, start.plant.hi_N)


def pi_weight(start: Start, goal: float, ki: float, offset_kg: float) -> Controller:
    """PI (Kp = 0) on the wrist load's weight estimate of the start's sponge, less the
    carried-water offset ``offset_kg`` (kg), within the start's setpoint bounds."""
    est = WeightEstimate(start.m_dry, offset_kg)
    return PI(est, goal, ki, 0.0, start.plant.lo_N, start.plant.hi_N)


@dataclass
class _Logged:
    """A controller that also keeps, per tick, the weight estimate without offset minus the
    true M_L (kg)."""

    inner: Controller
    m_dry: float
    excess: list[float] = field(default_factory=list)

    def start(self, history: list[Tick]) -> None:
        self.inner.start(history)

    def act(self, tick: Tick) -> float:
        assert tick.observed is not None
        raw = float(weight_estimate(float(tick.observed[WZ_INDEX]), self.m_dry))
        self.excess.append(raw - float(tick.record["M_L"]))
        return self.inner.act(tick)


def fit_weight_offset(starts: Sequence[Start], horizon: int) -> float:
    """The carried-water offset (kg) of the weight estimate: the mean excess of the raw
    estimate over the true M_L along the lowest and the highest constant setpoint of each
    start (validation seeds only; the ``sensors`` mode)."""
    excess: list[float] = []
    for s in starts:
        for force in (s.plant.lo_N, s.plant.hi_N):
            logged = _Logged(Fixed([force]), s.m_dry)
            if execute(s, logged, horizon).status == "ok":
                excess += logged.excess
    if not excess:
        raise ValueError("fit_weight_offset needs one executed validation episode, got none")
    return float(np.mean(excess))


def tune_ki(
    starts: Sequence[Start],
    kis: Sequence[float],
    horizon: int,
    goal_seed: int,
    law: Callable[[Start, float, float], Controller] = pi_privileged,
) -> tuple[float, dict[float, float]]:
    """The Ki (N/(kg s)) of ``law`` (start, goal, Ki) -> controller with the least median
    reach error (g) over ``starts`` (validation seeds only), and every candidate's median."""
    medians: dict[float, float] = {}
    for ki in kis:
        errs = []
        for s in starts:
            g = drawn_goal(s, horizon, goal_seed)
            if g is None:
                continue
            m = execute(s, law(s, g, ki), horizon).M_L_reach
            errs.append(np.inf if m is None else abs(m - g) * 1e3)
        medians[float(ki)] = float(np.median(errs)) if errs else float("inf")
    best = min(medians, key=lambda k: (medians[k], k))
    return best, medians


def evaluate(
    env: SpongeSqueezeEnv,
    seeds: Sequence[int],
    agents: Mapping[str, Policy],
    laws: Mapping[str, Law],
    horizon: int,
    goal_seed: int,
    bisection_steps: int = 2,
) -> list[dict[str, Any]]:
    """One row per (seed, controller): the agents, the feedback ``laws`` (name -> law),
    ``hold`` and ``oracle-constant``, each executed from the seed's hand-over toward its
    drawn goal. Agents and laws see the environment's observation mode."""
    rows: list[dict[str, Any]] = []
    for seed in seeds:
        s = start_of(env, int(seed))
        goal = drawn_goal(s, horizon, goal_seed)
        if goal is None:
            rows.append({"seed": int(seed), "controller": "all", "status": "no goal"})
            continue
        runs: dict[str, Episode] = {
            name: execute(s, AgentController(p, env, goal), horizon) for name, p in agents.items()
        }
        for name, law in laws.items():
            runs[name] = execute(s, law(s, goal), horizon)
        runs["hold"] = execute(s, Hold(), horizon)
        runs["oracle-constant"] = oracle_constant(s, goal, horizon, bisection_steps)
        for name, e in runs.items():
            m = e.M_L_reach
            rows.append(
                {
                    "seed": int(seed),
                    "controller": name,
                    "status": e.status,
                    "goal_kg": goal,
                    "M_L_kg": m,
                    "abs_error_g": None if m is None else abs(m - goal) * 1e3,
                    "peak_force_N": e.peak_force_N,
                }
            )
    return rows


def summarise(
    rows: Sequence[Mapping[str, Any]], reference: str, resamples: int = 2000, seed: int = 3
) -> list[dict[str, Any]]:
    """Per controller: states, median and mean error (g) with 95 % bootstrap intervals over
    seeds, and paired wins / ties / losses against ``reference`` (ties within ``TIE_G``)."""
    err: dict[str, dict[int, float]] = {}
    for r in rows:
        if r.get("abs_error_g") is not None:
            err.setdefault(str(r["controller"]), {})[int(r["seed"])] = float(r["abs_error_g"])
    ref = err.get(reference, {})
    out = []
    for name, by_seed in err.items():
        seeds = sorted(by_seed)
        v = np.array([by_seed[k] for k in seeds])
        rng = np.random.default_rng(seed)
        labels = [str(k) for k in seeds]
        paired = [(by_seed[k], ref[k]) for k in seeds if k in ref]
        out.append(
            {
                "controller": name,
                "states": len(seeds),
                "failed": sum(1 for r in rows if r["controller"] == name and r["status"] != "ok"),
                "median_g": float(np.median(v)),
                "median_ci_g": cluster_bootstrap(v, labels, np.median, rng, resamples),
                "mean_g": float(np.mean(v)),
                "mean_ci_g": cluster_bootstrap(v, labels, np.mean, rng, resamples),
                "wins": sum(1 for a, b in paired if a < b - TIE_G),
                "ties": sum(1 for a, b in paired if abs(a - b) <= TIE_G),
                "losses": sum(1 for a, b in paired if a > b + TIE_G),
            }
        )
    return out


def markdown(summary: Sequence[Mapping[str, Any]], reference: str) -> str:
    """The summary as a Markdown table (errors in g)."""

    def ci(pair: Any) -> str:
        return "n/a" if pair[0] is None else f"[{pair[0]:.2f}, {pair[1]:.2f}]"

    lines = [
        f"| controller | states | failed | median (g) [95 %] | mean (g) [95 %] | "
        f"vs {reference} W/T/L |",
        "|---|---|---|---|---|---|",
    ]
    for r in summary:
        lines.append(
            f"| {r['controller']} | {r['states']} | {r['failed']} | {r['median_g']:.2f} "
            f"{ci(r['median_ci_g'])} | {r['mean_g']:.2f} {ci(r['mean_ci_g'])} | "
            f"{r['wins']}/{r['ties']}/{r['losses']} |"
        )
    return "\n".join(lines) + "\n"


__all__ = [
    "AgentController",
    "Law",
    "Policy",
    "Start",
    "drawn_goal",
    "evaluate",
    "execute",
    "fit_weight_offset",
    "markdown",
    "oracle_constant",
    "pi_privileged",
    "pi_weight",
    "start_of",
    "summarise",
    "tune_ki",
]
