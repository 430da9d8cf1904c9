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

Layout: :mod:`.loop` (:class:`Trainer`), :mod:`.config` (settings and progress counters),
:mod:`.hooks` (:class:`Hook`, :class:`EMA`), :mod:`.batches` (data order and batches),
:mod:`.determinism` (seeding and random-number state), :mod:`.checkpoint` (the resumable
checkpoint), :mod:`.resume` (which settings a resume must repeat), :mod:`.weights` and
:mod:`.run_files` (the files of a run directory).
"""

from rmi_learn.trainer.batches import fetch_batch
from rmi_learn.trainer.config import TrainConfig, TrainState
from rmi_learn.trainer.determinism import seed_everything
from rmi_learn.trainer.hooks import EMA, Hook
from rmi_learn.trainer.loop import Trainer
from rmi_learn.trainer.resume import RESUME_FREE
from rmi_learn.trainer.run_files import (
    BEST_WEIGHTS,
    CONFIG_FILE,
    LAST_WEIGHTS,
    STATE_FILE,
    SUMMARY_FILE,
    read_config,
    write_json,
)
from rmi_learn.trainer.weights import count_parameters, load_weights, save_weights

__all__ = [
    "BEST_WEIGHTS",
    "CONFIG_FILE",
    "EMA",
    "LAST_WEIGHTS",
    "RESUME_FREE",
    "STATE_FILE",
    "SUMMARY_FILE",
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
    "write_json",
]
