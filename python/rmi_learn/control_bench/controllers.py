"""The controllers of the benchmark, executed from one start state toward its goals.

- Executed action: a chunk's H force setpoints F_target, each held for one 20 ms control
  step and tracked by the engine's force loop (:mod:`rmi_learn.sim.execute`); v_cmd is the
  force loop's own output and is not executed.
- Goals: a sweep of constant setpoints from 0.8 F_hold to the force limit gives the
  reachable interval of terminal M_L; goals are drawn uniformly inside it, and the logged
  goal (M_L at t + H) is reported apart.
- Controllers: ``recorded``, ``constant-best`` (hindsight), ``first-sample/<policy>``,
  ``ranked-<scorer>/<policy>``, ``best-of-k/<policy>`` (the ceiling of ranking),
  ``refined-<scorer>/<policy>``, ``model-<scorer>`` and ``receding-<n>/<policy>``
  (re-planning every n control steps from the observed history), see :data:`FAMILIES`.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from rmi_learn.control_bench import measures
from rmi_learn.control_bench.inputs import Candidate, PolicyInput, ScorerInput
from rmi_learn.data.schema import (
    CONTINUOUS_INDEX,
    CONTROL_ACTION_INDEX,
    CONTROL_ACTIONS,
    FORCE_LIMIT_N,
    OBS,
)
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.refine import refine_chunk
from rmi_learn.planning.scorers import EnsembleScorer, world_model_scorer
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.sim.execute import Execution, execute_forces, run_forces

#: The lowest setpoint of the sweep, as a fraction of the run's holding force: the lower
#: edge of the lift gate's load band (``gate.force_band[0]``), the smallest grip the trial
#: counts as a stable hold; the run itself lifted and carried the sponge at F_hold.
SETPOINT_LOW_FRACTION = 0.8
#: Name of the scorer that combines every loaded world model (mean forecast, spread penalty).
ENSEMBLE = "ensemble"
#: Controller families of the benchmark (``controllers``; the setpoint sweep, ``recorded``
#: and ``constant-best`` always run). ``best-of-k`` executes all K samples of every policy,
#: which the scorer diagnostics and ``control_samples.parquet``'s policy rows need.
FAMILIES: tuple[str, ...] = (
    "first-sample",
    "ranked",
    "best-of-k",
    "refined",
    "model",
    "receding",
    "receding-refined",
    "receding-model",
)

#: A goal: its kind (``drawn``, ``logged``, ``given``), index within the kind and mass (kg).
Goal = tuple[str, int, float]


def seed_of(*parts: Any) -> int:
    """A seed from the parts' text (the same parts give the same seed in every process)."""
    return zlib.crc32("|".join(str(p) for p in parts).encode())


def standardise_record(rec: Any, stats: Any) -> tuple[np.ndarray, np.ndarray]:
    """One observation (a ``take_record()`` dict) as a history row of the dataset windows:
    (23,) values, continuous channels standardised with ``stats`` (a dataset ``Stats``),
    invalid values 0, and the (23,) validity mask."""
    y = np.asarray([float(rec[n]) for n in OBS], dtype=np.float64)
    mask = np.isfinite(y)
    ys = y.copy()
    ci = list(CONTINUOUS_INDEX)
    ys[ci] = stats.standardise_z(y[ci])
    ys[~mask] = 0.0
    return ys.astype(np.float32), mask.astype(np.float32)


@dataclass
class StartState:
    """A replayed start state: the candidate, its track, the engine state and its window."""

    cand: Candidate
    track: Any
    state: bytes
    fingerprint: str
    bytes_hash: str
    hist: Any  # (1, L, 23) standardised history of the dataset window
    hist_mask: Any
    water_now_std: Any  # (1,)


@dataclass
class GoalBatch:
    """A start state's window repeated once per goal, with the goals standardised and in kg
    (as the policies and scorers see them), and the recorded chunk (H, 1) N."""

    hist: Any
    mask: Any
    water_now: Any
    goal_std: Any
    goal_kg: Any
    recorded_u: Any


@dataclass
class Proposals:
    """One policy's K samples (G, K, H, 1) N per goal, their executions on demand, and every
    scorer's costs and forecasts of the samples and the recorded chunk."""

    samples: Any
    run_sample: _Executed
    scored: dict[str, tuple[dict[str, Any], Any]]
    pred_kg: np.ndarray  # (G, K + 1, scorers)


def _row(base: Mapping[str, Any], goal: Goal, ctrl: str, e: Execution, **kw: Any) -> dict[str, Any]:
    """A controller's row: the state's columns, the goal and the execution's outcome."""
    g = goal[2]
    return {
        **base,
        "goal_kind": goal[0],
        "goal_index": goal[1],
        "goal_kg": g,
        "controller": ctrl,
        "M_L_end_kg": e.M_L,
        "err_g": None if e.M_L is None else 1000.0 * abs(e.M_L - g),
        "peak_force_N": e.peak_force_N,
        "failure": e.failure,
        "phase_end": e.phase,
        "status": e.status,
        "error": e.error,
        **kw,
    }


class Bench:
    """Runs the controllers of one start state (see :meth:`state_rows`)."""

    def __init__(
        self,
        sim: Any,
        substeps: int,
        ds: Any,
        policies: Mapping[str, PolicyInput],
        scorers: Mapping[str, ScorerInput],
        *,
        k: int,
        horizon: int,
        n_setpoints: int,
        goals_per_state: int,
        given_goals: Sequence[float],
        receding: int,
        seed: int,
        receding_scorers: Sequence[str],
        refine_scorers: Sequence[str],
        ensemble: bool = True,
        refine_metrics: Sequence[str] = ("smooth",),
        controllers: Sequence[str] = FAMILIES,
    ) -> None:
        self.sim, self.substeps, self.ds = sim, substeps, ds
        self.k, self.h, self.seed = k, horizon, seed
        self.n_setpoints, self.goals_per_state = n_setpoints, goals_per_state
        self.given_goals = list(given_goals)
        self.receding = receding
        self.std = Standardiser.from_stats(ds.stats)
        self.policies = policies
        fns = {name: world_model_scorer(sc.model) for name, sc in scorers.items()}
        if ensemble and len(fns) >= 2:
            fns[ENSEMBLE] = EnsembleScorer(dict(fns))  # type: ignore[assignment]
        self.scorer_names = list(fns)
        self.fns = fns
        self.planners = {
            (p, s): Planner(pol.net, pol.objective, fn, self.std, k=k)
            for p, pol in policies.items()
            for s, fn in fns.items()
        }
        self.default_scorer = self.scorer_names[0]
        self.receding_scorers = list(receding_scorers)
        self.refine_scorers = list(refine_scorers)
        self.refine_metrics = list(refine_metrics)
        self.families = set(controllers)
        self.executions = 0
        #: Rows of ``control_samples.parquet`` produced by the last :meth:`state_rows`.
        self.samples: list[dict[str, Any]] = []

    # -- helpers --------------------------------------------------------------------

    def _exec(self, state: bytes, forces: np.ndarray) -> Execution:
        self.executions += 1
        return execute_forces(self.sim, state, forces, self.substeps)

    def _goal_std(self, g_kg: np.ndarray) -> Any:
        g = torch.as_tensor(np.asarray(g_kg), dtype=torch.float32)
        return (g - self.std.z_mean[0]) / self.std.z_std[0]

    def _sample_row(
        self,
        base: Mapping[str, Any],
        objective: str,
        index: int,
        forces: Any,
        e: Execution,
        pred_kg: Sequence[float],
        goal: Goal | None = None,
    ) -> None:
        self.samples.append(
            {
                **{c: base[c] for c in ("size_cm", "run_id", "t", "state_hash", "water_now_kg")},
                "goal_kind": None if goal is None else goal[0],
                "goal_index": None if goal is None else goal[1],
                "goal_kg": None if goal is None else goal[2],
                "objective": objective,
                "sample_index": index,
                "forces_N": [float(f) for f in np.asarray(forces, dtype=np.float64)],
                "M_L_end_kg": e.M_L,
                "peak_force_N": e.peak_force_N,
                "status": e.status,
                "pred_M_L_kg": [float(x) for x in pred_kg],
            }
        )

    # -- one state ------------------------------------------------------------------

    def state_rows(self, s: StartState) -> list[dict[str, Any]]:
        """Every row of one start state: the setpoint sweep and its reachable interval, the
        goals, and each controller executed from the state toward each goal."""
        t0 = time.perf_counter()
        self.samples = []
        sweep, lo, hi = self._setpoint_sweep(s)
        goals = self._goals(s, lo, hi)
        base = self._base(s, lo, hi)
        rows: list[dict[str, Any]] = []
        recorded_f = s.track.actions[s.cand.t : s.cand.t + self.h, 0]
        rec = self._exec(s.state, recorded_f)
        logged = next(g for g in goals if g[0] == "logged")
        rows.append(_row(base, logged, "recorded", rec, executions=1))
        self._reference_samples(s, base, sweep, recorded_f, rec)
        rows += self._constant_best(base, goals, sweep)
        batch = self._goal_batch(s, goals)
        for pname in self.policies:
            props = self._proposals(s, pname, batch, len(goals))
            for gi, goal in enumerate(goals):
                rows += self._policy_rows(s, base, pname, props, gi, goal)
        rows += self._model_rows(s, base, goals)
        wall = time.perf_counter() - t0
        for r in rows:
            r["wall_s"] = wall
        return rows

    def _setpoint_sweep(
        self, s: StartState
    ) -> tuple[list[tuple[float, Execution]], float | None, float | None]:
        """The constant setpoints from the sweep's lowest to the force limit, executed, and
        the interval of terminal M_L they reach (kg; None when none executed)."""
        f_hold = float(s.track.config["hold_force"])
        setpoints = np.linspace(SETPOINT_LOW_FRACTION * f_hold, FORCE_LIMIT_N, self.n_setpoints)
        sweep = [(float(f), self._exec(s.state, np.full(self.h, f))) for f in setpoints]
        reached = [e.M_L for _, e in sweep if e.status == "ok" and e.M_L is not None]
        lo, hi = (min(reached), max(reached)) if reached else (None, None)
        return sweep, lo, hi

    def _goals(self, s: StartState, lo: float | None, hi: float | None) -> list[Goal]:
        """Goals drawn inside the reachable interval, the logged goal and the given ones."""
        c, tr = s.cand, s.track
        rng = np.random.default_rng(seed_of(self.seed, c.run_id, c.t, "goals"))
        drawn = (
            rng.uniform(lo, hi, self.goals_per_state)
            if lo is not None and hi is not None
            else np.zeros(0)
        )
        goals: list[Goal] = [("drawn", i, float(g)) for i, g in enumerate(drawn)]
        goals.append(("logged", 0, float(tr.water[c.t + self.h])))
        goals += [("given", i, float(g)) for i, g in enumerate(self.given_goals)]
        return goals

    def _base(self, s: StartState, lo: float | None, hi: float | None) -> dict[str, Any]:
        """The columns every row of the state shares."""
        c, tr = s.cand, s.track
        return {
            "size_cm": c.size_cm,
            "run_id": c.run_id,
            "t": c.t,
            "k": int(tr.k[c.t]),
            "anchor_phase": c.phase,
            "state_hash": s.fingerprint,
            "state_bytes_sha256": s.bytes_hash,
            "water_now_kg": float(tr.water[c.t]),
            "reach_min_kg": lo,
            "reach_max_kg": hi,
        }

    def _reference_samples(
        self,
        s: StartState,
        base: Mapping[str, Any],
        sweep: Sequence[tuple[float, Execution]],
        recorded_f: np.ndarray,
        rec: Execution,
    ) -> None:
        """Every scorer's forecast of the sweep's and the recorded chunk's outcome, as
        sample rows."""
        h = self.h
        ref_u = torch.as_tensor(
            np.stack([np.full(h, f) for f, _ in sweep] + [recorded_f])[None, :, :, None],
            dtype=torch.float32,
        )
        first_pol = next(iter(self.policies))
        ref_pred = np.stack(
            [
                self.planners[(first_pol, sn)]
                .score(s.hist, s.hist_mask, ref_u, torch.zeros(1))[1][0]
                .double()
                .numpy()
                for sn in self.scorer_names
            ],
            axis=-1,
        )
        for i, (f, e) in enumerate(sweep):
            self._sample_row(base, "constant", i, np.full(h, f), e, ref_pred[i])
        self._sample_row(base, "recorded", 0, recorded_f, rec, ref_pred[-1])

    def _constant_best(
        self,
        base: Mapping[str, Any],
        goals: Sequence[Goal],
        sweep: Sequence[tuple[float, Execution]],
    ) -> list[dict[str, Any]]:
        """Per goal, the swept setpoint that ended nearest to it (hindsight)."""
        rows = []
        for goal in goals:
            ok = [(f, e) for f, e in sweep if e.status == "ok" and e.M_L is not None]
            if ok:
                f, e = min(ok, key=lambda fe: abs(fe[1].M_L - goal[2]))  # type: ignore[operator]
                rows.append(
                    _row(base, goal, "constant-best", e, setpoint_N=f, executions=len(sweep))
                )
        return rows

    def _goal_batch(self, s: StartState, goals: Sequence[Goal]) -> GoalBatch:
        g_kg = np.asarray([g[2] for g in goals])
        g_std = self._goal_std(g_kg)
        n_goals = len(goals)
        c, h = s.cand, self.h
        return GoalBatch(
            hist=s.hist.expand(n_goals, -1, -1).contiguous(),
            mask=s.hist_mask.expand(n_goals, -1, -1).contiguous(),
            water_now=s.water_now_std.expand(n_goals).contiguous(),
            goal_std=g_std,
            goal_kg=self.std.water_to_kg(g_std),
            recorded_u=torch.as_tensor(
                s.track.actions[c.t : c.t + h, list(CONTROL_ACTION_INDEX)],
                dtype=torch.float32,
            ),
        )

    def _proposals(self, s: StartState, pname: str, b: GoalBatch, n_goals: int) -> Proposals:
        """Policy ``pname``'s K samples toward every goal, scored with the recorded chunk by
        every scorer."""
        c, h = s.cand, self.h
        first_planner = self.planners[(pname, self.default_scorer)]
        gen = torch.Generator().manual_seed(seed_of(self.seed, c.run_id, c.t, pname))
        samples = first_planner.sample(
            b.hist, b.mask, self.std.goal_vector(b.goal_std, b.water_now), gen
        )  # (G, K, H, 1)
        # Samples run on demand, once each: only best-of-K needs all K.
        run_sample = _Executed(lambda u: self._exec(s.state, u), samples)
        recorded = b.recorded_u.expand(n_goals, 1, h, len(CONTROL_ACTIONS))
        cand = torch.cat([samples, recorded], dim=1)
        scored = {
            sn: self.planners[(pname, sn)].score(b.hist, b.mask, cand, b.goal_kg)
            for sn in self.scorer_names
        }
        pred_kg = np.stack(
            [scored[sn][1].double().numpy() for sn in self.scorer_names], axis=-1
        )  # (G, K + 1, scorers)
        return Proposals(samples, run_sample, scored, pred_kg)

    def _policy_rows(
        self,
        s: StartState,
        base: Mapping[str, Any],
        pname: str,
        p: Proposals,
        gi: int,
        goal: Goal,
    ) -> list[dict[str, Any]]:
        """The rows of policy ``pname``'s controllers toward goal ``gi``: best-of-K, the
        first sample, ranked and refined by each scorer, and re-planned."""
        rows: list[dict[str, Any]] = []
        errs = np.full(self.k, np.nan)
        every = "best-of-k" in self.families
        if every:
            for j in range(self.k):
                e = p.run_sample(gi, j)
                self._sample_row(
                    base,
                    pname,
                    j,
                    p.samples[gi, j, :, 0].double().numpy(),
                    e,
                    p.pred_kg[gi, j],
                    goal,
                )
                errs[j] = np.inf if e.M_L is None else 1000.0 * abs(e.M_L - goal[2])
            best = int(np.argmin(errs))
            rows.append(
                _row(
                    base,
                    goal,
                    f"best-of-k/{pname}",
                    p.run_sample(gi, best),
                    objective=pname,
                    sample_index=best,
                    executions=self.k,
                )
            )
        if "first-sample" in self.families:
            rows.append(
                _row(
                    base,
                    goal,
                    f"first-sample/{pname}",
                    p.run_sample(gi, 0),
                    objective=pname,
                    sample_index=0,
                    executions=1,
                )
            )
        for sn, (costs, _water) in p.scored.items():
            rows += self._ranked_rows(s, base, pname, p, gi, goal, sn, costs, errs, every)
        rows += self._receding_rows(s, base, pname, gi, goal)
        return rows

    def _ranked_rows(
        self,
        s: StartState,
        base: Mapping[str, Any],
        pname: str,
        p: Proposals,
        gi: int,
        goal: Goal,
        sn: str,
        costs: Mapping[str, Any],
        errs: np.ndarray,
        every: bool,
    ) -> list[dict[str, Any]]:
        """The sample scorer ``sn`` selects toward goal ``gi``, executed, and that sample
        refined by the scorer in each metric."""
        rows = []
        j = costs["J"][gi]
        idx = int(torch.argmin(j[: self.k]))
        pred = costs["J_M"][gi].double().numpy()
        if "ranked" in self.families:
            finite = np.isfinite(errs)
            rank_rec = int(1 + np.sum(j[: self.k].numpy() < float(j[self.k])))
            rows.append(
                _row(
                    base,
                    goal,
                    f"ranked-{sn}/{pname}",
                    p.run_sample(gi, idx),
                    objective=pname,
                    scorer=sn,
                    sample_index=idx,
                    pred_err_g=float(pred[idx]),
                    spearman=(
                        measures.spearman(pred[: self.k][finite], errs[finite]) if every else None
                    ),
                    recorded_rank=rank_rec,
                    pred_err_recorded_g=float(pred[self.k]),
                    persistence_err_g=1000.0 * abs(base["water_now_kg"] - goal[2]),
                    executions=self.k if every else 1,
                )
            )
        if "refined" not in self.families or sn not in self.refine_scorers:
            return rows
        for metric in self.refine_metrics:
            u, pred_g = self._refine(s, sn, p.samples[gi, idx], goal[2], self.h - 1, metric)
            rows.append(
                _row(
                    base,
                    goal,
                    f"{self._refined_name(sn, metric)}/{pname}",
                    self._exec(s.state, u),
                    objective=pname,
                    scorer=sn,
                    sample_index=idx,
                    pred_err_g=pred_g,
                    executions=1,
                )
            )
        return rows

    def _receding_rows(
        self, s: StartState, base: Mapping[str, Any], pname: str, gi: int, goal: Goal
    ) -> list[dict[str, Any]]:
        """Policy ``pname`` re-planned every ``receding`` steps toward goal ``gi`` by each
        re-planning scorer, plain and refined."""
        c = s.cand
        plain = self.receding_scorers if "receding" in self.families else []
        refined = self.refine_scorers if "receding-refined" in self.families else []
        runs = [(x, None) for x in plain] + [(x, self.refine_metrics[0]) for x in refined]
        rows = []
        for sn, how in runs if self.receding else ():
            # The same draws for every scorer: they differ only in their choices.
            rgen = torch.Generator().manual_seed(
                seed_of(self.seed, c.run_id, c.t, pname, "receding", gi)
            )
            e, n_plans = self.receding_run(s, pname, sn, goal[2], rgen, refine=how)
            if how is not None:
                name = f"receding-{self.receding}-refined-{sn}"
            else:
                name = f"receding-{self.receding}" + ("" if sn == self.default_scorer else f"-{sn}")
            rows.append(
                _row(
                    base, goal, f"{name}/{pname}", e, objective=pname, scorer=sn, executions=n_plans
                )
            )
        return rows

    def _model_rows(
        self, s: StartState, base: Mapping[str, Any], goals: Sequence[Goal]
    ) -> list[dict[str, Any]]:
        """Model-based control without a policy: the last applied setpoint held, refined."""
        c, h = s.cand, self.h
        hold = float(s.track.actions[max(c.t - 1, 0), 0])
        rows = []
        for goal in goals:
            for sn in self.refine_scorers:
                metric = self.refine_metrics[0]
                if "model" in self.families:
                    start = torch.full((h, 1), hold)
                    u, pred_g = self._refine(s, sn, start, goal[2], h - 1, metric)
                    rows.append(
                        _row(
                            base,
                            goal,
                            f"model-{sn}",
                            self._exec(s.state, u),
                            scorer=sn,
                            setpoint_N=hold,
                            pred_err_g=pred_g,
                            executions=1,
                        )
                    )
                if "receding-model" in self.families and self.receding:
                    e, n_plans = self.receding_run(
                        s, None, sn, goal[2], None, refine=metric, start=hold
                    )
                    rows.append(
                        _row(
                            base,
                            goal,
                            f"receding-{self.receding}-model-{sn}",
                            e,
                            scorer=sn,
                            setpoint_N=hold,
                            executions=n_plans,
                        )
                    )
        return rows

    def _refined_name(self, scorer: str, metric: str) -> str:
        return (
            f"refined-{scorer}"
            if metric == self.refine_metrics[0]
            else (f"refined-{metric}-{scorer}")
        )

    def _refine(
        self,
        s: StartState,
        scorer: str,
        u: Any,
        goal_kg: float,
        step: int,
        metric: str,
        hist: Any = None,
        mask: Any = None,
    ) -> tuple[np.ndarray, float]:
        """The chunk ``u`` (H, 1) N refined by ``scorer`` toward ``goal_kg`` at command
        ``step`` (:func:`~rmi_learn.planning.refine.refine_chunk`), never below the sweep's
        lowest setpoint unless it starts there; returns the setpoints (H,) and the scorer's
        forecast error after refinement (g)."""
        floor = SETPOINT_LOW_FRACTION * float(s.track.config["hold_force"])
        u = torch.as_tensor(u, dtype=torch.float32)[None]
        g = torch.as_tensor([goal_kg], dtype=torch.float32)
        r = refine_chunk(
            self.fns[scorer],
            self.std,
            s.hist if hist is None else hist,
            s.hist_mask if mask is None else mask,
            u,
            g,
            step,
            lower=torch.clamp(u, max=floor),
            metric=metric,
        )
        return r.u[0, :, 0].double().numpy(), 1000.0 * abs(float(r.pred_after_kg[0]) - goal_kg)

    def receding_run(
        self,
        s: StartState,
        pname: str | None,
        scorer: str,
        goal_kg: float,
        gen: Any,
        refine: str | None = None,
        start: float | None = None,
    ) -> tuple[Execution, int]:
        """Re-plan every ``receding`` control steps from the observed history: K policy
        samples toward the goal, ranked by ``scorer`` on the predicted water at the goal
        time, of which the first ``receding`` setpoints are executed. ``refine``: a metric
        of :func:`~rmi_learn.planning.refine.refine_chunk`, with which the ranked chunk is
        refined by ``scorer`` toward the goal at the goal time before it is executed.
        ``pname`` None: no policy; the plan starts as ``start`` N held and each re-plan
        refines the rest of the previous plan (its last setpoint held to the full chunk)."""
        h, n = self.h, self.receding
        if pname is None and (refine is None or start is None):
            raise ValueError("a receding run without a policy needs refine and start")
        planner = self.planners[(pname, scorer)] if pname is not None else None
        plan = torch.full((h, 1), float(start or 0.0))
        hist = s.hist.clone()
        mask = s.hist_mask.clone()
        wnow = s.water_now_std.clone()
        g_std = self._goal_std(np.asarray([goal_kg]))
        g_kg = self.std.water_to_kg(g_std)
        self.sim.set_state(s.state)
        self.sim.take_record()
        done, plans, peak = 0, 0, -np.inf
        e = Execution()
        while done < h:
            left = h - done
            if planner is not None:
                samples = planner.sample(hist, mask, self.std.goal_vector(g_std, wnow), gen)
                costs, _ = planner.score(hist, mask, samples, g_kg, step=left - 1)
                plan = samples[0, int(torch.argmin(costs["J"][0]))]
            if refine is not None:
                u, _ = self._refine(s, scorer, plan, goal_kg, left - 1, refine, hist, mask)
                plan = torch.as_tensor(u, dtype=torch.float32)[:, None]
            step = min(n, left)
            e = run_forces(
                self.sim, plan[:step, 0].double().numpy(), self.substeps, keep_records=True
            )
            plan = torch.cat([plan[step:], plan[-1:].expand(step, -1)])
            plans += 1
            if e.status != "ok":
                return e, plans
            peak = max(peak, float(e.peak_force_N or -np.inf))
            new = [standardise_record(r, self.ds.stats) for r in e.records]
            ys = torch.as_tensor(np.stack([y for y, _ in new]))[None]
            ms = torch.as_tensor(np.stack([m for _, m in new]))[None]
            hist = torch.cat([hist, ys], dim=1)[:, -s.hist.shape[1] :]
            mask = torch.cat([mask, ms], dim=1)[:, -s.hist.shape[1] :]
            wnow = self._goal_std(np.asarray([e.records[-1]["M_L"]]))
            done += step
        self.executions += 1
        e.peak_force_N = float(peak)
        e.records = []
        return e, plans


class _Executed:
    """Executions of policy samples (G, K, H, 1) N on demand, each chunk at most once:
    calling it with (goal index, sample index) returns that sample's execution."""

    def __init__(self, execute: Callable[[np.ndarray], Execution], samples: Any) -> None:
        self.execute, self.samples = execute, samples
        self.cache: dict[tuple[int, int], Execution] = {}

    def __call__(self, gi: int, j: int) -> Execution:
        if (gi, j) not in self.cache:
            self.cache[gi, j] = self.execute(self.samples[gi, j, :, 0].double().numpy())
        return self.cache[gi, j]


def simulator_scorer(sim: Any, state: bytes, substeps: int, std: Any) -> Any:
    """A :data:`~rmi_learn.planning.scorers.Scorer` that executes every chunk in the engine
    from ``state`` (force setpoints, as the benchmark does) and returns the executed M_L as
    the forecast (other channels and the class probabilities zero): the oracle scorer, with
    which ranking on the water term alone is best-of-K."""

    def score(hist: Any, hist_mask: Any, actions: Any) -> tuple[Any, Any, Any]:
        u = std.u_to_phys(actions)
        n, h, _ = u.shape
        z = torch.zeros(n, h, 18)
        for i in range(n):
            e = execute_forces(sim, state, u[i, :, 0].double().numpy(), substeps, True)
            if e.status != "ok":
                z[i] = float("nan")
                continue
            m = torch.as_tensor([r["M_L"] for r in e.records], dtype=torch.float32)
            z[i, :, 0] = (m - std.z_mean[0]) / std.z_std[0]
        return z, torch.zeros(n, h), torch.zeros(n, h, 4)

    return score


__all__ = [
    "ENSEMBLE",
    "FAMILIES",
    "SETPOINT_LOW_FRACTION",
    "Bench",
    "StartState",
    "seed_of",
    "simulator_scorer",
    "standardise_record",
]
