"""The settings of a training run (:class:`TrainConfig`, stored in ``config.json``) and its
progress counters (:class:`TrainState`, saved in every checkpoint)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any


@dataclass
class TrainConfig:
    """Optimisation settings. Every field is JSON-serialisable and stored in config.json."""

    epochs: int = 40
    batch_size: int = 128
    lr: float = 1e-3
    weight_decay: float = 0.0
    optimizer: str = "adam"  #: "adam" | "adamw"
    betas: tuple[float, float] = (0.9, 0.999)
    scheduler: str = "none"  #: "none" | "cosine" (per step, after linear warm-up)
    warmup_steps: int = 0
    grad_clip: float | None = 1.0  #: max global gradient norm; None disables
    patience: int | None = 8  #: epochs without improvement before stopping; None: never
    #: patience counts only epochs after this many (e.g. the teacher-forcing decay), so the
    #: earliest early stop is at epoch min_epochs + patience; selection still sees every epoch
    min_epochs: int = 0
    #: epochs up to this one are neither selected nor counted by patience. Recurrent world
    #: models set it to the teacher-forcing decay: while teacher forcing is on, the free-rollout
    #: validation metric is erratic (18-140 g from one epoch to the next on the study preset)
    #: and a lucky early epoch was selected whose force forecast was worse than the Baseline's.
    #: If the run ends before any eligible epoch, its last epoch is selected.
    select_after: int = 0
    select_metric: str = "train_loss"
    select_mode: str = "min"  #: "min" | "max"
    seed: int = 0
    deterministic: bool = False  #: torch.use_deterministic_algorithms(True)
    device: str = "cpu"
    debug: bool = False  #: shrink the run to seconds (see :meth:`effective`)
    max_steps_per_epoch: int | None = None
    checkpoint_every: int = 0  #: also checkpoint every N steps inside an epoch (0: off)
    log_every: int = 50  #: write a "step" metrics line every N steps
    progress: bool = True  #: tqdm progress bars
    drop_last: bool = False

    def effective(self) -> TrainConfig:
        """The configuration actually used: debug mode caps epochs at 2 and epochs at 3 steps."""
        if not self.debug:
            return self
        steps = 3 if self.max_steps_per_epoch is None else min(3, self.max_steps_per_epoch)
        return dataclasses.replace(
            self, epochs=min(self.epochs, 2), max_steps_per_epoch=steps, log_every=1
        )

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["betas"] = list(self.betas)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TrainConfig:
        d = dict(d)
        if "betas" in d:
            d["betas"] = tuple(d["betas"])
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass
class TrainState:
    """Progress counters; saved in every checkpoint."""

    epoch: int = 0  #: index of the epoch in progress (0-based) = completed epochs
    step: int = 0  #: optimiser steps taken
    batch_in_epoch: int = 0  #: batches of ``epoch`` already consumed
    epochs_total: int = 0  #: configured number of epochs (for schedules)
    best_metric: float | None = None
    best_epoch: int | None = None  #: 1-based epoch whose weights are in model.safetensors
    bad_epochs: int = 0  #: epochs since the last improvement
    finished: bool = False
    stopped_early: bool = False
    train_loss_sum: float = 0.0  #: running sums of the epoch in progress
    train_batches: int = 0
    extra_sums: dict[str, float] = field(default_factory=dict)
