"""Running a preset's stages into one output directory (:func:`run_pipeline`): each stage
that has no marker ``OUT/stages/<stage>.json`` yet runs its calls, and a finished stage
leaves its marker (its wall time and the ``rmi`` command lines of its calls)."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rmi_learn import errors
from rmi_learn.data.runs import atomic_write_json
from rmi_learn.pipeline.calls import Call
from rmi_learn.pipeline.config import PipelineConfig
from rmi_learn.pipeline.stages import Stage, build_stages

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
    for c in calls:
        line = "rmi " + " ".join(c.argv)
        say("  $ " + line)
        rc = execute_call(c, threads)
        if rc != 0:
            raise PipelineError(f"stage {stage.name} failed (exit {rc}) running: {line}")
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
