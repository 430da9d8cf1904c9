"""The benchmark's inputs: the trained policies and the world models that score, the
candidate start states of a held-out split and their runs, and the goals."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

import rmi_sph
from rmi_learn import world_models as models
from rmi_learn.data.runs import read_run
from rmi_learn.errors import InputError
from rmi_learn.planning.scorers import can_score
from rmi_learn.planning.standardiser import stats_close
from rmi_learn.policies.checkpoint import load_policy
from rmi_learn.sim.replay import RunTrack, control_substeps

#: Phases in which the robot acts on the water (anchors are drawn there).
ACTING_PHASES: tuple[str, ...] = ("hold", "lift", "waiting", "squeeze")
#: World-model directory names that score chunks under another name in the tables.
SCORER_NAMES = {"transformer": "wt"}
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")


class ControlBenchError(InputError, ValueError):
    """Inputs the benchmark cannot use (missing or mismatched directories, bad goals or
    options); ``rmi control-bench`` reports it with exit status 2."""


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


def load_scorers(
    wm_dir: Path, ds: Any, horizon: int, wanted: Sequence[str] | None
) -> tuple[dict[str, ScorerInput], dict[str, str]]:
    """World models under ``wm_dir`` that can rank chunks (action-conditioned, horizon fits),
    by table name (``wt`` for ``transformer``); ``wanted`` restricts them (by table or
    directory name; a wanted model that cannot score is an error). Returns the scorers and
    the models left out with the reason."""
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
        why = can_score(model, horizon)
        if why is not None:
            if wanted:
                raise ControlBenchError(f"--scorers {name}: {path} cannot rank chunks: {why}")
            skipped[name] = why
            continue
        stats = (cfg.get("extra") or {}).get("stats")
        if stats is not None and not stats_close(ds.stats, stats):
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


def check_candidates(
    ds: Any,
    cands: Mapping[int, Sequence[Candidate]],
    tracks: Mapping[str, RunTrack],
    h: int,
    runs_p: Path,
) -> None:
    """Refuse candidates that are not the learning rows of the replayed runs (a dataset
    built from another sweep) or whose chunk crosses a gap of those rows."""
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


def total_water(
    pool_runs: Sequence[str], tracks: Mapping[str, RunTrack], index: Mapping[str, Path]
) -> dict[str, float]:
    """The water present in each run (kg): the run file's outcome, else the most the run
    retained."""
    out = {rid: float(tracks[rid].water.max()) for rid in pool_runs}
    try:
        for rid in pool_runs:
            tw = read_run(index[rid])[1].get("outcome", {}).get("total_water")
            if tw is not None:
                out[rid] = float(tw)
    except (OSError, ValueError) as exc:
        raise ControlBenchError(f"cannot read a run file of --runs: {exc}") from exc
    return out


def validated_configs(
    pool_runs: Sequence[str], tracks: Mapping[str, RunTrack]
) -> dict[str, dict[str, Any]]:
    """Each run's stored config as this engine validates it (its engine step a whole
    fraction of the control step)."""
    configs = {}
    for rid in pool_runs:
        try:
            configs[rid] = rmi_sph.validate_config(tracks[rid].config)
        except rmi_sph.ConfigError as exc:
            raise ControlBenchError(f"the stored config of run {rid} is refused: {exc}") from exc
        control_substeps(float(configs[rid]["dt"]))
    return configs


__all__ = [
    "ACTING_PHASES",
    "OBJECTIVES",
    "SCORER_NAMES",
    "Candidate",
    "ControlBenchError",
    "PolicyInput",
    "ScorerInput",
    "candidates",
    "check_candidates",
    "check_goals",
    "draw_order",
    "load_policies",
    "load_scorers",
    "total_water",
    "validated_configs",
]


@dataclass
class Setup:
    """The loaded inputs: dataset, the sweep's run files, policies (with their history and
    chunk length) and scorers (and the world models left out, with the reason)."""

    ds: Any
    index: dict[str, Path]
    policies: dict[str, PolicyInput]
    hist_len: int
    h: int
    scorers: dict[str, ScorerInput]
    skipped: dict[str, str]
