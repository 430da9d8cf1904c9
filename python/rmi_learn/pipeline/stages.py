"""The end-to-end pipeline: sweep -> dataset -> analysis -> world models -> ablations ->
evaluation -> policies -> ranking -> closed loop -> report, resumable at every stage.

A pipeline preset (:mod:`rmi_learn.pipeline.config`) names the run grid and the budgets of
every stage. Each stage calls the library function behind an ``rmi`` command with the
preset's options, and ``OUT/stages/<stage>.json`` records the ``rmi`` command lines that do
the same, so the pipeline never does anything a user could not reproduce by hand.

Resumption works at two levels. A finished stage leaves ``OUT/stages/<stage>.json`` and is
skipped next time. An interrupted stage is simply run again, and each call resumes on its
own: the sweep skips finished runs, training continues from its last checkpoint
(``--resume``), closed-loop execution skips finished windows, and the other stages take
seconds. Output layout under ``OUT``::

    sweep/        run files (hive tree), index.parquet         (rmi sweep)
    dataset/      resampled frames, split, statistics          (rmi dataset build)
    analysis/     water removed, lift success, squeeze association (rmi analyze)
    wm/<name>/    one directory per trained world model        (rmi train-wm)
    tables/wm/    forecast errors, state groups, lookahead     (rmi eval-wm)
    policy/<obj>/ diffusion and flow-matching UNets            (rmi train-policy)
    tables/rank/  ranking tables and the ranked chunks         (rmi rank)
    closed_loop/  real terminal water error in the simulator   (rmi closed-loop)
    control/      goal-reaching benchmark, when the preset has "control" (rmi control-bench)
    report/       report.md, report.html, figures              (rmi report)
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rmi_learn import errors
from rmi_learn.data.runs import atomic_write_json
from rmi_learn.pipeline.config import PipelineConfig

STAGES_SUBDIR = "stages"


@dataclass(frozen=True)
class ModelRun:
    """One world model a stage trains: the model, the ablation settings of its run, the
    fixed horizon of a lookahead model trained on windows of that length (None: its
    default), and for Linear-ARX whether each step is fitted on the setpoints up to it only
    (``causal``)."""

    model: str
    shuffle_actions: bool = False
    state_groups: str = "ALL"
    horizon: int | None = None
    causal: bool = False

    def flags(self) -> list[str]:
        """The ``rmi train-wm`` options of this run."""
        out = ["--model", self.model]
        out += ["--shuffle-actions"] if self.shuffle_actions else []
        out += ["--state-groups", self.state_groups] if self.state_groups != "ALL" else []
        for key, value in (self.model_args() or {}).items():
            out += ["--model-arg", f"{key}={json.dumps(value)}"]
        return out

    def model_args(self) -> dict[str, Any] | None:
        """Constructor overrides of this run."""
        args: dict[str, Any] = {"horizon": self.horizon} if self.horizon is not None else {}
        args.update({"causal": True} if self.causal else {})
        return args or None


#: The world models of Tables II and the lookahead diagnostic, by run directory name.
MAIN_MODELS: dict[str, ModelRun] = {
    name: ModelRun(name) for name in ("state-gru", "ac-gru", "arx", "ac-mlp", "transformer")
}
#: Scorers of the policies' 32-step chunks for ranking (``rmi control-bench``): Linear-ARX
#: fitted on 32-step windows, whose forecasts order the executed outcomes of policy samples
#: best among the trained models, and its causal fit, whose forecasts inside the chunk do
#: not lean on later setpoints, for re-planning toward a goal time inside the chunk
#: (docs/control.md).
SCORER_MODELS: dict[str, ModelRun] = {
    "arx-32": ModelRun("arx", horizon=32),
    "arx-32c": ModelRun("arx", horizon=32, causal=True),
}
#: Ablations: shuffled action chunks (Table II last row, diagnostic) and state groups (Table IV).
ABLATION_MODELS: dict[str, ModelRun] = {
    "ac-gru-shuffled": ModelRun("ac-gru", shuffle_actions=True),
    "arx-shuffled": ModelRun("arx", shuffle_actions=True),
    "ac-mlp-shuffled": ModelRun("ac-mlp", shuffle_actions=True),
    "ac-gru-LS": ModelRun("ac-gru", state_groups="LS"),
    "ac-gru-LS+G": ModelRun("ac-gru", state_groups="LS+G"),
    "ac-gru-LS+G+C": ModelRun("ac-gru", state_groups="LS+G+C"),
}
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")


class PipelineError(RuntimeError):
    """A stage failed; the message names the stage and the command that failed."""


def _flags(options: Mapping[str, Any], skip: tuple[str, ...] = ()) -> list[str]:
    """``{"max_windows": 4, "debug": True}`` -> ``["--max-windows", "4", "--debug"]``."""
    out: list[str] = []
    for key, value in options.items():
        if key in skip:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            out.append(flag)
        elif value is False or value is None:
            continue
        elif isinstance(value, (tuple, list)):
            out += [flag, ",".join(str(v) for v in value)]
        else:
            out += [flag, str(value)]
    return out


@dataclass(frozen=True)
class Call:
    """One library call of a stage: the ``rmi`` command line that does the same (``argv``,
    recorded in the stage's marker) and the call itself."""

    argv: list[str]
    run: Callable[[], object]
    #: Whether the call runs torch (the pipeline's ``threads`` then set its CPU threads).
    torch: bool = False


@dataclass
class Stage:
    """One pipeline stage: a name, what it does, and its calls."""

    name: str
    title: str
    calls: Callable[[], list[Call]]


def _training_argv(
    head: list[str], dest: Path, options: Mapping[str, Any], threads: int
) -> tuple[list[str], bool]:
    """The command line of a training call into ``dest`` (``head`` names the command and its
    inputs) and whether it resumes: a run directory with a config was interrupted (a
    finished one returns its summary at once)."""
    resume = (dest / "config.json").exists()
    argv = head + ["--out", str(dest)] + _flags(options) + ["--threads", str(threads)]
    return argv + ["--no-progress"] + (["--resume"] if resume else []), resume


def build_stages(cfg: PipelineConfig, out: Path, threads: int) -> list[Stage]:
    """The stages of a preset, in order, with their calls (built lazily, because a training
    stage decides on resuming when it starts)."""
    from rmi_learn import closed_loop
    from rmi_learn.analysis import physical
    from rmi_learn.analysis import report as reporting
    from rmi_learn.data import dataset, sweep

    # A grid preset's name (the sweep's presets, e.g. `paper-fine`), else a grid file.
    grid = cfg.grid
    named = grid in sweep.PRESETS
    grid_args = ["--preset", grid] if named else ["--grid", grid]
    grid_kw: dict[str, Any] = {"preset": grid} if named else {"grid_file": grid}
    sweep_dir, data = out / "sweep", out / "dataset"
    wm_opts = cfg.world_models.given()
    pol_opts = cfg.policies.given()
    eval_opts = cfg.eval.given()
    latency = eval_opts.pop("latency", True)
    t = ["--threads", str(threads)]

    def train_wm_call(name: str, run: ModelRun) -> Call:
        from rmi_learn.world_models import training

        dest = out / "wm" / name
        head = ["train-wm", *run.flags(), "--data", str(data)]
        argv, resume = _training_argv(head, dest, wm_opts, threads)

        def call() -> object:
            return training.train(
                model=run.model,
                data=data,
                out=dest,
                state_groups=run.state_groups,
                shuffle_actions=run.shuffle_actions,
                model_args=run.model_args(),
                resume=resume,
                progress=False,
                **wm_opts,
            )

        return Call(argv, call, torch=True)

    def train_wm(models: Mapping[str, ModelRun]) -> Callable[[], list[Call]]:
        return lambda: [train_wm_call(name, run) for name, run in models.items()]

    def eval_wm() -> list[Call]:
        from rmi_learn.world_models import evaluation

        names = list(MAIN_MODELS) + (list(ABLATION_MODELS) if cfg.ablations else [])
        runs = [str(out / "wm" / n) for n in names]
        argv = (
            ["eval-wm", "--runs", *runs, "--data", str(data), "--out", str(out / "tables" / "wm")]
            + _flags(eval_opts)
            + t
            + ([] if latency else ["--no-latency"])
        )

        def run() -> object:
            return evaluation.eval_wm(
                runs, data, out / "tables" / "wm", latency=latency, **eval_opts
            )

        return [Call(argv, run, torch=True)]

    def policy_call(obj: str) -> Call:
        from rmi_learn.policies import training

        dest = out / "policy" / obj
        head = ["train-policy", "--objective", obj, "--data", str(data)]
        argv, resume = _training_argv(head, dest, pol_opts, threads)

        def call() -> object:
            return training.train_policy(obj, data, dest, resume=resume, progress=False, **pol_opts)

        return Call(argv, call, torch=True)

    def policies() -> list[Call]:
        return [policy_call(obj) for obj in OBJECTIVES]

    def rank() -> list[Call]:
        from rmi_learn.planning import ranking

        opts = cfg.rank.given()
        wm, tables = out / "wm" / "transformer", out / "tables" / "rank"
        pol = {obj: out / "policy" / obj for obj in OBJECTIVES}
        argv = (
            ["rank", "--data", str(data), "--wm", str(wm)]
            + [a for obj in OBJECTIVES for a in (f"--{obj}", str(pol[obj]))]
            + ["--out", str(tables)]
            + _flags(opts)
            + t
        )

        def run() -> object:
            return ranking.rank(
                data, wm, tables, diffusion=pol["diffusion"], flow=pol["flow"], **opts
            )

        return [Call(argv, run, torch=True)]

    def closed() -> list[Call]:
        opts = cfg.closed_loop.given()
        chunks, dest = out / "tables" / "rank", out / "closed_loop"
        argv = (
            ["closed-loop", "--runs", str(sweep_dir), "--chunks", str(chunks)]
            + ["--out", str(dest)]
            + _flags(opts)
            + t
        )

        def run() -> object:
            return closed_loop.run_closed_loop(
                sweep_dir,
                chunks,
                dest,
                threads=threads,
                log=lambda msg: print(msg, file=sys.stderr),
                **opts,
            )

        return [Call(argv, run)]

    def control() -> list[Call]:
        from rmi_learn.control_bench import run_control_bench

        opts = cfg.control.given() if cfg.control is not None else {}
        dirs = {"runs": sweep_dir, "data": data, "wm": out / "wm", "policy": out / "policy"}
        argv = (
            ["control-bench", *(a for n, d in dirs.items() for a in (f"--{n}", str(d)))]
            + ["--out", str(out / "control")]
            + _flags(opts)
            + t
            + ["--no-progress"]
        )
        for key in ("scorers", "receding_scorers", "refine_scorers", "refine_metrics",
                    "controllers"):
            if key in opts:
                opts[key] = [n.strip() for n in opts[key].split(",") if n.strip()]

        def run() -> object:
            return run_control_bench(
                **dirs,  # type: ignore[arg-type]
                out=out / "control",
                threads=threads,
                progress=False,
                log=lambda msg: print(msg, file=sys.stderr),
                **opts,
            )

        return [Call(argv, run, torch=True)]

    sweep_opts = cfg.sweep.given()
    stages = [
        Stage(
            "sweep",
            "simulate the run grid",
            lambda: [
                Call(
                    ["sweep", *grid_args, "--out", str(sweep_dir)] + _flags(sweep_opts),
                    lambda: sweep.sweep(sweep_dir, **grid_kw, **sweep_opts),
                )
            ],
        ),
        Stage(
            "dataset",
            "resample to 20 ms, split, standardise",
            lambda: [
                Call(
                    ["dataset", "build", "--runs", str(sweep_dir / "runs"), "--out", str(data)],
                    lambda: dataset.build(sweep_dir / "runs", data),
                )
            ],
        ),
        Stage(
            "analysis",
            "physical analysis (water removed per phase, lift success, squeeze association)",
            lambda: [
                Call(
                    ["analyze", "--runs", str(sweep_dir), "--out", str(out / "analysis")],
                    lambda: physical.analyze(sweep_dir, out / "analysis"),
                )
            ],
        ),
        Stage(
            "world-models",
            "train the world models",
            train_wm({**MAIN_MODELS, **SCORER_MODELS}),
        ),
    ]
    if cfg.ablations:
        stages.append(Stage("ablations", "train the ablation models", train_wm(ABLATION_MODELS)))
    stages += [
        Stage("eval-wm", "evaluate the world models (forecast errors)", eval_wm),
        Stage("policies", "train the diffusion and flow-matching policies", policies),
        Stage("rank", "rank policy samples with W_T", rank),
        Stage("closed-loop", "execute ranked chunks in the simulator", closed),
        Stage(
            "report",
            "write report.md and report.html",
            lambda: [Call(["report", "--out", str(out)], lambda: reporting.write_report(out))],
        ),
    ]
    if cfg.control is not None:
        control_stage = Stage("control", "goal-reaching benchmark in the simulator", control)
        stages.insert(len(stages) - 1, control_stage)  # before the report
    return stages


def _execute(call: Call, threads: int) -> int:
    """Run one call as its command would: 0 when it finished, else the command's exit status
    after its one-line message (see :mod:`rmi_learn.errors`); a bug keeps its traceback."""
    if call.torch:
        import torch

        torch.set_num_threads(threads)
    try:
        call.run()
    except (Exception, KeyboardInterrupt) as exc:
        status = errors.report(call.argv[0], exc)
        if status is None:
            raise
        return status
    return 0


def run_pipeline(
    cfg: PipelineConfig,
    out_dir: str | os.PathLike[str],
    *,
    threads: int = 2,
    only: list[str] | None = None,
    redo: list[str] | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run every stage of ``cfg`` into ``out_dir`` that has not finished yet.

    ``only`` restricts to the named stages (in pipeline order); ``redo`` forgets the markers
    of the named stages first (their calls still resume rather than start over). Returns
    ``{stage: marker}``; raises :class:`PipelineError` on the first failing call (the
    stages before it keep their markers, so the next call continues there).
    """
    say = log or (lambda s: print(s, flush=True))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stages = build_stages(cfg, out, threads)
    names = [s.name for s in stages]
    for name in (only or []) + (redo or []):
        if name not in names:
            raise ValueError(f"unknown stage {name!r}; stages are {names}")
    preset_file = out / "pipeline.json"
    if preset_file.exists():
        old = json.loads(preset_file.read_text(encoding="utf-8"))
        if old != cfg.raw:
            raise ValueError(
                f"{out} was started with another pipeline preset ({old.get('name')!r}); "
                "use a fresh --out directory"
            )
    else:
        atomic_write_json(preset_file, cfg.raw)
    for name in redo or []:
        (out / STAGES_SUBDIR / f"{name}.json").unlink(missing_ok=True)

    markers: dict[str, Any] = {}
    selected = [s for s in stages if not only or s.name in only]
    t_all = time.perf_counter()
    for i, stage in enumerate(selected, 1):
        head = f"[{i}/{len(selected)}] {stage.name}: {stage.title}"
        marker = out / STAGES_SUBDIR / f"{stage.name}.json"
        if marker.exists():
            markers[stage.name] = json.loads(marker.read_text(encoding="utf-8"))
            say(f"{head} ... done earlier ({markers[stage.name]['wall_s']:.1f} s), skipped")
            continue
        say(f"{head} ...")
        t0 = time.perf_counter()
        calls = stage.calls()
        for call in calls:
            line = "rmi " + " ".join(call.argv)
            say("  $ " + line)
            rc = _execute(call, threads)
            if rc != 0:
                raise PipelineError(f"stage {stage.name} failed (exit {rc}) running: {line}")
        wall = time.perf_counter() - t0
        markers[stage.name] = {
            "stage": stage.name,
            "wall_s": wall,
            "commands": ["rmi " + " ".join(c.argv) for c in calls],
            "finished_unix": time.time(),
        }
        atomic_write_json(marker, markers[stage.name])
        say(f"{head} ... done in {wall:.1f} s")
    say(f"pipeline finished in {time.perf_counter() - t_all:.1f} s -> {out}")
    return markers
