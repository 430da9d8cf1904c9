"""The end-to-end pipeline: sweep -> dataset -> analysis -> world models -> ablations ->
evaluation -> policies -> ranking -> closed loop -> report, resumable at every stage.

A pipeline preset (``rmi_learn/pipelines/<name>.json``, or any JSON file with the same keys)
names the run grid and the budgets of every stage; the stages themselves are the ``rmi``
subcommands, called in-process with the arguments a user would type, so the pipeline never
does anything a user could not reproduce by hand (``OUT/stages/<stage>.json`` records the
exact command lines).

Resumption works at two levels. A finished stage leaves ``OUT/stages/<stage>.json`` and is
skipped next time. An interrupted stage is simply run again, and each command resumes on its
own: the sweep skips finished runs, training continues from its last checkpoint
(``--resume``), closed-loop execution skips finished windows, and the other stages take
seconds. Output layout under ``OUT``::

    sweep/        run files (hive tree), index.parquet         (rmi sweep)
    dataset/      resampled frames, split, statistics          (rmi dataset build)
    analysis/     Figs. 4-6 and the squeeze association        (rmi analyze)
    wm/<name>/    one directory per trained world model        (rmi train-wm)
    tables/wm/    Tables II, IV and the lookahead diagnostic   (rmi eval-wm)
    policy/<obj>/ diffusion and flow-matching UNets            (rmi train-policy)
    tables/rank/  Tables III, V, S1 and the ranked chunks      (rmi rank)
    closed_loop/  real terminal water error in the simulator   (rmi closed-loop)
    report/       report.md, report.html, figures              (rmi report)
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rmi_learn.runs import atomic_write_json, read_json_source

PRESETS: tuple[str, ...] = ("tiny", "quick", "study", "paper")
STAGES_SUBDIR = "stages"
_KEYS = {
    "name",
    "description",
    "grid",
    "sweep",
    "world_models",
    "ablations",
    "eval",
    "policies",
    "rank",
    "closed_loop",
}

#: The world models of Tables II and the lookahead diagnostic: directory name -> train-wm args.
MAIN_MODELS: dict[str, list[str]] = {
    "state-gru": ["--model", "state-gru"],
    "ac-gru": ["--model", "ac-gru"],
    "arx": ["--model", "arx"],
    "ac-mlp": ["--model", "ac-mlp"],
    "transformer": ["--model", "transformer"],
}
#: Ablations: shuffled action chunks (Table II last row, diagnostic) and state groups (Table IV).
ABLATION_MODELS: dict[str, list[str]] = {
    "ac-gru-shuffled": ["--model", "ac-gru", "--shuffle-actions"],
    "arx-shuffled": ["--model", "arx", "--shuffle-actions"],
    "ac-mlp-shuffled": ["--model", "ac-mlp", "--shuffle-actions"],
    "ac-gru-LS": ["--model", "ac-gru", "--state-groups", "LS"],
    "ac-gru-LS+G": ["--model", "ac-gru", "--state-groups", "LS+G"],
    "ac-gru-LS+G+C": ["--model", "ac-gru", "--state-groups", "LS+G+C"],
}
OBJECTIVES: tuple[str, ...] = ("diffusion", "flow")


class PipelineError(RuntimeError):
    """A stage failed; the message names the stage and the command that failed."""


def load_preset(
    preset: str | None = None, path: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """Read a pipeline preset by name (``tiny``, ``quick``, ``paper``) or from a JSON file and
    check its keys. Stage budgets are passed through to the commands, so unknown budget keys
    surface as the command's own argument error."""
    cfg, source = read_json_source("rmi_learn.pipelines", PRESETS, preset, path, "pipeline")
    if not isinstance(cfg, dict):
        raise ValueError(f"{source}: expected a JSON object")
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ValueError(f"{source}: unknown keys {sorted(unknown)} (allowed {sorted(_KEYS)})")
    if "grid" not in cfg:
        raise ValueError(f"{source}: missing key 'grid' (a grid preset name or a grid file)")
    for key in ("sweep", "world_models", "eval", "policies", "rank", "closed_loop"):
        if not isinstance(cfg.get(key, {}), dict):
            raise ValueError(f"{source}: {key} must be an object of command options")
    return cfg


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
        else:
            out += [flag, str(value)]
    return out


@dataclass
class Stage:
    """One pipeline stage: a name, what it does, and the command lines it runs."""

    name: str
    title: str
    commands: Callable[[], list[list[str]]]


def _resume_flag(run_dir: Path) -> list[str]:
    # A training directory with a config but no summary was interrupted: continue it.
    return ["--resume"] if (run_dir / "config.json").exists() else []


def build_stages(cfg: Mapping[str, Any], out: Path, threads: int) -> list[Stage]:
    """The stages of a preset, in order, with their command lines (built lazily, because a
    training stage decides on ``--resume`` when it starts)."""
    grid = str(cfg["grid"])
    grid_args = ["--preset", grid] if grid in PRESETS else ["--grid", grid]
    sweep, data = out / "sweep", out / "dataset"
    wm_opts = dict(cfg.get("world_models", {}))
    pol_opts = dict(cfg.get("policies", {}))
    eval_opts = dict(cfg.get("eval", {}))
    latency = eval_opts.pop("latency", True)
    t = ["--threads", str(threads)]

    def train_wm(models: Mapping[str, list[str]]) -> Callable[[], list[list[str]]]:
        def cmds() -> list[list[str]]:
            return [
                ["train-wm", *margs, "--data", str(data), "--out", str(out / "wm" / name)]
                + _flags(wm_opts)
                + t
                + ["--no-progress"]
                + _resume_flag(out / "wm" / name)
                for name, margs in models.items()
            ]

        return cmds

    def wm_runs() -> list[str]:
        names = list(MAIN_MODELS) + (list(ABLATION_MODELS) if cfg.get("ablations", True) else [])
        return [str(out / "wm" / n) for n in names]

    def policies() -> list[list[str]]:
        return [
            ["train-policy", "--objective", obj, "--data", str(data)]
            + ["--out", str(out / "policy" / obj)]
            + _flags(pol_opts)
            + t
            + ["--no-progress"]
            + _resume_flag(out / "policy" / obj)
            for obj in OBJECTIVES
        ]

    stages = [
        Stage(
            "sweep",
            "simulate the run grid",
            lambda: [["sweep", *grid_args, "--out", str(sweep)] + _flags(cfg.get("sweep", {}))],
        ),
        Stage(
            "dataset",
            "resample to 20 ms, split, standardise",
            lambda: [["dataset", "build", "--runs", str(sweep / "runs"), "--out", str(data)]],
        ),
        Stage(
            "analysis",
            "physical analysis (Figs. 4-6)",
            lambda: [["analyze", "--runs", str(sweep), "--out", str(out / "analysis")]],
        ),
        Stage("world-models", "train the world models", train_wm(MAIN_MODELS)),
    ]
    if cfg.get("ablations", True):
        stages.append(Stage("ablations", "train the ablation models", train_wm(ABLATION_MODELS)))
    stages += [
        Stage(
            "eval-wm",
            "evaluate the world models (Tables II, IV, diagnostic)",
            lambda: [
                ["eval-wm", "--runs", *wm_runs(), "--data", str(data)]
                + ["--out", str(out / "tables" / "wm")]
                + _flags(eval_opts)
                + t
                + ([] if latency else ["--no-latency"])
            ],
        ),
        Stage("policies", "train the diffusion and flow-matching policies", policies),
        Stage(
            "rank",
            "rank policy samples with W_T (Tables III, V, S1)",
            lambda: [
                ["rank", "--data", str(data), "--wm", str(out / "wm" / "transformer")]
                + ["--diffusion", str(out / "policy" / "diffusion")]
                + ["--flow", str(out / "policy" / "flow")]
                + ["--out", str(out / "tables" / "rank")]
                + _flags(cfg.get("rank", {}))
                + t
            ],
        ),
        Stage(
            "closed-loop",
            "execute ranked chunks in the simulator",
            lambda: [
                ["closed-loop", "--runs", str(sweep), "--chunks", str(out / "tables" / "rank")]
                + ["--out", str(out / "closed_loop")]
                + _flags(cfg.get("closed_loop", {}))
                + t
            ],
        ),
        Stage("report", "write report.md and report.html", lambda: [["report", "--out", str(out)]]),
    ]
    return stages


def run_pipeline(
    cfg: Mapping[str, Any],
    out_dir: str | os.PathLike[str],
    *,
    threads: int = 2,
    only: list[str] | None = None,
    redo: list[str] | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run every stage of ``cfg`` into ``out_dir`` that has not finished yet.

    ``only`` restricts to the named stages (in pipeline order); ``redo`` forgets the markers
    of the named stages first (their commands still resume rather than start over). Returns
    ``{stage: marker}``; raises :class:`PipelineError` on the first failing command (the
    stages before it keep their markers, so the next call continues there).
    """
    from rmi_learn import cli

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
        if old != dict(cfg):
            raise ValueError(
                f"{out} was started with another pipeline preset ({old.get('name')!r}); "
                "use a fresh --out directory"
            )
    else:
        atomic_write_json(preset_file, dict(cfg))
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
        argvs = stage.commands()
        for argv in argvs:
            say("  $ rmi " + " ".join(argv))
            try:
                rc = cli.main(argv)
            except SystemExit as exc:  # argparse rejects a preset option
                rc = exc.code if isinstance(exc.code, int) else 2
            if rc != 0:
                raise PipelineError(
                    f"stage {stage.name} failed (exit {rc}) running: rmi {' '.join(argv)}"
                )
        wall = time.perf_counter() - t0
        markers[stage.name] = {
            "stage": stage.name,
            "wall_s": wall,
            "commands": ["rmi " + " ".join(a) for a in argvs],
            "finished_unix": time.time(),
        }
        atomic_write_json(marker, markers[stage.name])
        say(f"{head} ... done in {wall:.1f} s")
    say(f"pipeline finished in {time.perf_counter() - t_all:.1f} s -> {out}")
    return markers
