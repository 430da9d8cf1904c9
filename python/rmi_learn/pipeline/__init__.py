"""The end-to-end pipeline (``rmi pipeline``): typed presets (:mod:`.config`, the JSON files
in ``presets/``), the calls of a stage described once (:mod:`.calls`), the world models it
trains (:mod:`.models`), the table of stages (:mod:`.stages`) and the driver that runs them,
resumable (:mod:`.run`).

Sweep -> dataset -> analysis -> world models -> ablations -> evaluation -> policies ->
ranking -> closed loop -> report, resumable at every stage. A pipeline preset names the run
grid and the budgets of every stage. Each stage calls the library function behind an
``rmi`` command with the preset's options, and ``OUT/stages/<stage>.json`` records the
``rmi`` command lines that do the same, so the pipeline never does anything a user could
not reproduce by hand.

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

from rmi_learn.pipeline.calls import Arg, Call
from rmi_learn.pipeline.config import PRESETS, PipelineConfig, load_preset
from rmi_learn.pipeline.models import ABLATION_MODELS, MAIN_MODELS, SCORER_MODELS, ModelRun
from rmi_learn.pipeline.run import STAGES_SUBDIR, PipelineError, execute_call, run_pipeline
from rmi_learn.pipeline.stages import OBJECTIVES, STAGES, Stage, StageSpec, build_stages

__all__ = [
    "ABLATION_MODELS",
    "MAIN_MODELS",
    "OBJECTIVES",
    "PRESETS",
    "SCORER_MODELS",
    "STAGES",
    "STAGES_SUBDIR",
    "Arg",
    "Call",
    "ModelRun",
    "PipelineConfig",
    "PipelineError",
    "Stage",
    "StageSpec",
    "build_stages",
    "execute_call",
    "load_preset",
    "run_pipeline",
]
