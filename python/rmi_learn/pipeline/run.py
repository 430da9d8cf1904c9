"""Running a preset's stages into one output directory (:func:`run_pipeline`): each stage
that has no marker ``OUT/stages/<stage>.json`` yet runs its calls, and a finished stage
leaves its marker (its wall time and the ``rmi`` command lines of its calls). The calls of a
``parallel`` stage (independent trainings, one torch thread each) run ``threads`` at a time in
processes of their own."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rmi_learn import errors
from rmi_learn.data.runs import atomic_write_json
from rmi_learn.pipeline.calls import Call
from rmi_learn.pipeline.config import PipelineConfig
from rmi_learn.pipeline.stages import TRAINING_THREADS, Stage, build_stages
from rmi_learn.process_pool import ordered_map

STAGES_SUBDIR = "stages"


class PipelineError(RuntimeError):
    """A stage failed; the message names the stage and the command that failed."""


def execute_call(call: Call, threads: int) -> int:
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


def _execute_training(call: Call) -> int:
    return execute_call(call, TRAINING_THREADS)


def parallel_map(fn: Callable[[Call], int], calls: Sequence[Call], workers: int) -> list[int]:
    """``fn`` of each call in a pool of ``workers`` spawned processes; the statuses in the
    calls' order. A bug in one call raises here once the calls already running have ended."""
    return list(ordered_map(fn, calls, workers))


def _run_calls(stage: Stage, calls: list[Call], threads: int, say: Callable[[str], None]) -> None:
    """Run ``calls`` of ``stage``: one after another, or ``threads`` at a time for a parallel
    stage. Raises :class:`PipelineError` naming the first call (in the stage's order) that
    failed."""
    lines = ["rmi " + " ".join(c.argv) for c in calls]
    workers = min(threads, len(calls)) if stage.parallel else 1
    if workers > 1:
        say(f"  ({workers} at a time, {TRAINING_THREADS} thread each)")
        for line in lines:
            say("  $ " + line)
        statuses = parallel_map(_execute_training, calls, workers)
    else:
        statuses = []
        for c, line in zip(calls, lines, strict=True):
            say("  $ " + line)
            statuses.append(execute_call(c, TRAINING_THREADS if stage.parallel else threads))
            if statuses[-1] != 0:
                break
    for rc, line in zip(statuses, lines, strict=False):
        if rc != 0:
            raise PipelineError(f"stage {stage.name} failed (exit {rc}) running: {line}")


def _check_names(stages: list[Stage], only: list[str] | None, redo: list[str] | None) -> None:
    names = [s.name for s in stages]
    for name in (only or []) + (redo or []):
        if name not in names:
            raise ValueError(f"unknown stage {name!r}; stages are {names}")


def _tie_to_preset(out: Path, cfg: PipelineConfig) -> None:
    """Store the preset as ``OUT/pipeline.json`` on the first run into ``out``; refuse
    another preset on a later one."""
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


def _run_stage(stage: Stage, marker: Path, threads: int, say: Callable[[str], None]) -> Any:
    """Run every call of ``stage`` and write its marker; returns the marker's content.
    Raises :class:`PipelineError` on the first call that fails."""
    t0 = time.perf_counter()
    calls = stage.calls()
    _run_calls(stage, calls, threads, say)
    done = {
        "stage": stage.name,
        "wall_s": time.perf_counter() - t0,
        "commands": ["rmi " + " ".join(c.argv) for c in calls],
        "finished_unix": time.time(),
    }
    atomic_write_json(marker, done)
    return done


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
    of the named stages first (their calls still resume rather than start over); a name
    that is not a stage of ``cfg`` is a ``ValueError`` before ``out_dir`` is created. Returns
    ``{stage: marker}``; raises :class:`PipelineError` on the first failing call (the
    stages before it keep their markers, so the next call continues there).
    """
    say = log or (lambda s: print(s, flush=True))
    out = Path(out_dir)
    # Stage names are checked before anything is made, so a misspelt one leaves no directory.
    stages = build_stages(cfg, out, threads)
    _check_names(stages, only, redo)
    out.mkdir(parents=True, exist_ok=True)
    _tie_to_preset(out, cfg)
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
        markers[stage.name] = _run_stage(stage, marker, threads, say)
        say(f"{head} ... done in {markers[stage.name]['wall_s']:.1f} s")
    say(f"pipeline finished in {time.perf_counter() - t_all:.1f} s -> {out}")
    return markers
