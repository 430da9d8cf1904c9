"""The training loop (:class:`Trainer`): epochs of optimiser steps over a data set, an
evaluation after each, checkpoint selection and early stopping, metrics lines and resumable
checkpoints (see :mod:`rmi_learn.trainer`)."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm  # type: ignore[import-untyped,unused-ignore]

from rmi_learn.metrics_log import (
    TENSORBOARD_DIR,
    TensorBoardLog,
    append_record,
    drop_records_after,
    require_tensorboard,
)
from rmi_learn.trainer.batches import epoch_order, fetch_batch
from rmi_learn.trainer.checkpoint import load_checkpoint, save_checkpoint
from rmi_learn.trainer.config import TrainConfig, TrainState
from rmi_learn.trainer.determinism import seed_everything, set_rng_state
from rmi_learn.trainer.hooks import Hook
from rmi_learn.trainer.resume import check_resume_config
from rmi_learn.trainer.run_files import (
    BEST_WEIGHTS,
    CONFIG_FILE,
    STATE_FILE,
    SUMMARY_FILE,
    write_json,
)
from rmi_learn.trainer.weights import count_parameters, save_weights, state_tensors

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

    def _save_checkpoint(self) -> None:
        save_checkpoint(
            self.out_dir, self.model, self.optimizer, self.scheduler, self.state, self.hooks
        )

    def _load_checkpoint(self) -> None:
        check_resume_config(
            self.out_dir, self._config_json(), self.resume_fixed, self.resume_legacy
        )
        self.state, rng = load_checkpoint(
            self.out_dir, self.model, self.optimizer, self.scheduler, self.hooks
        )
        if self.cfg.deterministic:
            seed_everything(self.cfg.seed, True)
            set_rng_state(rng)
        self._resumed = True
        # Drop metrics lines written after this checkpoint (a crash between log and save).
        drop_records_after(self.out_dir, self.state.step)

    def log(self, record: dict[str, Any]) -> None:
        """Append one JSON line to metrics.jsonl (adds ``step`` and wall ``time``), and hand
        it to TensorBoard when that is on."""
        rec = {"step": self.state.step, "time": time.time(), **record}
        append_record(self.out_dir, rec)
        if self._tb is not None:
            self._tb.write(rec)

    def _save_best(self) -> None:
        save_weights(state_tensors(self.model), self.out_dir / BEST_WEIGHTS)
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
        order = epoch_order(len(self.train_data), self.cfg.seed, epoch)
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
        self._start()
        taken = 0
        while self.state.epoch < self.cfg.epochs:
            t0 = time.perf_counter()
            taken, interrupted = self._train_epoch(taken, stop_after_steps)
            if interrupted:
                self._save_checkpoint()
                return self.summary()
            train_s = time.perf_counter() - t0
            metrics = self._epoch_metrics()
            value = float(metrics[self.cfg.select_metric])
            best = self._end_epoch(value)
            self._report_epoch(metrics, value, best, t0, train_s)
            if not (self.out_dir / BEST_WEIGHTS).exists():
                # No epoch selected yet (non-finite metrics, or all before ``select_after``):
                # keep weights on disk so that an interrupted run still has a model file.
                self._save_best()
            self._save_checkpoint()
            if self.state.finished:
                break
        return self._finish()

    def _start(self) -> None:
        """Write config.json on a first call, start the hooks, log the ``start`` line."""
        if not self._resumed:
            write_json(self.out_dir / CONFIG_FILE, self._config_json())
        for h in self.hooks:
            h.on_fit_start(self)
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

    def _train_epoch(self, taken: int, stop_after_steps: int | None) -> tuple[int, bool]:
        """The remaining optimiser steps of the epoch in progress. Returns the steps taken in
        this call so far and whether ``stop_after_steps`` cut the epoch short."""
        cfg, st = self.cfg, self.state
        self.model.train()
        bar = None
        if cfg.progress:
            bar = tqdm(
                total=self.steps_per_epoch(),
                initial=st.batch_in_epoch,
                desc=f"epoch {st.epoch + 1}/{cfg.epochs}",
                leave=False,
                dynamic_ncols=True,
            )
        for idx in self._batches(st.epoch, st.batch_in_epoch):
            lv = self._step(idx)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{lv:.4g}")
            taken += 1
            if cfg.checkpoint_every and st.step % cfg.checkpoint_every == 0:
                self._save_checkpoint()
            if stop_after_steps is not None and taken >= stop_after_steps:
                if bar is not None:
                    bar.close()
                return taken, True
        if bar is not None:
            bar.close()
        return taken, False

    def _step(self, idx: np.ndarray) -> float:
        """One optimiser step on the batch ``idx``: loss, gradient (clipped), update, running
        sums, hooks and, every ``log_every`` steps, a ``step`` line. Returns the loss."""
        cfg, st = self.cfg, self.state
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
        return lv

    def _epoch_metrics(self) -> dict[str, float]:
        """The epoch's mean training loss and terms, the evaluation's metrics and what the
        hooks add; KeyError when the selection metric is not among them."""
        st = self.state
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
        if self.cfg.select_metric not in metrics:
            raise KeyError(
                f"select_metric {self.cfg.select_metric!r} not among metrics {sorted(metrics)}"
            )
        return metrics

    def _end_epoch(self, value: float) -> bool:
        """Close the epoch: count it, select its weights when ``value`` improves on the best
        (from ``select_after`` on), count patience, mark the run finished when it stops.
        Returns whether the epoch was selected."""
        cfg, st = self.cfg, self.state
        st.epoch += 1
        st.batch_in_epoch = 0
        st.train_loss_sum, st.train_batches, st.extra_sums = 0.0, 0, {}
        eligible = st.epoch > cfg.select_after or (st.best_epoch is None and st.epoch >= cfg.epochs)
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
        return best

    def _report_epoch(
        self, metrics: dict[str, float], value: float, best: bool, t0: float, train_s: float
    ) -> None:
        """The ``epoch`` metrics line and, with progress on, one line on stderr."""
        cfg, st = self.cfg, self.state
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

    def _finish(self) -> dict[str, Any]:
        """Mark the run finished, checkpoint it, write summary.json and the ``end`` line."""
        self.state.finished = True
        self._save_checkpoint()
        summary = self.summary()
        write_json(self.out_dir / SUMMARY_FILE, summary)
        self.log({"kind": "end", **summary})
        return summary
