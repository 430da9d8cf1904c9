"""The goal-reaching benchmark driver (``rmi control-bench``): start states, goals,
controllers, checkpointed rows and tables. See :mod:`rmi_learn.control`."""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn import __version__
from rmi_learn.control import measures
from rmi_learn.control.execute import (
    Execution,
    execute_forces,
    run_forces,
    standardise_record,
    state_bytes_hash,
    state_fingerprint,
)
from rmi_learn.data.runs import atomic_write_bytes, atomic_write_json, json_safe
from rmi_learn.data.schema import (
    CONTROL_ACTION_INDEX,
    CONTROL_ACTIONS,
    CONTROL_DT,
    FORCE_LIMIT_N,
)
from rmi_learn.errors import InputError

#: Phases in which the robot acts on the water (anchors are drawn there).
ACTING_PHASES: tuple[str, ...] = ("hold", "lift", "waiting", "squeeze")
#: The lowest setpoint of the sweep, as a fraction of the run's holding force: the lower
#: edge of the lift gate's load band (``gate.force_band[0]``), the smallest grip the trial
#: counts as a stable hold; the run itself lifted and carried the sponge at F_hold.
SETPOINT_LOW_FRACTION = 0.8
#: World-model directory names that score chunks under another name in the tables.
SCORER_NAMES = {"transformer": "wt"}
#: Name of the scorer that combines every loaded world model (mean forecast, spread penalty).
ENSEMBLE = "ensemble"
WINDOWS_FILE = "control_windows.parquet"
SAMPLES_FILE = "control_samples.parquet"
TABLE_STEM = "table_control"
FIGURE_FILE = "fig_control.png"
SCORERS_FIGURE_FILE = "fig_control_scorers.png"
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")
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
#: Row statuses of a start state that ran no controller.
STATE_STATUSES = ("duplicate", "replay_failed")

#: Columns of ``control_windows.parquet``.
ROW_SCHEMA: dict[str, Any] = {
    "size_cm": pl.Int64,
    "run_id": pl.String,
    "t": pl.Int64,
    "k": pl.Int64,
    "anchor_phase": pl.String,
    "state_hash": pl.String,
    "state_bytes_sha256": pl.String,
    "water_now_kg": pl.Float64,
    "reach_min_kg": pl.Float64,
    "reach_max_kg": pl.Float64,
    "goal_kind": pl.String,
    "goal_index": pl.Int64,
    "goal_kg": pl.Float64,
    "controller": pl.String,
    "objective": pl.String,
    "scorer": pl.String,
    "sample_index": pl.Int64,
    "setpoint_N": pl.Float64,
    "M_L_end_kg": pl.Float64,
    "err_g": pl.Float64,
    "pred_err_g": pl.Float64,
    "peak_force_N": pl.Float64,
    "failure": pl.String,
    "phase_end": pl.String,
    "status": pl.String,
    "error": pl.String,
    "spearman": pl.Float64,
    "recorded_rank": pl.Int64,
    "pred_err_recorded_g": pl.Float64,
    "persistence_err_g": pl.Float64,
    "executions": pl.Int64,
    "wall_s": pl.Float64,
}

#: Columns of ``control_samples.parquet``: every executed chunk with every scorer's forecast.
#: ``objective`` is ``constant`` (the setpoint sweep), ``recorded`` or a policy name;
#: ``pred_M_L_kg`` holds one forecast of the terminal M_L per scorer, in the order of the
#: file's ``rmi.control.scorers`` metadata (and ``table_control.json`` -> ``sample_scorers``).
SAMPLE_SCHEMA: dict[str, Any] = {
    "size_cm": pl.Int64,
    "run_id": pl.String,
    "t": pl.Int64,
    "state_hash": pl.String,
    "goal_kind": pl.String,
    "goal_index": pl.Int64,
    "goal_kg": pl.Float64,
    "objective": pl.String,
    "sample_index": pl.Int64,
    "forces_N": pl.List(pl.Float64),
    "water_now_kg": pl.Float64,
    "M_L_end_kg": pl.Float64,
    "peak_force_N": pl.Float64,
    "status": pl.String,
    "pred_M_L_kg": pl.List(pl.Float64),
}


class ControlBenchError(InputError, ValueError):
    """Inputs the benchmark cannot use (missing or mismatched directories, bad goals or
    options); ``rmi control-bench`` reports it with exit status 2."""


# --------------------------------------------------------------------------------------
# Inputs


@dataclass
class PolicyInput:
    name: str
    net: Any
    objective: Any
    history: int
    horizon: int


@dataclass
class ScorerInput:
    name: str
    path: Path
    model: Any


@dataclass(frozen=True)
class Candidate:
    """A dataset window eligible as a start state: run, size, kept-row index ``t`` of the
    anchor and its global window index in the per-size window set."""

    size_cm: int
    run_id: str
    t: int
    window: int
    phase: str


def load_policies(policy_dir: Path, ds: Any) -> dict[str, PolicyInput]:
    """The trained policies under ``policy_dir`` (``diffusion/`` and/or ``flow/``, any other
    policy run beside them, such as a distilled one, under its directory's name; or one policy
    run directory itself), checked against the dataset's statistics."""
    from rmi_learn.policies.checkpoint import load_policy

    if not policy_dir.is_dir():
        raise ControlBenchError(f"--policy {policy_dir} is not a directory")
    dirs = {o: policy_dir / o for o in OBJECTIVES if (policy_dir / o / "config.json").exists()}
    for d in sorted(policy_dir.iterdir()):
        if d.name not in dirs and d.is_dir() and _is_policy_run(d / "config.json"):
            dirs[d.name] = d
    if not dirs and (policy_dir / "config.json").exists():
        cfg = json.loads((policy_dir / "config.json").read_text())
        dirs = {str(cfg.get("model", {}).get("objective")): policy_dir}
    if not dirs:
        raise ControlBenchError(
            f"--policy {policy_dir} holds no trained policy (diffusion/ or flow/ from "
            "`rmi train-policy`)"
        )
    water_std = float(ds.stats.z_std[0])
    out: dict[str, PolicyInput] = {}
    for name, d in dirs.items():
        try:
            net, objective, cfg = load_policy(d)
        except (OSError, ValueError, KeyError) as exc:
            raise ControlBenchError(f"--policy {d}: {exc}") from exc
        ws = (cfg.get("extra") or {}).get("water_std_kg")
        if ws is not None and not math.isclose(float(ws), water_std, rel_tol=1e-6):
            raise ControlBenchError(
                f"--policy {d} was trained on another dataset (M_L std {float(ws):.6g} kg, "
                f"the dataset's {water_std:.6g} kg)"
            )
        out[name] = PolicyInput(
            name, net, objective, int(cfg["model"]["history"]), int(cfg["model"]["horizon"])
        )
    if len({(p.history, p.horizon) for p in out.values()}) != 1:
        raise ControlBenchError("the policies differ in history or chunk length")
    return out


def _is_policy_run(config: Path) -> bool:
    """Whether ``config`` is the config.json of a policy run (not a world model's)."""
    try:
        cfg = json.loads(config.read_text())
    except (OSError, ValueError):
        return False
    model = cfg.get("model") if isinstance(cfg, dict) else None
    return isinstance(model, dict) and model.get("objective") in OBJECTIVES


def _can_score(model: Any, horizon: int) -> str | None:
    """Why ``model`` cannot rank chunks of ``horizon`` steps, or None."""
    if model.kind == "baseline" or not getattr(model, "action_conditioned", True):
        return "does not see the actions"
    try:
        model.check_horizon_length(horizon)
    except ValueError as exc:
        return str(exc)
    return None


def load_scorers(
    wm_dir: Path, ds: Any, horizon: int, wanted: Sequence[str] | None
) -> tuple[dict[str, ScorerInput], dict[str, str]]:
    """World models under ``wm_dir`` that can rank chunks (action-conditioned, horizon fits),
    by table name (``wt`` for ``transformer``); ``wanted`` restricts them (by table or
    directory name; a wanted model that cannot score is an error). Returns the scorers and
    the models left out with the reason."""
    from rmi_learn import world_models as models
    from rmi_learn.policies.ranking import _stats_close

    if not wm_dir.is_dir():
        raise ControlBenchError(f"--wm {wm_dir} is not a directory")
    found = sorted(p.parent for p in wm_dir.glob("*/config.json"))
    if (wm_dir / "config.json").exists():
        found = [wm_dir]
    names = {SCORER_NAMES.get(p.name, p.name): p for p in found}
    if wanted:
        alias = {**{p.name: n for n, p in names.items()}, **{n: n for n in names}}
        missing = [w for w in wanted if w not in alias]
        if missing:
            raise ControlBenchError(
                f"--scorers {missing}: no such world model in {wm_dir} (found {sorted(names)})"
            )
        names = {alias[w]: names[alias[w]] for w in wanted}
    scorers: dict[str, ScorerInput] = {}
    skipped: dict[str, str] = {}
    for name, path in names.items():
        try:
            model, cfg = models.load(path)
        except (OSError, ValueError, KeyError) as exc:
            raise ControlBenchError(f"--wm {path}: {exc}") from exc
        why = _can_score(model, horizon)
        if why is not None:
            if wanted:
                raise ControlBenchError(f"--scorers {name}: {path} cannot rank chunks: {why}")
            skipped[name] = why
            continue
        stats = (cfg.get("extra") or {}).get("stats")
        if stats is not None and not _stats_close(ds.stats, stats):
            raise ControlBenchError(
                f"--wm {path} was trained with other standardisation statistics than "
                f"--data {ds.root}"
            )
        scorers[name] = ScorerInput(name, path, model)
    if not scorers:
        raise ControlBenchError(f"--wm {wm_dir}: no world model that can rank chunks")
    # The first scorer is the default one (receding horizon): W_T when present.
    order = sorted(scorers, key=lambda n: (n != "wt", n)) if not wanted else list(scorers)
    return {n: scorers[n] for n in order}, skipped


def candidates(ds: Any, split: str, history: int, horizon: int) -> dict[int, list[Candidate]]:
    """Per size, every window of ``split`` whose anchor lies in an acting phase."""
    phases = ds.frames["phase"].to_numpy().astype(str)
    out: dict[int, list[Candidate]] = {}
    for size in sorted(ds.runs["size_cm"].unique().to_list()):
        ws = ds.windows(split, int(size), history=history, horizon=horizon)
        cands = [
            Candidate(
                int(size),
                ds.run_ids[int(ds.row_run[a])],
                int(ds.row_t[a]),
                i,
                str(phases[a]),
            )
            for i, a in enumerate(ws.anchors.tolist())
            if phases[a] in ACTING_PHASES
        ]
        if cands:
            out[int(size)] = cands
    return out


def draw_order(cands: Sequence[Candidate], seed: int, size: int) -> list[Candidate]:
    """The candidates in a seeded random order (the first N distinct states are used)."""
    perm = np.random.default_rng([seed, size, 0x57A7E]).permutation(len(cands))
    return [cands[i] for i in perm.tolist()]


def check_goals(goals: Sequence[float], total_water: Mapping[str, float]) -> None:
    """Refuse goals that no start state can have: NaN, negative, or above the water present
    in a held-out run (kg)."""
    for g in goals:
        if not math.isfinite(g) or g < 0.0:
            raise ControlBenchError(f"--goal-kg {g!r}: a goal must be a finite mass >= 0 kg")
        for rid, w in total_water.items():
            if g > w:
                raise ControlBenchError(
                    f"--goal-kg {g!r}: above the {w:.6g} kg of water present in run {rid}"
                )


def _seed(*parts: Any) -> int:
    return zlib.crc32("|".join(str(p) for p in parts).encode())


# --------------------------------------------------------------------------------------
# Controllers of one start state


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
        from rmi_learn.policies.ranking import (
            EnsembleScorer,
            Planner,
            Standardiser,
            world_model_scorer,
        )

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
        import torch

        g = torch.as_tensor(np.asarray(g_kg), dtype=torch.float32)
        return (g - self.std.z_mean[0]) / self.std.z_std[0]

    def _sample_row(
        self, base: Mapping[str, Any], objective: str, index: int, forces: Any, e: Execution,
        pred_kg: Sequence[float], goal: tuple[str, int, float] | None = None,
    ) -> None:
        self.samples.append({
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
        })

    # -- one state ------------------------------------------------------------------

    def state_rows(self, s: StartState) -> list[dict[str, Any]]:
        """Every row of one start state: the setpoint sweep and its reachable interval, the
        goals, and each controller executed from the state toward each goal."""
        import torch

        c, tr, h = s.cand, s.track, self.h
        t0 = time.perf_counter()
        water_now = float(tr.water[c.t])
        f_hold = float(tr.config["hold_force"])
        setpoints = np.linspace(SETPOINT_LOW_FRACTION * f_hold, FORCE_LIMIT_N, self.n_setpoints)
        sweep = [(float(f), self._exec(s.state, np.full(h, f))) for f in setpoints]
        reached = [e.M_L for _, e in sweep if e.status == "ok" and e.M_L is not None]
        lo, hi = (min(reached), max(reached)) if reached else (None, None)
        rng = np.random.default_rng(_seed(self.seed, c.run_id, c.t, "goals"))
        drawn = (
            rng.uniform(lo, hi, self.goals_per_state)
            if lo is not None and hi is not None
            else np.zeros(0)
        )
        goals: list[tuple[str, int, float]] = [("drawn", i, float(g)) for i, g in enumerate(drawn)]
        goals.append(("logged", 0, float(tr.water[c.t + h])))
        goals += [("given", i, float(g)) for i, g in enumerate(self.given_goals)]
        base = {
            "size_cm": c.size_cm,
            "run_id": c.run_id,
            "t": c.t,
            "k": int(tr.k[c.t]),
            "anchor_phase": c.phase,
            "state_hash": s.fingerprint,
            "state_bytes_sha256": s.bytes_hash,
            "water_now_kg": water_now,
            "reach_min_kg": lo,
            "reach_max_kg": hi,
        }
        rows: list[dict[str, Any]] = []

        def row(goal: tuple[str, int, float], ctrl: str, e: Execution, **kw: Any) -> None:
            g = goal[2]
            rows.append(
                {
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
            )

        recorded_f = tr.actions[c.t : c.t + h, 0]
        rec = self._exec(s.state, recorded_f)
        logged = next(g for g in goals if g[0] == "logged")
        row(logged, "recorded", rec, executions=1)
        # Every scorer's forecast of the sweep's and the recorded chunk's outcome.
        self.samples = []
        ref_u = torch.as_tensor(
            np.stack([np.full(h, f) for f, _ in sweep] + [recorded_f])[None, :, :, None],
            dtype=torch.float32,
        )
        first_pol = next(iter(self.policies))
        ref_pred = np.stack([
            self.planners[(first_pol, sn)].score(
                s.hist, s.hist_mask, ref_u, torch.zeros(1)
            )[1][0].double().numpy()
            for sn in self.scorer_names
        ], axis=-1)
        for i, (f, e) in enumerate(sweep):
            self._sample_row(base, "constant", i, np.full(h, f), e, ref_pred[i])
        self._sample_row(base, "recorded", 0, recorded_f, rec, ref_pred[-1])
        for goal in goals:
            ok = [(f, e) for f, e in sweep if e.status == "ok" and e.M_L is not None]
            if ok:
                f, e = min(ok, key=lambda fe: abs(fe[1].M_L - goal[2]))  # type: ignore[operator]
                row(goal, "constant-best", e, setpoint_N=f, executions=len(sweep))
        g_kg = np.asarray([g[2] for g in goals])
        g_std = self._goal_std(g_kg)
        n_goals = len(goals)
        hist = s.hist.expand(n_goals, -1, -1).contiguous()
        mask = s.hist_mask.expand(n_goals, -1, -1).contiguous()
        wnow = s.water_now_std.expand(n_goals).contiguous()
        goal_kg_t = self.std.water_to_kg(g_std)
        recorded_u = torch.as_tensor(
            tr.actions[c.t : c.t + h, list(CONTROL_ACTION_INDEX)],
            dtype=torch.float32,
        )
        for pname in self.policies:
            first_planner = self.planners[(pname, self.default_scorer)]
            gen = torch.Generator().manual_seed(_seed(self.seed, c.run_id, c.t, pname))
            samples = first_planner.sample(
                hist, mask, self.std.goal_vector(g_std, wnow), gen
            )  # (G, K, H, 1)
            # Samples run on demand, once each: only best-of-K needs all K.
            run_sample = _Executed(lambda u: self._exec(s.state, u), samples)

            every = "best-of-k" in self.families
            recorded = recorded_u.expand(n_goals, 1, h, len(CONTROL_ACTIONS))
            cand = torch.cat([samples, recorded], dim=1)
            scored = {
                sn: self.planners[(pname, sn)].score(hist, mask, cand, goal_kg_t)
                for sn in self.scorer_names
            }
            pred_kg = np.stack(
                [scored[sn][1].double().numpy() for sn in self.scorer_names], axis=-1
            )  # (G, K + 1, scorers)
            for gi, goal in enumerate(goals):
                errs = np.full(self.k, np.nan)
                if every:
                    for j in range(self.k):
                        e = run_sample(gi, j)
                        self._sample_row(base, pname, j, samples[gi, j, :, 0].double().numpy(),
                                         e, pred_kg[gi, j], goal)
                        errs[j] = np.inf if e.M_L is None else 1000.0 * abs(e.M_L - goal[2])
                    best = int(np.argmin(errs))
                    row(goal, f"best-of-k/{pname}", run_sample(gi, best), objective=pname,
                        sample_index=best, executions=self.k)
                if "first-sample" in self.families:
                    row(goal, f"first-sample/{pname}", run_sample(gi, 0), objective=pname,
                        sample_index=0, executions=1)
                for sn, (costs, _water) in scored.items():
                    j = costs["J"][gi]
                    idx = int(torch.argmin(j[: self.k]))
                    pred = costs["J_M"][gi].double().numpy()
                    if "ranked" in self.families:
                        finite = np.isfinite(errs)
                        rank_rec = int(1 + np.sum(j[: self.k].numpy() < float(j[self.k])))
                        row(
                            goal,
                            f"ranked-{sn}/{pname}",
                            run_sample(gi, idx),
                            objective=pname,
                            scorer=sn,
                            sample_index=idx,
                            pred_err_g=float(pred[idx]),
                            spearman=(
                                measures.spearman(pred[: self.k][finite], errs[finite])
                                if every else None
                            ),
                            recorded_rank=rank_rec,
                            pred_err_recorded_g=float(pred[self.k]),
                            persistence_err_g=1000.0 * abs(water_now - goal[2]),
                            executions=self.k if every else 1,
                        )
                    if "refined" not in self.families or sn not in self.refine_scorers:
                        continue
                    for metric in self.refine_metrics:
                        u, pred_g = self._refine(s, sn, samples[gi, idx], goal[2], h - 1, metric)
                        row(goal, f"{self._refined_name(sn, metric)}/{pname}",
                            self._exec(s.state, u), objective=pname, scorer=sn,
                            sample_index=idx, pred_err_g=pred_g, executions=1)
                plain = self.receding_scorers if "receding" in self.families else []
                refined = (
                    self.refine_scorers if "receding-refined" in self.families else []
                )
                runs = [(x, None) for x in plain] + [(x, self.refine_metrics[0]) for x in refined]
                for sn, how in runs if self.receding else ():
                    # The same draws for every scorer: they differ only in their choices.
                    rgen = torch.Generator().manual_seed(
                        _seed(self.seed, c.run_id, c.t, pname, "receding", gi)
                    )
                    e, n_plans = self.receding_run(s, pname, sn, goal[2], rgen, refine=how)
                    if how is not None:
                        name = f"receding-{self.receding}-refined-{sn}"
                    else:
                        name = f"receding-{self.receding}" + (
                            "" if sn == self.default_scorer else f"-{sn}"
                        )
                    row(goal, f"{name}/{pname}", e, objective=pname, scorer=sn,
                        executions=n_plans)
        # Model-based control without a policy: the last applied setpoint held, refined.
        hold = float(tr.actions[max(c.t - 1, 0), 0])
        for goal in goals:
            for sn in self.refine_scorers:
                metric = self.refine_metrics[0]
                if "model" in self.families:
                    start = torch.full((h, 1), hold)
                    u, pred_g = self._refine(s, sn, start, goal[2], h - 1, metric)
                    row(goal, f"model-{sn}", self._exec(s.state, u), scorer=sn,
                        setpoint_N=hold, pred_err_g=pred_g, executions=1)
                if "receding-model" in self.families and self.receding:
                    e, n_plans = self.receding_run(s, None, sn, goal[2], None, refine=metric,
                                                   start=hold)
                    row(goal, f"receding-{self.receding}-model-{sn}", e, scorer=sn,
                        setpoint_N=hold, executions=n_plans)
        wall = time.perf_counter() - t0
        for r in rows:
            r["wall_s"] = wall
        return rows

    def _refined_name(self, scorer: str, metric: str) -> str:
        return f"refined-{scorer}" if metric == self.refine_metrics[0] else (
            f"refined-{metric}-{scorer}"
        )

    def _refine(
        self, s: StartState, scorer: str, u: Any, goal_kg: float, step: int, metric: str,
        hist: Any = None, mask: Any = None,
    ) -> tuple[np.ndarray, float]:
        """The chunk ``u`` (H, 1) N refined by ``scorer`` toward ``goal_kg`` at command
        ``step`` (:func:`~rmi_learn.control.refine.refine_chunk`), never below the sweep's
        lowest setpoint unless it starts there; returns the setpoints (H,) and the scorer's
        forecast error after refinement (g)."""
        import torch

        from rmi_learn.control.refine import refine_chunk

        floor = SETPOINT_LOW_FRACTION * float(s.track.config["hold_force"])
        u = torch.as_tensor(u, dtype=torch.float32)[None]
        g = torch.as_tensor([goal_kg], dtype=torch.float32)
        r = refine_chunk(
            self.fns[scorer], self.std, s.hist if hist is None else hist,
            s.hist_mask if mask is None else mask, u, g, step,
            lower=torch.clamp(u, max=floor), metric=metric,
        )
        return r.u[0, :, 0].double().numpy(), 1000.0 * abs(float(r.pred_after_kg[0]) - goal_kg)

    def receding_run(
        self, s: StartState, pname: str | None, scorer: str, goal_kg: float, gen: Any,
        refine: str | None = None, start: float | None = None,
    ) -> tuple[Execution, int]:
        """Re-plan every ``receding`` control steps from the observed history: K policy
        samples toward the goal, ranked by ``scorer`` on the predicted water at the goal
        time, of which the first ``receding`` setpoints are executed. ``refine``: a metric
        of :func:`~rmi_learn.control.refine.refine_chunk`, with which the ranked chunk is
        refined by ``scorer`` toward the goal at the goal time before it is executed.
        ``pname`` None: no policy; the plan starts as ``start`` N held and each re-plan
        refines the rest of the previous plan (its last setpoint held to the full chunk)."""
        import torch

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
            e = run_forces(self.sim, plan[:step, 0].double().numpy(), self.substeps,
                           keep_records=True)
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
    """A :data:`~rmi_learn.policies.ranking.Scorer` that executes every chunk in the engine
    from ``state`` (force setpoints, as the benchmark does) and returns the executed M_L as
    the forecast (other channels and the class probabilities zero): the oracle scorer, with
    which ranking on the water term alone is best-of-K."""
    import torch

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


# --------------------------------------------------------------------------------------
# Checkpoint


@dataclass
class Checkpoint:
    """``control_windows.parquet`` (the controllers' rows) and ``control_samples.parquet``
    (every executed chunk), tied to the inputs and options by a fingerprint in the files'
    metadata and rewritten atomically after every start state: the samples first, so that
    the windows file, which decides what is done, never lists a state whose samples are
    missing."""

    path: Path
    fingerprint: str
    samples_path: Path | None = None
    scorers: tuple[str, ...] = ()
    #: Settings stored with the samples (``rmi.control.info``): what re-ranking needs.
    info: Mapping[str, Any] | None = None

    def _read(self, path: Path, schema: Mapping[str, Any]) -> pl.DataFrame:
        advice = "use another --out or delete that file to start over"
        try:
            stored = pl.read_parquet_metadata(path).get("rmi.control.fingerprint")
            frame = pl.read_parquet(path)
        except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same advice
            raise ControlBenchError(f"{path} is not readable ({exc}); {advice}") from exc
        if stored != self.fingerprint:
            raise ControlBenchError(f"{path} holds results of other inputs; {advice}")
        if frame.columns != list(schema):
            raise ControlBenchError(f"{path} has other columns than this version; {advice}")
        return frame

    def load(self) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
        """The stored rows and sample rows (none when the files do not exist); refuses files
        of other inputs, options or columns with advice, since resuming them would mix
        results. Samples of a state the windows file does not list (an interruption between
        the two writes) are dropped: that state runs again."""
        if not self.path.exists():
            return [], []
        rows = self._read(self.path, ROW_SCHEMA).to_dicts()
        samples: list[dict[str, Any]] = []
        if self.samples_path is not None and self.samples_path.exists():
            done = {(r["run_id"], r["t"]) for r in rows}
            samples = [
                r for r in self._read(self.samples_path, SAMPLE_SCHEMA).to_dicts()
                if (r["run_id"], r["t"]) in done
            ]
        return rows, samples

    def save(
        self, rows: Sequence[Mapping[str, Any]], samples: Sequence[Mapping[str, Any]] = ()
    ) -> None:
        """Write every sample row (when there is a samples file), then every row, atomically."""
        meta = {"rmi.control.fingerprint": self.fingerprint, "rmi.version": __version__}
        if self.samples_path is not None:
            frame = _frame(samples, SAMPLE_SCHEMA)
            smeta = {
                **meta,
                "rmi.control.scorers": json.dumps(list(self.scorers)),
                "rmi.control.info": json.dumps(dict(self.info or {})),
            }
            atomic_write_bytes(
                self.samples_path, lambda f: frame.write_parquet(f, metadata=smeta)
            )
        windows = _frame(rows, ROW_SCHEMA)
        atomic_write_bytes(self.path, lambda f: windows.write_parquet(f, metadata=meta))


def _frame(rows: Sequence[Mapping[str, Any]], schema: Mapping[str, Any]) -> pl.DataFrame:
    return pl.DataFrame(
        [pl.Series(c, [r.get(c) for r in rows], dtype=d) for c, d in schema.items()]
    )


def _full(row: Mapping[str, Any]) -> dict[str, Any]:
    """A row with every column of :data:`ROW_SCHEMA` (None where it does not apply)."""
    return {c: row.get(c) for c in ROW_SCHEMA}


# --------------------------------------------------------------------------------------
# Driver


def run_control_bench(
    runs: str | os.PathLike[str],
    data: str | os.PathLike[str],
    wm: str | os.PathLike[str],
    policy: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    states_per_size: int = 4,
    goals_per_state: int = 2,
    setpoints: int = 5,
    k: int = 8,
    receding: int = 8,
    scorers: Sequence[str] | None = None,
    ensemble: bool = True,
    receding_scorers: Sequence[str] = (),
    refine_scorers: Sequence[str] = (),
    refine_metrics: Sequence[str] = ("smooth",),
    controllers: Sequence[str] | None = None,
    sizes: Sequence[int] | None = None,
    goal_kg: Sequence[float] = (),
    split: str = "test",
    seed: int = 0,
    threads: int = 1,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the goal-reaching benchmark (see :mod:`rmi_learn.control`) and write
    ``control_windows.parquet``, ``control_samples.parquet``, ``table_control.{md,json}``,
    ``fig_control.png`` and ``fig_control_scorers.png`` to ``out``. ``runs``: the sweep
    output (``index.parquet``) the dataset ``data`` was built from; ``wm``: a directory of
    world-model runs (``rmi train-wm`` outputs) or one run;
    ``policy``: a directory holding ``diffusion/`` and/or ``flow/`` policy runs.
    ``receding``: re-planning period of the receding-horizon controller in control steps
    (0: none). ``scorers``: world models to rank with (default every one that can);
    ``ensemble``: with two or more, also rank by their ensemble (``ranked-ensemble``: mean
    forecast, members' spread as a penalty). ``receding_scorers``: the scorers of the
    receding-horizon controller (default the first scorer, W_T when present; others are
    named ``receding-<n>-<scorer>``). ``refine_scorers``: the scorers whose gradient
    refines the ranked chunk (``refined-<scorer>/<policy>``, one per metric of
    ``refine_metrics``, see :mod:`rmi_learn.control.refine`), the re-planned chunks
    (``receding-<n>-refined-<scorer>/<policy>``) and a held setpoint without a policy
    (``model-<scorer>``, ``receding-<n>-model-<scorer>``); default the receding scorers.
    ``controllers``: the families of :data:`FAMILIES` to run (default all). ``sizes``: the
    sponge sizes (cm) to draw start states from (default every size of the split; each
    size's states are drawn independently, so a run can be extended to other sizes).
    ``goal_kg``: extra goals (kg) for every state. States already in the checkpoint are not
    run again; a larger ``states_per_size`` extends it. Returns the summary written to
    ``table_control.json``. Raises :class:`ControlBenchError` for unusable inputs, before
    anything is written."""
    import torch
    from tqdm.auto import tqdm  # type: ignore[import-untyped]

    import rmi_sph
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.closed_loop import (
        Window,
        _sha256,
        check_anchor,
        control_substeps,
        load_index,
        load_track,
    )

    for name, v, low in (
        ("states_per_size", states_per_size, 1),
        ("goals_per_state", goals_per_state, 0),
        ("setpoints", setpoints, 2),
        ("k", k, 1),
        ("receding", receding, 0),
        ("threads", threads, 1),
    ):
        if v < low:
            raise ControlBenchError(f"{name} must be >= {low}, got {v}")
    say = log or (lambda _m: None)
    runs_p, data_p, wm_p, pol_p, out_p = map(Path, (runs, data, wm, policy, out))
    try:
        ds = load_dataset(data_p)
    except (OSError, ValueError) as exc:
        raise ControlBenchError(f"--data {data_p}: {exc}") from exc
    index = load_index(runs_p)
    pols = load_policies(pol_p, ds)
    first_pol = next(iter(pols.values()))
    hist_len, h = first_pol.history, first_pol.horizon
    if receding > h:
        raise ControlBenchError(f"receding must be at most the chunk length {h}, got {receding}")
    scs, skipped = load_scorers(wm_p, ds, h, scorers)
    rank_names = list(scs) + ([ENSEMBLE] if ensemble and len(scs) >= 2 else [])
    for flag, names in (("--receding-scorers", receding_scorers),
                        ("--refine-scorers", refine_scorers)):
        bad = [n for n in names if n not in rank_names]
        if bad:
            raise ControlBenchError(f"{flag} {bad}: not among the scorers {rank_names}")
    # Defaults resolved once: the first scorer re-plans, the re-planning scorers refine.
    receding_scorers = list(receding_scorers) or [rank_names[0]]
    refine_scorers = list(refine_scorers) or receding_scorers
    from rmi_learn.control.refine import METRICS

    bad = [m for m in refine_metrics if m not in METRICS] or (
        ["(none)"] if not refine_metrics else []
    )
    if bad or len(set(refine_metrics)) != len(refine_metrics):
        raise ControlBenchError(
            f"--refine-metrics {list(refine_metrics)}: give distinct metrics of {list(METRICS)}"
        )
    families = list(FAMILIES) if controllers is None else list(controllers)
    bad = [f for f in families if f not in FAMILIES]
    if bad or not families:
        raise ControlBenchError(
            f"--controllers {bad or '(none)'}: choose among {list(FAMILIES)}"
        )
    split_used = split
    if not len(ds.split_runs(split)):
        split_used = "val"
        say(f"control-bench: the {split} split is empty; start states from the val split")
    cands = candidates(ds, split_used, hist_len, h)
    if sizes is not None:
        missing = sorted(set(sizes) - set(cands))
        if missing or not sizes:
            raise ControlBenchError(
                f"--sizes {list(sizes)}: the {split_used} split has start states for sizes "
                f"{sorted(cands)} cm only"
            )
        cands = {size: cs for size, cs in cands.items() if size in sizes}
    if not cands:
        raise ControlBenchError(
            f"no window of the {split_used} split has its anchor in {ACTING_PHASES}"
        )
    pool_runs = sorted({c.run_id for cs in cands.values() for c in cs})
    unknown = [r for r in pool_runs if r not in index]
    if unknown:
        raise ControlBenchError(
            f"run {unknown[0]!r} of --data is not a completed run of --runs {runs_p}: give the "
            "sweep the dataset was built from"
        )
    tracks = {rid: load_track(index[rid]) for rid in pool_runs}
    for cs in cands.values():
        for c in cs:
            tr = tracks[c.run_id]
            row = ds.frames.filter(
                (pl.col("run") == ds.run_ids.index(c.run_id)) & (pl.col("t") == c.t)
            )
            if c.t + h >= tr.k.size or row.is_empty() or int(row["k"][0]) != int(tr.k[c.t]):
                raise ControlBenchError(
                    f"window (run {c.run_id}, t={c.t}) lies outside that run's learning rows in "
                    f"--runs {runs_p}: the dataset was built from another sweep"
                )
            if tr.k[c.t + h] - tr.k[c.t] != h:
                raise ControlBenchError(
                    f"window (run {c.run_id}, t={c.t}) crosses a gap of the run's rows"
                )
    total_water = {rid: float(tracks[rid].water.max()) for rid in pool_runs}
    try:
        from rmi_learn.data.runs import read_run

        for rid in pool_runs:
            tw = read_run(index[rid])[1].get("outcome", {}).get("total_water")
            if tw is not None:
                total_water[rid] = float(tw)
    except (OSError, ValueError) as exc:
        raise ControlBenchError(f"cannot read a run file of --runs: {exc}") from exc
    check_goals(list(goal_kg), total_water)
    configs = {}
    for rid in pool_runs:
        try:
            configs[rid] = rmi_sph.validate_config(tracks[rid].config)
        except rmi_sph.ConfigError as exc:
            raise ControlBenchError(f"the stored config of run {rid} is refused: {exc}") from exc
        control_substeps(float(configs[rid]["dt"]))

    options = {
        "k": k,
        "goals_per_state": goals_per_state,
        "setpoints": setpoints,
        "receding": receding,
        "goal_kg": [float(g) for g in goal_kg],
        "split": split_used,
        "seed": seed,
        "scorers": sorted(scs),
        "ensemble": bool(ensemble and len(scs) >= 2),
        "receding_scorers": receding_scorers,
        "refine_scorers": refine_scorers,
        "refine_metrics": list(refine_metrics),
        "controllers": [f for f in FAMILIES if f in families],
        "horizon": h,
        "history": hist_len,
    }
    digest = hashlib.sha256(json.dumps(options, sort_keys=True).encode())
    for p in [data_p / "stats.json", data_p / "runs.parquet"] + [
        d for pol in sorted(pols) for d in (pol_p / pol / "model.ema.safetensors",)
    ] + [sc.path / "model.safetensors" for sc in scs.values()]:
        if p.exists():
            digest.update(f"{p.name}={_sha256(p)}".encode())
    fingerprint = digest.hexdigest()

    out_p.mkdir(parents=True, exist_ok=True)
    ckpt = Checkpoint(
        out_p / WINDOWS_FILE, fingerprint, out_p / SAMPLES_FILE, tuple(rank_names),
        {"data": str(data_p), "wm": str(wm_p), "policy": str(pol_p), "split_used": split_used,
         **options},
    )
    rows, sample_rows = ckpt.load()
    done = {(r["run_id"], r["t"]) for r in rows}
    seen = {
        r["state_hash"]: (r["run_id"], r["t"]) for r in rows if r["status"] not in STATE_STATUSES
    }
    say(
        f"control-bench: {sum(len(c) for c in cands.values())} candidate windows in "
        f"{len(cands)} size(s), scorers {sorted(scs)}, policies {sorted(pols)}"
    )
    t_start = time.perf_counter()
    n_new = 0
    bar = tqdm(desc="control-bench", unit="state", disable=not progress, dynamic_ncols=True)
    try:
        for size, cs in cands.items():
            order = draw_order(cs, seed, size)
            pos = 0
            while pos < len(order):
                distinct = len(
                    {r["state_hash"] for r in rows
                     if r["size_cm"] == size and r["status"] not in STATE_STATUSES}
                )
                need = states_per_size - distinct
                if need <= 0:
                    break
                batch: list[Candidate] = []
                while pos < len(order) and len(batch) < need:
                    if (order[pos].run_id, order[pos].t) not in done:
                        batch.append(order[pos])
                    pos += 1
                ws = ds.windows(split_used, size, history=hist_len, horizon=h)
                for rid in sorted({c.run_id for c in batch}):
                    tr = tracks[rid]
                    sim = rmi_sph.Trial(configs[rid], num_threads=threads)
                    substeps = control_substeps(float(sim.dt))
                    bench = Bench(
                        sim, substeps, ds, pols, scs, k=k, horizon=h, n_setpoints=setpoints,
                        goals_per_state=goals_per_state, given_goals=goal_kg,
                        receding=receding, seed=seed, ensemble=ensemble,
                        receding_scorers=receding_scorers, refine_scorers=refine_scorers,
                        refine_metrics=refine_metrics, controllers=families,
                    )
                    auto: bytes | None = None
                    for c in sorted((c for c in batch if c.run_id == rid), key=lambda c: c.t):
                        target = round(float(tr.k[c.t]) * CONTROL_DT / float(sim.dt))
                        try:
                            if auto is not None:
                                sim.set_state(auto)
                            elif sim.step_count > 0:
                                sim = rmi_sph.Trial(configs[rid], num_threads=threads)
                                bench.sim = sim
                            sim.step(target - sim.step_count)
                        except rmi_sph.RmiError as exc:
                            # Deterministic: the same replay fails again, so it is recorded.
                            auto = None
                            rows.append(_full({
                                "size_cm": size, "run_id": rid, "t": c.t,
                                "k": int(tr.k[c.t]), "anchor_phase": c.phase,
                                "status": "replay_failed", "error": f"{type(exc).__name__}: {exc}",
                            }))
                            done.add((rid, c.t))
                            ckpt.save(rows, sample_rows)
                            continue
                        check_anchor(sim, tr, Window(rid, size, c.t, ()))
                        state = sim.get_state()
                        auto = state
                        fp = state_fingerprint(sim)
                        if fp in seen:
                            rows.append(_full({
                                "size_cm": size, "run_id": rid, "t": c.t,
                                "k": int(tr.k[c.t]), "anchor_phase": c.phase,
                                "state_hash": fp, "state_bytes_sha256": state_bytes_hash(state),
                                "status": "duplicate",
                                "error": f"same state as run {seen[fp][0]}, t={seen[fp][1]}",
                            }))
                        else:
                            b = ws.batch([c.window])
                            s = StartState(
                                c, tr, state, fp, state_bytes_hash(state),
                                b["hist"], b["hist_mask"], b["water_now"],
                            )
                            with torch.no_grad():
                                rows.extend(_full(r) for r in bench.state_rows(s))
                            sample_rows.extend(bench.samples)
                            seen[fp] = (rid, c.t)
                            n_new += 1
                            bar.update(1)
                        done.add((rid, c.t))
                        ckpt.save(rows, sample_rows)
                        bar.set_postfix_str(f"{size} cm {rid} t={c.t}", refresh=False)
    finally:
        bar.close()
    wall = time.perf_counter() - t_start

    objectives = [o for o in OBJECTIVES if o in pols] + sorted(set(pols) - set(OBJECTIVES))
    summary = measures.summarise(rows, objectives, seed)
    diag = measures.scorer_diagnostics(sample_rows, rank_names)
    states_info = {}
    for size, cs in cands.items():
        srows = [r for r in rows if r["size_cm"] == size]
        anchors = ds.windows(split_used, size, hist_len, h).anchors
        # Windows whose recorded rows (history, anchor and future) are identical.
        recorded_keys = {
            hashlib.sha256(
                ds.y_std[anchors[c.window] - hist_len + 1 : anchors[c.window] + h + 1].tobytes()
            ).hexdigest()
            for c in cs
        }
        states_info[str(size)] = {
            "candidate_windows": len(cs),
            "candidate_windows_distinct_recorded_rows": len(recorded_keys),
            "replayed": len({(r["run_id"], r["t"]) for r in srows}),
            "distinct_states": len(
                {r["state_hash"] for r in srows if r["status"] not in STATE_STATUSES}
            ),
            "replay_failed": len(
                {(r["run_id"], r["t"]) for r in srows if r["status"] == "replay_failed"}
            ),
            "duplicates": len({(r["run_id"], r["t"]) for r in srows if r["status"] == "duplicate"}),
            "distinct_raw_state_bytes": len(
                {r["state_bytes_sha256"] for r in srows if r["state_bytes_sha256"]}
            ),
        }
    info = {
        "runs": str(runs_p),
        "data": str(data_p),
        "wm": str(wm_p),
        "policy": str(pol_p),
        "split": split,
        "split_used": split_used,
        "phases": list(ACTING_PHASES),
        "states_per_size": states_per_size,
        **options,
        "threads": threads,
        "control_dt_s": CONTROL_DT,
        "force_limit_N": FORCE_LIMIT_N,
        "setpoint_low_fraction": SETPOINT_LOW_FRACTION,
        "setpoint_fractions": [float(x) for x in np.linspace(0.0, 1.0, setpoints)],
        "scorers_skipped": skipped,
        "sample_scorers": rank_names,
        "default_scorer": next(iter(scs)),
        "objectives": objectives,
        "unit": "g",
        "tie_g": measures.TIE_G,
    }
    payload = {
        **info,
        "states": states_info,
        "summary": summary,
        "scorer_diagnostics": diag,
        "states_run_now": n_new,
        "wall_s": wall,
        "wall_s_per_state": wall / n_new if n_new else None,
        "version": __version__,
    }
    atomic_write_json(out_p / f"{TABLE_STEM}.json", json_safe(payload))
    md = measures.markdown(summary, info, diag)
    atomic_write_bytes(out_p / f"{TABLE_STEM}.md", lambda f: f.write(md.encode("utf-8")))
    tmp = out_p / f".{FIGURE_FILE}.tmp.png"
    measures.figure(rows, tmp)
    os.replace(tmp, out_p / FIGURE_FILE)
    tmp = out_p / f".{SCORERS_FIGURE_FILE}.tmp.png"
    measures.figure_scorers(sample_rows, rank_names, tmp)
    os.replace(tmp, out_p / SCORERS_FIGURE_FILE)
    say(f"control-bench: {n_new} start states run in {wall:.1f} s -> {out_p}")
    return payload

