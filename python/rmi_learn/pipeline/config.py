"""Pipeline presets as typed configs: the run grid and the budget options of every stage.

A preset (``rmi_learn/pipeline/presets/<name>.json``, or any JSON file with the same keys)
names the grid and, per stage, the options it sets; an option it does not set keeps the
stage's own default. Option names are those of the ``rmi`` command that runs the stage
(``max_windows`` for ``--max-windows``), and values are checked like the command's
arguments when the preset is read, so a typo fails before any stage runs.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from rmi_learn.data.runs import read_json_source
from rmi_learn.option_types import count, device, real, seed

PRESETS: tuple[str, ...] = ("tiny", "quick", "study", "paper", "control")


def _checked(parse: Callable[[str], Any] | None = None, kind: type | tuple[type, ...] = int) -> Any:
    """A field that a preset may set (``None``: the stage's default); ``parse`` is the
    ``rmi`` command's argument type that checks the value's range."""
    return field(default=None, metadata={"kind": kind, "parse": parse})


def _count(low: int) -> Any:
    return _checked(count(low))


def _seed() -> Any:
    return _checked(seed)


def _device() -> Any:
    return _checked(device, str)


def _real(**limits: Any) -> Any:
    return _checked(real(**limits), (int, float))


def _flag() -> Any:
    return _checked(kind=bool)


def _text() -> Any:
    return _checked(kind=str)


@dataclass(frozen=True)
class StageOptions:
    """Options a preset sets for one stage; ``None`` fields keep the stage's default.
    ``order`` is the order the preset names them in (its command lines keep it)."""

    order: tuple[str, ...] = field(default=(), compare=False, repr=False)

    def __post_init__(self) -> None:
        for f in _options(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            kind, parse = f.metadata["kind"], f.metadata["parse"]
            # bool is an int in Python; a count must not be given as true/false.
            if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
                raise ValueError(f"{f.name} must be of type {_name(kind)}, got {value!r}")
            if parse is not None:
                try:
                    parse(str(value))
                except Exception as exc:  # argparse.ArgumentTypeError
                    raise ValueError(f"{f.name}: {exc}") from None

    @classmethod
    def from_json(cls, options: Mapping[str, Any], where: str) -> Any:
        """The options of ``options`` (a preset's stage object); ``where`` names it in errors."""
        known = [f.name for f in _options(cls)]
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise ValueError(f"{where}: unknown options {unknown} (allowed {known})")
        try:
            return cls(**options, order=tuple(options))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None

    def given(self) -> dict[str, Any]:
        """The options the preset sets (keyword arguments of the stage), in its order."""
        names = [f.name for f in _options(self)]
        names.sort(key=lambda n: self.order.index(n) if n in self.order else len(self.order))
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


def _options(options: Any) -> list[dataclasses.Field[Any]]:
    """The option fields of a :class:`StageOptions` class or instance."""
    return [f for f in dataclasses.fields(options) if "kind" in f.metadata]


def _name(kind: type | tuple[type, ...]) -> str:
    return "number" if isinstance(kind, tuple) else kind.__name__


@dataclass(frozen=True)
class SweepOptions(StageOptions):
    """``rmi sweep`` (:func:`rmi_learn.data.sweep.sweep`)."""

    workers: int | None = _count(0)
    threads_per_run: int | None = _count(1)
    backend: str | None = _text()
    retry_failed: bool | None = _flag()
    limit: int | None = _count(0)


@dataclass(frozen=True)
class WorldModelOptions(StageOptions):
    """``rmi train-wm`` (:func:`rmi_learn.world_models.training.train`), for every model."""

    epochs: int | None = _count(1)
    patience: int | None = _count(1)
    tf_epochs: int | None = _count(0)
    water_weight: float | None = _real(low=0.0, low_open=True)
    huber_delta: float | None = _real(low=0.0, low_open=True)
    loss_scale: str | None = _text()
    batch_size: int | None = _count(1)
    steps_per_epoch: int | None = _count(1)
    lr: float | None = _real(low=0.0, low_open=True)
    val_windows: int | None = _count(1)
    seed: int | None = _seed()
    deterministic: bool | None = _flag()
    device: str | None = _device()
    debug: bool | None = _flag()


@dataclass(frozen=True)
class EvalOptions(StageOptions):
    """``rmi eval-wm`` (:func:`rmi_learn.world_models.evaluation.eval_wm`)."""

    split: str | None = _text()
    batch_size: int | None = _count(1)
    max_windows: int | None = _count(1)
    device: str | None = _device()
    latency: bool | None = _flag()


@dataclass(frozen=True)
class PolicyOptions(StageOptions):
    """``rmi train-policy`` (:func:`rmi_learn.policies.training.train_policy`), for both
    objectives."""

    size_cm: int | None = _checked()
    epochs: int | None = _count(1)
    batch_size: int | None = _count(1)
    lr: float | None = _real(low=0.0, low_open=True)
    weight_decay: float | None = _real(low=0.0)
    patience: int | None = _count(1)
    seed: int | None = _seed()
    history: int | None = _count(1)
    horizon: int | None = _count(4)
    ema_decay: float | None = _real(low=0.0, high=1.0, high_open=True)
    snr_floor: float | None = _real(low=0.0)
    val_windows: int | None = _count(1)
    device: str | None = _device()
    max_steps_per_epoch: int | None = _count(1)
    debug: bool | None = _flag()
    deterministic: bool | None = _flag()


@dataclass(frozen=True)
class RankOptions(StageOptions):
    """``rmi rank`` (:func:`rmi_learn.planning.ranking.rank`)."""

    split: str | None = _text()
    k: int | None = _count(1)
    max_windows: int | None = _count(0)
    batch_size: int | None = _count(1)
    seed: int | None = _seed()
    force_limit: float | None = _real(low=0.0, low_open=True)
    weights: str | None = _text()
    device: str | None = _device()


@dataclass(frozen=True)
class ClosedLoopOptions(StageOptions):
    """``rmi closed-loop`` (:func:`rmi_learn.closed_loop.run_closed_loop`)."""

    max_windows: int | None = _count(0)
    command: str | None = _text()


@dataclass(frozen=True)
class ControlOptions(StageOptions):
    """``rmi control-bench`` (:func:`rmi_learn.control_bench.run_control_bench`); the stage runs
    only when a preset has a ``control`` key."""

    states_per_size: int | None = _count(1)
    goals_per_state: int | None = _count(0)
    setpoints: int | None = _count(2)
    k: int | None = _count(1)
    receding: int | None = _count(0)
    scorers: str | None = _text()
    receding_scorers: str | None = _text()
    refine_scorers: str | None = _text()
    refine_metrics: str | None = _text()
    controllers: str | None = _text()
    split: str | None = _text()
    seed: int | None = _seed()


@dataclass(frozen=True)
class PipelineConfig:
    """A pipeline preset: the run grid (a grid preset name or a grid file) and the options of
    every stage. ``raw`` is the JSON it was read from; an output directory is tied to it."""

    grid: str
    name: str | None = None
    description: str | None = None
    sweep: SweepOptions = field(default_factory=SweepOptions)
    world_models: WorldModelOptions = field(default_factory=WorldModelOptions)
    ablations: bool = True
    #: Training runs of each learned Table II model (AC-GRU-WM, its shuffled-command
    #: ablation, State-GRU-WM) that differ only in the seed; the tables give their mean and
    #: each run's water error.
    seeds: int = 1
    eval: EvalOptions = field(default_factory=EvalOptions)
    policies: PolicyOptions = field(default_factory=PolicyOptions)
    rank: RankOptions = field(default_factory=RankOptions)
    closed_loop: ClosedLoopOptions = field(default_factory=ClosedLoopOptions)
    #: The goal-reaching benchmark's options; None: the preset does not run it.
    control: ControlOptions | None = None
    #: The protocol (a shipped name or a file) of the benchmark with the feedback baselines
    #: and the sensor mode (``rmi control-bench --protocol``); None: not run.
    control_protocol: str | None = None
    raw: dict[str, Any] = field(default_factory=dict, compare=False)


#: Preset keys holding one stage's options, and their types.
_STAGE_KEYS: dict[str, type[StageOptions]] = {
    "sweep": SweepOptions,
    "world_models": WorldModelOptions,
    "eval": EvalOptions,
    "policies": PolicyOptions,
    "rank": RankOptions,
    "closed_loop": ClosedLoopOptions,
}
_KEYS = {
    "name",
    "description",
    "grid",
    "ablations",
    "seeds",
    "control",
    "control_protocol",
    *_STAGE_KEYS,
}


def load_preset(
    preset: str | None = None, path: str | os.PathLike[str] | None = None
) -> PipelineConfig:
    """Read a pipeline preset by name (``tiny``, ``quick``, ``study``, ``paper``) or from a
    JSON file and check it. Raises ``ValueError`` naming the first problem."""
    cfg, source = read_json_source("rmi_learn.pipeline.presets", PRESETS, preset, path, "pipeline")
    if not isinstance(cfg, dict):
        raise ValueError(f"{source}: expected a JSON object")
    unknown = set(cfg) - _KEYS
    if unknown:
        raise ValueError(f"{source}: unknown keys {sorted(unknown)} (allowed {sorted(_KEYS)})")
    if "grid" not in cfg:
        raise ValueError(f"{source}: missing key 'grid' (a grid preset name or a grid file)")
    stages: dict[str, Any] = {}
    for key, kind in _STAGE_KEYS.items():
        options = cfg.get(key, {})
        if not isinstance(options, dict):
            raise ValueError(f"{source}: {key} must be an object of command options")
        stages[key] = kind.from_json(options, f"{source}: {key}")
    if "control" in cfg:
        if not isinstance(cfg["control"], dict):
            raise ValueError(f"{source}: control must be an object of command options")
        stages["control"] = ControlOptions.from_json(cfg["control"], f"{source}: control")
    if "control_protocol" in cfg:
        if not isinstance(cfg["control_protocol"], str) or not cfg["control_protocol"]:
            raise ValueError(f"{source}: control_protocol must be a protocol name or file")
        stages["control_protocol"] = cfg["control_protocol"]
    seeds = cfg.get("seeds", 1)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= 10:
        raise ValueError(f"{source}: seeds must be a whole number from 1 to 10, got {seeds!r}")
    return PipelineConfig(
        grid=str(cfg["grid"]),
        seeds=seeds,
        name=cfg.get("name"),
        description=cfg.get("description"),
        ablations=bool(cfg.get("ablations", True)),
        raw=cfg,
        **stages,
    )
