"""A small, generic PyTorch training loop shared by the world models and the policies.

Usage::

    cfg = TrainConfig(epochs=40, lr=1e-3, patience=8, select_metric="val_water_mae_g")
    trainer = Trainer(model, loss_fn, train_set, out_dir, cfg,
                      evaluate=eval_fn, model_config={"kind": "ac-gru", ...})
    summary = trainer.fit()

``loss_fn(model, batch, state) -> loss`` or ``(loss, {name: float})``; ``batch`` is the dict
of tensors the data set gives for a list of indices (``data.batch(indices)`` when the data set
has that method, else ``data[i]`` collated), already moved to ``cfg.device``; ``state`` is the
:class:`TrainState` (epoch, global step; use it for schedules such as teacher forcing).
``evaluate(model, state) -> {name: float}`` runs after every epoch; ``cfg.select_metric``
names the entry that selects the checkpoint (``cfg.select_mode`` "min" or "max") and drives
early stopping. Without ``evaluate`` the mean training loss ("train_loss") is used.

Files in ``out_dir``:

- ``config.json``: ``{"model": model_config, "train": TrainConfig, "extra": ..., "params": n}``
- ``model.safetensors``: the selected (best) weights; hooks may add ``model.<name>.safetensors``
  (e.g. EMA weights) saved at the same moment.
- ``last.safetensors``: the weights at the latest checkpoint.
- ``metrics.jsonl``: one JSON object per line (``kind`` = start | step | epoch | end; see
  :mod:`rmi_learn.metrics_log`, which also reads it back).
- ``tensorboard/``: with ``tensorboard=True``, the same numbers as TensorBoard scalars.
- ``train_state.pt``: everything needed to resume bit-exactly (model, optimiser, scheduler,
  step/epoch/batch position, torch/numpy/python RNG, hook state). Loaded with
  ``weights_only=True``; it is never needed for inference.
- ``summary.json``: written when the run finishes (status, best epoch and metric).

A run directory that already holds a run is never overwritten: pass ``resume=True`` to
continue it (a finished run then returns its summary at once).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from rmi_learn.metrics_log import METRICS_FILE, TENSORBOARD_DIR, TensorBoardLog

__all__ = [
    "EMA",
    "Hook",
    "TrainConfig",
    "TrainState",
    "Trainer",
    "count_parameters",
    "fetch_batch",
    "load_weights",
    "read_config",
    "save_weights",
    "seed_everything",
]

STATE_FILE = "train_state.pt"
CONFIG_FILE = "config.json"
SUMMARY_FILE = "summary.json"
BEST_WEIGHTS = "model.safetensors"
LAST_WEIGHTS = "last.safetensors"

#: TrainConfig fields that may differ between the first call and a resume.
RESUME_FREE = {"progress", "device", "log_every"}


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


class Hook:
    """Extension point (e.g. EMA weights). Override what you need; all methods are optional."""

    #: names the extra weight files: ``model.<name>.safetensors``
    name: str = "hook"

    def on_fit_start(self, trainer: Trainer) -> None:
        """Called once per ``fit`` after the state was created or restored."""

    def on_step_end(self, trainer: Trainer) -> None:
        """Called after every optimiser step (``trainer.state.step`` already counts it)."""

    def on_epoch_end(self, trainer: Trainer, metrics: dict[str, float]) -> None:
        """Called after evaluation at the end of each epoch; may add entries to ``metrics``."""

    def state_dict(self) -> dict[str, Any]:
        """Resume state (tensors and plain Python values)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned."""

    def weights(self) -> dict[str, torch.Tensor]:
        """Extra weights to save next to the selected checkpoint ({} for none)."""
        return {}


class EMA(Hook):
    """Exponential moving average of the parameters with a warmed-up decay.

    decay(n) = min(max_decay, 1 - (1 + n)^-power) after n updates, so early weights are
    forgotten quickly (a constant 0.999 from step 0 would keep 37 % of the initial weights
    after 1000 steps). ``with ema.applied(model): ...`` evaluates with the averaged weights;
    the averaged weights are saved as ``model.ema.safetensors`` with the selected checkpoint.
    """

    name = "ema"

    def __init__(self, max_decay: float = 0.999, power: float = 0.75) -> None:
        self.max_decay = max_decay
        self.power = power
        self.updates = 0
        self.shadow: dict[str, torch.Tensor] = {}

    def decay(self) -> float:
        """Decay used for the next update (dimensionless)."""
        return float(min(self.max_decay, 1.0 - (1.0 + self.updates) ** -self.power))

    def _init(self, model: torch.nn.Module) -> None:
        self.shadow = {k: v.detach().clone() for k, v in model.state_dict().items()}

    def on_fit_start(self, trainer: Trainer) -> None:
        if not self.shadow:
            self._init(trainer.model)

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        """One EMA update from the live weights of ``model``."""
        if not self.shadow:
            self._init(model)
        d = self.decay()
        for k, v in model.state_dict().items():
            s = self.shadow[k]
            if v.dtype.is_floating_point:
                s.mul_(d).add_(v.detach(), alpha=1.0 - d)
            else:
                s.copy_(v)
        self.updates += 1

    def on_step_end(self, trainer: Trainer) -> None:
        self.update(trainer.model)

    def state_dict(self) -> dict[str, Any]:
        return {"updates": self.updates, "shadow": dict(self.shadow)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.updates = int(state["updates"])
        self.shadow = {k: v.clone() for k, v in state["shadow"].items()}

    def weights(self) -> dict[str, torch.Tensor]:
        return dict(self.shadow)

    def applied(self, model: torch.nn.Module) -> _Swap:
        """Context manager: ``model`` holds the EMA weights inside, its live weights after."""
        return _Swap(model, self.shadow)


class _Swap:
    def __init__(self, model: torch.nn.Module, weights: dict[str, torch.Tensor]) -> None:
        self.model, self.weights = model, weights
        self.saved: dict[str, torch.Tensor] = {}

    def __enter__(self) -> torch.nn.Module:
        self.saved = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
        self.model.load_state_dict(self.weights)
        return self.model

    def __exit__(self, *exc: object) -> None:
        self.model.load_state_dict(self.saved)


# ----------------------------------------------------------------------------- helpers


def seed_everything(seed: int, deterministic: bool = False) -> None:
    """Seed python, numpy and torch; optionally force deterministic torch kernels."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    if deterministic:
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.use_deterministic_algorithms(True)
        torch.backends.cudnn.benchmark = False
        torch.backends.cudnn.deterministic = True


def count_parameters(model: torch.nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def fetch_batch(
    data: Any, indices: np.ndarray, device: str | torch.device = "cpu"
) -> dict[str, Any]:
    """Batch ``indices`` of ``data``: ``data.batch(indices)`` if it exists, else ``data[i]``
    collated with torch's default collate; tensors are moved to ``device``."""
    if hasattr(data, "batch"):
        batch = data.batch(indices)
    else:
        from torch.utils.data import default_collate

        batch = default_collate([data[int(i)] for i in indices])
    return {
        k: (v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v)
        for k, v in batch.items()
    }


def _state_tensors(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu().clone().contiguous() for k, v in model.state_dict().items()}


def save_weights(tensors: dict[str, torch.Tensor], path: str | Path) -> None:
    """Write a dict of tensors as safetensors (atomically: a temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    save_file({k: v.detach().cpu().clone().contiguous() for k, v in tensors.items()}, str(tmp))
    os.replace(tmp, path)


def load_weights(
    model: torch.nn.Module, out_dir: str | Path, which: str = "model", strict: bool = True
) -> torch.nn.Module:
    """Load ``out_dir/<which>.safetensors`` (``model``: the selected weights, ``last``: the
    latest, ``model.ema``: EMA weights) into ``model`` and return it."""
    from safetensors import SafetensorError

    from rmi_learn.errors import InputError

    path = Path(out_dir) / f"{which}.safetensors"
    try:
        tensors = load_file(str(path))
    except SafetensorError as exc:
        raise InputError(f"{path}: damaged weights file ({exc}); train the run again") from exc
    try:
        model.load_state_dict(tensors, strict=strict)
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        raise InputError(f"{path}: weights do not fit the model of {CONFIG_FILE}: {first}") from exc
    return model


def read_config(out_dir: str | Path) -> dict[str, Any]:
    """The ``config.json`` of a run directory (FileNotFoundError naming the directory when
    it is not one)."""
    path = Path(out_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{out_dir} is not a training run directory (no {CONFIG_FILE})")
    config = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(config, dict) or not isinstance(config.get("model"), dict):
        from rmi_learn.data.runs import json_kind
        from rmi_learn.errors import InputError

        got = json_kind(config.get("model") if isinstance(config, dict) else config)
        raise InputError(
            f"{path}: a training run's config is a JSON object whose 'model' is an object, "
            f"got {got}"
        )
    return config


def _write_json(path: Path, obj: Any) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _rng_state() -> dict[str, Any]:
    np_state: Any = np.random.get_state()
    py_state = random.getstate()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "key": torch.from_numpy(np.asarray(np_state[1], dtype=np.int64)),
            "pos": int(np_state[2]),
            "has_gauss": int(np_state[3]),
            "cached": float(np_state[4]),
        },
        "python": {
            "version": int(py_state[0]),
            "state": torch.tensor(py_state[1], dtype=torch.int64),
            "gauss": py_state[2],
        },
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state(
        ("MT19937", n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached"])
    )
    p = state["python"]
    random.setstate((p["version"], tuple(int(x) for x in p["state"].tolist()), p["gauss"]))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _epoch_order(n: int, seed: int, epoch: int) -> np.ndarray:
    """Data order of one epoch: a permutation fixed by (seed, epoch), so resumes replay it."""
    g = np.random.default_rng([seed, epoch, 0x5EED])
    return g.permutation(n)


# ----------------------------------------------------------------------------- trainer

LossOut = torch.Tensor | tuple[torch.Tensor, dict[str, float]]


class Trainer:
    """Train ``model`` on ``train_data`` into ``out_dir``; see the module docstring.

    Args:
        model: the network (moved to ``config.device``).
        loss_fn: ``(model, batch, state) -> loss`` or ``(loss, logs)``.
        train_data: an object with ``__len__`` and ``batch(indices)`` or ``__getitem__``.
        out_dir: run directory (created).
        config: optimisation settings; ``config.effective()`` is used (debug mode).
        evaluate: ``(model, state) -> {metric: float}``, run after each epoch in eval mode
            under ``torch.no_grad``.
        model_config: JSON describing how to rebuild the model (stored as config["model"]).
        extra_config: any other JSON to store (data path, size, ...), config["extra"].
        hooks: :class:`Hook` instances (EMA, ...).
        resume: continue the run found in ``out_dir`` instead of refusing to touch it.
        resume_fixed: keys of ``extra_config`` that a resume must repeat (settings that shape
            the data or the loss); the model and optimisation settings always must.
        resume_legacy: values of ``resume_fixed`` keys assumed for a first call that did not
            record them.
        tensorboard: also write the metrics as TensorBoard events under
            ``out_dir/tensorboard`` (needs the ``tensorboard`` package; checked here).
    """

    def __init__(
        self,
        model: torch.nn.Module,
        loss_fn: Callable[[torch.nn.Module, dict[str, Any], TrainState], LossOut],
        train_data: Any,
        out_dir: str | Path,
        config: TrainConfig,
        *,
        evaluate: Callable[[torch.nn.Module, TrainState], dict[str, float]] | None = None,
        model_config: dict[str, Any] | None = None,
        extra_config: dict[str, Any] | None = None,
        hooks: Sequence[Hook] = (),
        resume: bool = False,
        resume_fixed: Sequence[str] = (),
        resume_legacy: dict[str, Any] | None = None,
        tensorboard: bool = False,
    ) -> None:
        self.config = config
        self.cfg = config.effective()
        self.model = model.to(self.cfg.device)
        self.loss_fn = loss_fn
        self.train_data = train_data
        self.out_dir = Path(out_dir)
        self.evaluate = evaluate
        self.model_config = model_config or {}
        self.extra_config = extra_config or {}
        self.hooks = list(hooks)
        self.resume = resume
        self.resume_fixed = tuple(resume_fixed)
        self.resume_legacy = resume_legacy or {}
        self.tensorboard = tensorboard
        self._tb: TensorBoardLog | None = None
        if tensorboard:
            from rmi_learn.metrics_log import require_tensorboard

            require_tensorboard()
        if len(train_data) == 0:
            raise ValueError("the training data set is empty")
        if self.cfg.select_mode not in ("min", "max"):
            raise ValueError(f"select_mode must be 'min' or 'max', got {self.cfg.select_mode!r}")
        if self.evaluate is None and self.cfg.select_metric != "train_loss":
            raise ValueError("select_metric other than 'train_loss' needs an evaluate function")

        has_run = (self.out_dir / CONFIG_FILE).exists() or (self.out_dir / STATE_FILE).exists()
        if has_run and not resume:
            raise FileExistsError(
                f"{self.out_dir} already holds a run; pass resume=True (--resume) to continue "
                "it, or choose another output directory"
            )
        self.state = TrainState(epochs_total=self.cfg.epochs)
        self.optimizer = self._make_optimizer()
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, self._lr_factor)
        self._resumed = False
        if resume and (self.out_dir / STATE_FILE).exists():
            self._load_checkpoint()
        else:
            seed_everything(self.cfg.seed, self.cfg.deterministic)

    # -- construction helpers

    def _make_optimizer(self) -> torch.optim.Optimizer:
        params = [p for p in self.model.parameters() if p.requires_grad]
        c = self.cfg
        if c.optimizer == "adam":
            return torch.optim.Adam(params, lr=c.lr, betas=c.betas, weight_decay=c.weight_decay)
        if c.optimizer == "adamw":
            return torch.optim.AdamW(params, lr=c.lr, betas=c.betas, weight_decay=c.weight_decay)
        raise ValueError(f"unknown optimizer {c.optimizer!r}")

    def steps_per_epoch(self) -> int:
        """Optimiser steps in one epoch (after the debug/step caps)."""
        n = len(self.train_data)
        b = self.cfg.batch_size
        steps = n // b if self.cfg.drop_last else math.ceil(n / b)
        steps = max(steps, 1)
        if self.cfg.max_steps_per_epoch is not None:
            steps = min(steps, self.cfg.max_steps_per_epoch)
        return steps

    def _lr_factor(self, step: int) -> float:
        c = self.cfg
        if c.warmup_steps > 0 and step < c.warmup_steps:
            return (step + 1) / c.warmup_steps
        if c.scheduler == "none":
            return 1.0
        if c.scheduler == "cosine":
            total = max(1, c.epochs * self.steps_per_epoch() - c.warmup_steps)
            frac = min(1.0, (step - c.warmup_steps) / total)
            return 0.5 * (1.0 + math.cos(math.pi * frac))
        raise ValueError(f"unknown scheduler {c.scheduler!r}")

    # -- persistence

    def _config_json(self) -> dict[str, Any]:
        return {
            "model": self.model_config,
            "train": self.config.to_json(),
            "extra": self.extra_config,
            "params": count_parameters(self.model),
            "train_size": len(self.train_data),
        }

    def _check_resume_config(self) -> None:
        old = read_config(self.out_dir)
        new = self._config_json()
        if old.get("model") != json.loads(json.dumps(new["model"])):
            raise ValueError(
                f"cannot resume {self.out_dir}: the model configuration differs "
                f"({old.get('model')} vs {new['model']})"
            )
        defaults = TrainConfig().to_json()
        old_train = {**defaults, **(old.get("train") or {})}
        old_t = {k: v for k, v in old_train.items() if k not in RESUME_FREE}
        new_t = {k: v for k, v in new["train"].items() if k not in RESUME_FREE}
        if old_t != json.loads(json.dumps(new_t)):
            diff = sorted(k for k in set(old_t) | set(new_t) if old_t.get(k) != new_t.get(k))
            raise ValueError(f"cannot resume {self.out_dir}: training settings differ in {diff}")
        old_extra = {**self.resume_legacy, **(old.get("extra") or {})}
        for key in self.resume_fixed:
            if key in old_extra and old_extra[key] != new["extra"][key]:
                raise ValueError(
                    f"cannot resume {self.out_dir}: {key} was {old_extra[key]!r} in the first "
                    f"call, now {new['extra'][key]!r}"
                )

    def _save_checkpoint(self) -> None:
        ckpt = {
            "model": _state_tensors(self.model),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "state": dataclasses.asdict(self.state),
            "rng": _rng_state(),
            "hooks": {h.name: h.state_dict() for h in self.hooks},
        }
        tmp = self.out_dir / (STATE_FILE + ".tmp")
        torch.save(ckpt, tmp)
        os.replace(tmp, self.out_dir / STATE_FILE)
        save_weights(ckpt["model"], self.out_dir / LAST_WEIGHTS)

    def _load_checkpoint(self) -> None:
        self._check_resume_config()
        ckpt = torch.load(self.out_dir / STATE_FILE, map_location="cpu", weights_only=True)
        self.model.load_state_dict(ckpt["model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        self.state = TrainState(**ckpt["state"])
        for h in self.hooks:
            if h.name in ckpt["hooks"]:
                h.load_state_dict(ckpt["hooks"][h.name])
        _set_rng_state(ckpt["rng"])
        if self.cfg.deterministic:
            seed_everything(self.cfg.seed, True)
            _set_rng_state(ckpt["rng"])
        self._resumed = True
        # Drop metrics lines written after this checkpoint (a crash between log and save).
        path = self.out_dir / METRICS_FILE
        if path.exists():
            keep = []
            for line in path.read_text(encoding="utf-8").splitlines():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if rec.get("step", 0) <= self.state.step:
                    keep.append(line)
            path.write_text("".join(k + "\n" for k in keep), encoding="utf-8")

    def log(self, record: dict[str, Any]) -> None:
        """Append one JSON line to metrics.jsonl (adds ``step`` and wall ``time``), and hand
        it to TensorBoard when that is on."""
        rec = {"step": self.state.step, "time": time.time(), **record}
        with open(self.out_dir / METRICS_FILE, "a", encoding="utf-8") as f:
            f.write(json.dumps(rec, sort_keys=True, default=float) + "\n")
        if self._tb is not None:
            self._tb.write(rec)

    def _save_best(self) -> None:
        save_weights(_state_tensors(self.model), self.out_dir / BEST_WEIGHTS)
        for h in self.hooks:
            w = h.weights()
            if w:
                save_weights(w, self.out_dir / f"model.{h.name}.safetensors")

    def summary(self) -> dict[str, Any]:
        """Status of the run: finished, stopped_early, epochs, steps, best metric and epoch."""
        s = self.state
        return {
            "finished": s.finished,
            "stopped_early": s.stopped_early,
            "epochs": s.epoch,
            "steps": s.step,
            "select_metric": self.cfg.select_metric,
            "best_metric": s.best_metric,
            "best_epoch": s.best_epoch,
        }

    # -- the loop

    def _improved(self, value: float) -> bool:
        best = self.state.best_metric
        if not math.isfinite(value):
            return False
        if best is None:
            return True
        return value < best if self.cfg.select_mode == "min" else value > best

    def _batches(self, epoch: int, start: int) -> Iterable[np.ndarray]:
        order = _epoch_order(len(self.train_data), self.cfg.seed, epoch)
        b = self.cfg.batch_size
        for i in range(start, self.steps_per_epoch()):
            idx = order[i * b : (i + 1) * b]
            if len(idx) == 0:
                idx = order[:b]
            yield idx

    def fit(self, stop_after_steps: int | None = None) -> dict[str, Any]:
        """Train until the configured epochs, early stopping, or ``stop_after_steps`` optimiser
        steps taken in this call (the run then stays resumable). Returns :meth:`summary`."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if self.state.finished:
            return self.summary()
        if self.tensorboard:
            purge = self.state.step + 1 if self._resumed else None
            self._tb = TensorBoardLog(self.out_dir / TENSORBOARD_DIR, purge_step=purge)
        try:
            return self._fit(stop_after_steps)
        finally:
            if self._tb is not None:
                self._tb.close()
                self._tb = None

    def _fit(self, stop_after_steps: int | None) -> dict[str, Any]:
        if not self._resumed:
            _write_json(self.out_dir / CONFIG_FILE, self._config_json())
        for h in self.hooks:
            h.on_fit_start(self)
        cfg = self.cfg
        self.log(
            {
                "kind": "start",
                "params": count_parameters(self.model),
                "train_size": len(self.train_data),
                "steps_per_epoch": self.steps_per_epoch(),
                "resumed": self._resumed,
                "epoch": self.state.epoch,
            }
        )
        taken = 0
        try:
            from tqdm.auto import tqdm  # type: ignore[import-untyped,unused-ignore]
        except ImportError:  # pragma: no cover
            tqdm = None  # type: ignore[assignment,unused-ignore]
        while self.state.epoch < cfg.epochs:
            st = self.state
            t0 = time.perf_counter()
            self.model.train()
            bar = None
            if cfg.progress and tqdm is not None:
                bar = tqdm(
                    total=self.steps_per_epoch(),
                    initial=st.batch_in_epoch,
                    desc=f"epoch {st.epoch + 1}/{cfg.epochs}",
                    leave=False,
                    dynamic_ncols=True,
                )
            for idx in self._batches(st.epoch, st.batch_in_epoch):
                batch = fetch_batch(self.train_data, idx, cfg.device)
                out = self.loss_fn(self.model, batch, st)
                loss, logs = out if isinstance(out, tuple) else (out, {})
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"non-finite loss {loss.item()} at step {st.step}")
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()  # type: ignore[no-untyped-call,unused-ignore]
                if cfg.grad_clip is not None:
                    torch.nn.utils.clip_grad_norm_(self.model.parameters(), cfg.grad_clip)
                self.optimizer.step()
                self.scheduler.step()
                lv = float(loss.detach())
                st.step += 1
                st.batch_in_epoch += 1
                st.train_loss_sum += lv
                st.train_batches += 1
                for k, v in logs.items():
                    st.extra_sums[k] = st.extra_sums.get(k, 0.0) + float(v)
                for h in self.hooks:
                    h.on_step_end(self)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(loss=f"{lv:.4g}")
                if cfg.log_every and st.step % cfg.log_every == 0:
                    self.log(
                        {
                            "kind": "step",
                            "epoch": st.epoch + 1,
                            "loss": lv,
                            "lr": self.scheduler.get_last_lr()[0],
                            **{k: float(v) for k, v in logs.items()},
                        }
                    )
                taken += 1
                if cfg.checkpoint_every and st.step % cfg.checkpoint_every == 0:
                    self._save_checkpoint()
                if stop_after_steps is not None and taken >= stop_after_steps:
                    if bar is not None:
                        bar.close()
                    self._save_checkpoint()
                    return self.summary()
            if bar is not None:
                bar.close()
            train_s = time.perf_counter() - t0
            n = max(st.train_batches, 1)
            metrics: dict[str, float] = {"train_loss": st.train_loss_sum / n}
            metrics.update({f"train_{k}": v / n for k, v in st.extra_sums.items()})
            if self.evaluate is not None:
                self.model.eval()
                with torch.no_grad():
                    metrics.update(self.evaluate(self.model, st))
                self.model.train()
            for h in self.hooks:
                h.on_epoch_end(self, metrics)
            if cfg.select_metric not in metrics:
                raise KeyError(
                    f"select_metric {cfg.select_metric!r} not among metrics {sorted(metrics)}"
                )
            value = float(metrics[cfg.select_metric])
            st.epoch += 1
            st.batch_in_epoch = 0
            st.train_loss_sum, st.train_batches, st.extra_sums = 0.0, 0, {}
            eligible = st.epoch > cfg.select_after or (
                st.best_epoch is None and st.epoch >= cfg.epochs
            )
            best = eligible and self._improved(value)
            if best:
                st.best_metric, st.best_epoch, st.bad_epochs = value, st.epoch, 0
                self._save_best()
            else:
                st.bad_epochs += 1
            if st.epoch <= cfg.min_epochs:
                st.bad_epochs = 0
            if cfg.patience is not None and st.bad_epochs >= cfg.patience:
                st.finished = st.stopped_early = True
            if st.epoch >= cfg.epochs:
                st.finished = True
            self.log(
                {
                    "kind": "epoch",
                    "epoch": st.epoch,
                    "lr": self.scheduler.get_last_lr()[0],
                    "epoch_s": time.perf_counter() - t0,
                    "train_s": train_s,
                    "best": best,
                    **metrics,
                }
            )
            if cfg.progress:
                print(
                    f"epoch {st.epoch}/{cfg.epochs}: train_loss {metrics['train_loss']:.4g}, "
                    f"{cfg.select_metric} {value:.4g}{' (best)' if best else ''}, "
                    f"{time.perf_counter() - t0:.1f} s",
                    file=sys.stderr,
                )
            if not (self.out_dir / BEST_WEIGHTS).exists():
                # No epoch selected yet (non-finite metrics, or all before ``select_after``):
                # keep weights on disk so that an interrupted run still has a model file.
                self._save_best()
            self._save_checkpoint()
            if st.finished:
                break
        self.state.finished = True
        self._save_checkpoint()
        summary = self.summary()
        _write_json(self.out_dir / SUMMARY_FILE, summary)
        self.log({"kind": "end", **summary})
        return summary
