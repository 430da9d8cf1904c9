"""The stages of the pipeline, in order: a table of :class:`StageSpec` whose call builders
describe each stage's library calls once (:mod:`rmi_learn.pipeline.calls`), so the command
lines a stage records are those of the calls it runs.

The stages after the sweep import their modules when their calls are built: those modules
import torch when it is installed (matplotlib, for the analysis), which ``rmi --help`` and a
pipeline that only sweeps never need.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from rmi_learn.analysis import report as reporting
from rmi_learn.data import sweep
from rmi_learn.pipeline.calls import (
    Arg,
    Call,
    call,
    call_only,
    command_line,
    keyword,
    options,
    positional,
)
from rmi_learn.pipeline.config import PipelineConfig
from rmi_learn.pipeline.models import (
    ABLATION_MODELS,
    MAIN_MODELS,
    SCORER_MODELS,
    ModelRun,
    with_replicates,
)

OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")
#: The benchmark's options that name several things, comma-separated in a preset and on the
#: command line, a list in the library call.
_LIST_OPTIONS = ("scorers", "receding_scorers", "refine_scorers", "refine_metrics", "controllers")


@dataclass
class Stage:
    """One pipeline stage: a name, what it does, its calls, and whether they are independent
    trainings (``parallel``) that the pipeline may run side by side, one torch thread each."""

    name: str
    title: str
    calls: Callable[[], list[Call]]
    parallel: bool = False


@dataclass(frozen=True)
class StageContext:
    """What the calls of a preset's stages read and write: the preset, the output directory
    and the threads of every stage after the sweep."""

    cfg: PipelineConfig
    out: Path
    threads: int

    @property
    def sweep_dir(self) -> Path:
        return self.out / "sweep"

    @property
    def data(self) -> Path:
        return self.out / "dataset"

    def replicated(self, models: Mapping[str, ModelRun]) -> dict[str, ModelRun]:
        """``models`` with the preset's seed replicates
        (:func:`rmi_learn.pipeline.models.with_replicates`)."""
        first = self.cfg.world_models.seed or 0
        return with_replicates(models, self.cfg.seeds, first)

    def threads_flag(self) -> Arg:
        """``--threads N`` of a call whose threads the pipeline sets (torch's) or that takes
        the engine's from the command line only."""
        return command_line("--threads", str(self.threads))


def _log(msg: str) -> None:
    print(msg, file=sys.stderr)


def sweep_calls(w: StageContext) -> list[Call]:
    # A grid preset's name (the sweep's presets, e.g. `paper-fine`), else a grid file.
    grid = w.cfg.grid
    source = (
        keyword("preset", grid, ["--preset", grid])
        if grid in sweep.PRESETS
        else keyword("grid_file", grid, ["--grid", grid])
    )
    out = positional("--out", w.sweep_dir)
    return [call("sweep", sweep.sweep, source, out, options(w.cfg.sweep.given()))]


def dataset_calls(w: StageContext) -> list[Call]:
    from rmi_learn.data import dataset

    runs = positional("--runs", w.sweep_dir / "runs")
    return [call(("dataset", "build"), dataset.build, runs, positional("--out", w.data))]


def analysis_calls(w: StageContext) -> list[Call]:
    from rmi_learn.analysis import physical

    out = positional("--out", w.out / "analysis")
    return [call("analyze", physical.analyze, positional("--runs", w.sweep_dir), out)]


#: A training's torch threads. Its weights depend on torch's thread count, so every training
#: runs on one thread: the result is the same for any ``--threads``, which sets how many
#: trainings run at a time instead (their stages are ``parallel``).
TRAINING_THREADS = 1


def _training_args(out: Arg, given: Mapping[str, Any]) -> list[Arg]:
    """The arguments a training call into the run directory ``out`` ends with; it resumes
    when that directory has a config (it was interrupted; a finished one returns its summary
    at once)."""
    resume = (Path(out.value) / "config.json").exists()
    return [
        out,
        *options(given),
        command_line("--threads", str(TRAINING_THREADS)),
        keyword("progress", False, ["--no-progress"]),
        keyword("resume", resume),
    ]


def world_model_calls(models: Mapping[str, ModelRun], w: StageContext) -> list[Call]:
    from rmi_learn.world_models import training

    given = w.cfg.world_models.given()
    # A replicate sets its own seed.
    unseeded = {k: v for k, v in given.items() if k != "seed"}
    return [
        call(
            "train-wm",
            training.train,
            run.args(),
            keyword("data", w.data),
            _training_args(
                keyword("out", w.out / "wm" / name), given if run.seed is None else unseeded
            ),
            torch=True,
        )
        # W_T trains several times longer than any other model: first, so that the others
        # share the remaining workers while it runs.
        for name, run in sorted(
            w.replicated(models).items(), key=lambda m: m[1].model != "transformer"
        )
    ]


def eval_calls(w: StageContext) -> list[Call]:
    from rmi_learn.world_models import evaluation

    given = w.cfg.eval.given()
    latency = given.pop("latency", True)
    names = list(w.replicated(MAIN_MODELS))
    names += list(w.replicated(ABLATION_MODELS)) if w.cfg.ablations else []
    runs = [str(w.out / "wm" / n) for n in names]
    args = [
        positional("--runs", runs, ["--runs", *runs]),
        positional("--data", w.data),
        positional("--out", w.out / "tables" / "wm"),
        *options(given),
        w.threads_flag(),
        keyword("latency", latency, [] if latency else ["--no-latency"]),
    ]
    return [call("eval-wm", evaluation.eval_wm, args, torch=True)]


def policy_calls(w: StageContext) -> list[Call]:
    from rmi_learn.policies import training

    given = w.cfg.policies.given()
    return [
        call(
            "train-policy",
            training.train_policy,
            positional("--objective", obj),
            positional("--data", w.data),
            _training_args(positional("--out", w.out / "policy" / obj), given),
            torch=True,
        )
        for obj in OBJECTIVES
    ]


def rank_calls(w: StageContext) -> list[Call]:
    from rmi_learn.planning import ranking

    args = [
        positional("--data", w.data),
        positional("--wm", w.out / "wm" / "transformer"),
        *(keyword(obj, w.out / "policy" / obj) for obj in OBJECTIVES),
        positional("--out", w.out / "tables" / "rank"),
        *options(w.cfg.rank.given()),
        w.threads_flag(),
    ]
    return [call("rank", ranking.rank, args, torch=True)]


def closed_loop_calls(w: StageContext) -> list[Call]:
    from rmi_learn import closed_loop

    args = [
        positional("--runs", w.sweep_dir),
        positional("--chunks", w.out / "tables" / "rank"),
        positional("--out", w.out / "closed_loop"),
        *options(w.cfg.closed_loop.given()),
        keyword("threads", w.threads),
        call_only("log", _log),
    ]
    return [call("closed-loop", closed_loop.run_closed_loop, args)]


def control_calls(w: StageContext) -> list[Call]:
    from rmi_learn.control_bench import run_control_bench

    given = w.cfg.control.given() if w.cfg.control is not None else {}
    dirs = {"runs": w.sweep_dir, "data": w.data, "wm": w.out / "wm", "policy": w.out / "policy"}
    args = [
        *(keyword(name, d) for name, d in dirs.items()),
        keyword("out", w.out / "control"),
        *(_control_option(name, value) for name, value in given.items()),
        keyword("threads", w.threads),
        keyword("progress", False, ["--no-progress"]),
        call_only("log", _log),
    ]
    return [call("control-bench", run_control_bench, args, torch=True)]


def protocol_calls(w: StageContext) -> list[Call]:
    from rmi_learn.control_bench.feedback import run_protocol_bench

    args = [
        keyword("protocol", w.cfg.control_protocol),
        keyword("runs", w.sweep_dir),
        keyword("out", w.out / "control_protocol"),
        keyword("workers", w.cfg.sweep.workers or 1),
        keyword("threads", 1),
        call_only("log", _log),
        # The stage owns its folder: after a protocol's new version (a code update) it starts
        # over and keeps the old output beside it.
        keyword("replace_other", True),
    ]
    return [call("control-bench", run_protocol_bench, args)]


def _control_option(name: str, value: Any) -> Arg:
    """A benchmark option: the preset's text on the command line, a list of names in the
    call for the options of ``_LIST_OPTIONS``."""
    if name not in _LIST_OPTIONS:
        return keyword(name, value)
    names = [n.strip() for n in value.split(",") if n.strip()]
    return keyword(name, names, [f"--{name.replace('_', '-')}", str(value)])


def report_calls(w: StageContext) -> list[Call]:
    return [call("report", reporting.write_report, positional("--out", w.out))]


@dataclass(frozen=True)
class StageSpec:
    """A row of the stage table: the stage's name, what it does, its calls, whether a
    preset runs it, and whether its calls are independent trainings (:class:`Stage`)."""

    name: str
    title: str
    calls: Callable[[StageContext], list[Call]]
    runs: Callable[[PipelineConfig], bool] = lambda cfg: True
    parallel: bool = False


#: Every stage, in pipeline order.
STAGES: tuple[StageSpec, ...] = (
    StageSpec("sweep", "simulate the run grid", sweep_calls),
    StageSpec("dataset", "resample to 20 ms, split, standardise", dataset_calls),
    StageSpec(
        "analysis",
        "physical analysis (water removed per phase, lift success, squeeze association)",
        analysis_calls,
    ),
    StageSpec(
        "world-models",
        "train the world models",
        partial(world_model_calls, {**MAIN_MODELS, **SCORER_MODELS}),
        parallel=True,
    ),
    StageSpec(
        "ablations",
        "train the ablation models",
        partial(world_model_calls, ABLATION_MODELS),
        lambda cfg: cfg.ablations,
        parallel=True,
    ),
    StageSpec("eval-wm", "evaluate the world models (forecast errors)", eval_calls),
    StageSpec(
        "policies", "train the diffusion and flow-matching policies", policy_calls, parallel=True
    ),
    StageSpec("rank", "rank policy samples with W_T", rank_calls),
    StageSpec("closed-loop", "execute ranked chunks in the simulator", closed_loop_calls),
    StageSpec(
        "control",
        "goal-reaching benchmark in the simulator",
        control_calls,
        lambda cfg: cfg.control is not None,
    ),
    StageSpec(
        "control-protocol",
        "goal-reaching benchmark under its protocol: PI baselines, the sensor mode",
        protocol_calls,
        lambda cfg: cfg.control_protocol is not None,
    ),
    StageSpec("report", "write report.md and report.html", report_calls),
)


def build_stages(cfg: PipelineConfig, out: Path, threads: int) -> list[Stage]:
    """The stages of a preset, in order, with their calls (built lazily, because a training
    stage decides on resuming when it starts)."""
    where = StageContext(cfg, out, threads)
    return [
        Stage(s.name, s.title, partial(s.calls, where), s.parallel) for s in STAGES if s.runs(cfg)
    ]
