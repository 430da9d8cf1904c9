"""The training metrics a user watches: ``metrics.jsonl`` in every run directory, read back
by :func:`epoch_records`, and optional TensorBoard event files (:class:`TensorBoardLog`).

``metrics.jsonl`` holds one JSON object per line, appended and flushed as training goes
(``tail -f RUN/metrics.jsonl`` follows a run): ``kind`` is ``start``, ``step`` (every
``log_every`` optimiser steps: ``loss``, ``lr`` and the loss terms), ``epoch`` (one per
epoch: ``epoch``, ``train_loss``, the validation metrics such as ``val_loss``, ``lr``,
``best``, wall times) or ``end``; every line has the optimiser ``step`` and the wall
``time`` (Unix time, s). A resumed run drops the lines written after its checkpoint,
so each epoch appears once.

TensorBoard is optional: :class:`TensorBoardLog` writes the same numbers as scalars under
``RUN/tensorboard`` (tags ``epoch/<name>`` and ``step/<name>``, x axis the optimiser step)
and needs the ``tensorboard`` package; without it, :func:`require_tensorboard` raises a
:class:`~rmi_learn.errors.StageFailure` whose one line says how to install it. This module
imports neither torch nor tensorboard at import time.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from rmi_learn.errors import StageFailure

METRICS_FILE = "metrics.jsonl"
#: Subdirectory of a run directory that holds its TensorBoard event files.
TENSORBOARD_DIR = "tensorboard"
#: Keys of a metrics line that are bookkeeping, not scalars to plot.
_NOT_SCALARS = frozenset({"kind", "step", "time", "epoch", "best", "resumed"})


def require_tensorboard() -> None:
    """Raise :class:`~rmi_learn.errors.StageFailure` (one line: install tensorboard) unless
    torch's TensorBoard writer can be imported."""
    try:
        from torch.utils.tensorboard import SummaryWriter  # noqa: F401
    except ImportError:
        raise StageFailure(
            "--tensorboard needs the tensorboard package: pip install tensorboard "
            "(metrics.jsonl in the run directory has the same numbers)"
        ) from None


class TensorBoardLog:
    """Scalars of the metrics lines as TensorBoard events under ``log_dir``.

    ``purge_step``: on a resumed run, the optimiser step of its checkpoint plus one, so that
    TensorBoard hides the events an interrupted call wrote after that checkpoint (the same
    lines ``metrics.jsonl`` drops).
    """

    def __init__(self, log_dir: str | os.PathLike[str], purge_step: int | None = None) -> None:
        require_tensorboard()
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(log_dir=str(log_dir), purge_step=purge_step)

    def write(self, record: dict[str, Any]) -> None:
        """Add the numbers of one metrics line (``step`` and ``epoch`` lines; others are
        skipped) at its optimiser step; an epoch line is flushed at once."""
        kind = record.get("kind")
        if kind not in ("step", "epoch"):
            return
        step = int(record.get("step", 0))
        for key, value in record.items():
            if key in _NOT_SCALARS or isinstance(value, bool):
                continue
            if isinstance(value, (int, float)) and math.isfinite(value):
                self.writer.add_scalar(f"{kind}/{key}", float(value), step)
        if kind == "epoch":
            self.writer.flush()

    def close(self) -> None:
        """Flush and close the event file."""
        self.writer.close()


def epoch_records(run_dir: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The ``epoch`` lines of ``run_dir/metrics.jsonl`` in epoch order, one per epoch (the
    last one written wins); [] when the file is missing. A line cut short by a killed
    writer is skipped."""
    path = Path(run_dir) / METRICS_FILE
    if not path.is_file():
        return []
    by_epoch: dict[int, dict[str, Any]] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict) and rec.get("kind") == "epoch":
            epoch = rec.get("epoch")
            if isinstance(epoch, int):
                by_epoch[epoch] = rec
    return [by_epoch[e] for e in sorted(by_epoch)]


def loss_curves(run_dir: str | os.PathLike[str]) -> dict[str, list[float]]:
    """Per-epoch losses of a run: ``epoch`` (1-based), ``train_loss`` and, where the run
    records it, ``val_loss`` (NaN for an epoch without it); {} for a run without training
    losses (the closed-form world models)."""
    recs = [r for r in epoch_records(run_dir) if isinstance(r.get("train_loss"), (int, float))]
    if not recs:
        return {}
    out: dict[str, list[float]] = {
        "epoch": [float(r["epoch"]) for r in recs],
        "train_loss": [float(r["train_loss"]) for r in recs],
    }
    val = [r.get("val_loss") for r in recs]
    if any(isinstance(v, (int, float)) for v in val):
        out["val_loss"] = [float(v) if isinstance(v, (int, float)) else math.nan for v in val]
    best = [float(r["epoch"]) for r in recs if r.get("best") is True]
    if best:
        out["best_epoch"] = [best[-1]]
    return out


def append_record(run_dir: str | os.PathLike[str], record: dict[str, Any]) -> None:
    """Append ``record`` as one line of ``run_dir/metrics.jsonl`` (keys sorted; numbers that
    JSON cannot hold as such, e.g. numpy scalars, as floats)."""
    with open(Path(run_dir) / METRICS_FILE, "a", encoding="utf-8") as f:
        f.write(json.dumps(record, sort_keys=True, default=float) + "\n")


def drop_records_after(run_dir: str | os.PathLike[str], step: int) -> None:
    """Keep only the lines of ``run_dir/metrics.jsonl`` written at optimiser steps up to
    ``step`` (a resumed run's checkpoint), so that lines logged after the checkpoint by an
    interrupted call are not repeated; lines cut short are dropped."""
    path = Path(run_dir) / METRICS_FILE
    if not path.exists():
        return
    keep = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if rec.get("step", 0) <= step:
            keep.append(line)
    path.write_text("".join(k + "\n" for k in keep), encoding="utf-8")
