"""The end-to-end pipeline (``rmi pipeline``): typed presets (:mod:`.config`, the JSON files
in ``presets/``) and the stages that call the library function of each ``rmi`` command
(:mod:`.stages`)."""

from __future__ import annotations

from rmi_learn.pipeline.config import PRESETS, PipelineConfig, load_preset
from rmi_learn.pipeline.stages import (
    ABLATION_MODELS,
    MAIN_MODELS,
    OBJECTIVES,
    SCORER_MODELS,
    STAGES_SUBDIR,
    Call,
    ModelRun,
    PipelineError,
    Stage,
    build_stages,
    run_pipeline,
)

__all__ = [
    "ABLATION_MODELS",
    "MAIN_MODELS",
    "OBJECTIVES",
    "PRESETS",
    "SCORER_MODELS",
    "STAGES_SUBDIR",
    "Call",
    "ModelRun",
    "PipelineConfig",
    "PipelineError",
    "Stage",
    "build_stages",
    "load_preset",
    "run_pipeline",
]
