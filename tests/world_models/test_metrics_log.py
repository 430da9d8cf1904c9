"""The training metrics a user watches (rmi_learn.metrics_log): metrics.jsonl read back per
epoch, TensorBoard events through torch's writer (a recording stand-in when the
``tensorboard`` package is absent), and the one line that asks to install it."""

from __future__ import annotations

import importlib.util
import json
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from rmi_learn import metrics_log
from rmi_learn.cli import main
from rmi_learn.trainer import TrainConfig, Trainer

HAVE_TENSORBOARD = importlib.util.find_spec("tensorboard") is not None


class Line:
    """y = 2 x: a data set with ``batch(indices)`` like the learning windows."""

    def __init__(self, n: int = 32) -> None:
        self.x = torch.linspace(-1, 1, n).unsqueeze(-1)

    def __len__(self) -> int:
        return len(self.x)

    def batch(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        return {"x": self.x[torch.as_tensor(np.asarray(idx))]}


def mse(model: torch.nn.Module, batch: dict[str, torch.Tensor], state: Any) -> torch.Tensor:
    pred: torch.Tensor = model(batch["x"])
    return ((pred - 2 * batch["x"]) ** 2).mean()


def val_mse(model: torch.nn.Module, state: Any) -> dict[str, float]:
    x = Line(8).x
    return {"val_mse": float(((model(x) - 2 * x) ** 2).mean())}


def line_trainer(out: Path, resume: bool = False, **kw: Any) -> Trainer:
    torch.manual_seed(0)
    config = TrainConfig(
        epochs=2, batch_size=8, progress=False, select_metric="val_mse", log_every=2, **kw
    )
    return Trainer(
        torch.nn.Linear(1, 1),
        mse,
        Line(),
        out,
        config,
        evaluate=val_mse,
        tensorboard=True,
        resume=resume,
    )


class RecordingWriter:
    """Stands in for torch.utils.tensorboard.SummaryWriter and records what it is given."""

    made: list[RecordingWriter] = []

    def __init__(self, log_dir: str, purge_step: int | None = None) -> None:
        self.log_dir, self.purge_step = log_dir, purge_step
        self.scalars: list[tuple[str, float, int]] = []
        self.flushes = 0
        self.closed = False
        RecordingWriter.made.append(self)

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self.scalars.append((tag, value, step))

    def flush(self) -> None:
        self.flushes += 1

    def close(self) -> None:
        self.closed = True


@pytest.fixture
def recording_writer(monkeypatch: pytest.MonkeyPatch) -> type[RecordingWriter]:
    module = types.ModuleType("torch.utils.tensorboard")
    module.SummaryWriter = RecordingWriter  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", module)
    RecordingWriter.made = []
    return RecordingWriter


def test_epoch_records_one_per_epoch_and_loss_curves(tmp_path: Path) -> None:
    lines = [
        {"kind": "start", "step": 0},
        {"kind": "epoch", "epoch": 1, "step": 3, "train_loss": 2.0, "val_loss": 3.0, "best": True},
        {"kind": "epoch", "epoch": 2, "step": 6, "train_loss": 9.0, "best": False},
        {"kind": "epoch", "epoch": 2, "step": 6, "train_loss": 1.0, "val_loss": 2.5, "best": True},
        {"kind": "epoch", "epoch": 3, "step": 9, "train_loss": 0.5, "best": False},
    ]
    text = "".join(json.dumps(x) + "\n" for x in lines) + '{"kind": "epo'  # cut short
    (tmp_path / "metrics.jsonl").write_text(text)
    recs = metrics_log.epoch_records(tmp_path)
    assert [r["epoch"] for r in recs] == [1, 2, 3] and recs[1]["train_loss"] == 1.0
    curves = metrics_log.loss_curves(tmp_path)
    assert curves["epoch"] == [1.0, 2.0, 3.0]
    assert curves["train_loss"] == [2.0, 1.0, 0.5]
    assert curves["val_loss"][:2] == [3.0, 2.5] and curves["val_loss"][2] != curves["val_loss"][2]
    assert curves["best_epoch"] == [2.0]
    assert metrics_log.epoch_records(tmp_path / "none") == []
    closed_form = tmp_path / "arx"
    closed_form.mkdir()
    (closed_form / "metrics.jsonl").write_text(json.dumps({"kind": "epoch", "epoch": 1}) + "\n")
    assert metrics_log.loss_curves(closed_form) == {}


def test_trainer_writes_each_epoch_to_tensorboard(
    tmp_path: Path, recording_writer: type[RecordingWriter]
) -> None:
    out = tmp_path / "run"
    line_trainer(out).fit()
    (writer,) = recording_writer.made
    assert writer.log_dir == str(out / "tensorboard") and writer.purge_step is None
    assert writer.closed and writer.flushes == 2
    recs = metrics_log.epoch_records(out)
    assert len(recs) == 2
    for rec in recs:
        assert ("epoch/train_loss", rec["train_loss"], rec["step"]) in writer.scalars
        assert ("epoch/val_mse", rec["val_mse"], rec["step"]) in writer.scalars
    assert not any(tag in ("epoch/best", "epoch/epoch") for tag, _, _ in writer.scalars)
    assert any(tag == "step/loss" for tag, _, _ in writer.scalars)


def test_resume_purges_later_events(
    tmp_path: Path, recording_writer: type[RecordingWriter]
) -> None:
    out = tmp_path / "run"
    line_trainer(out).fit(stop_after_steps=3)
    line_trainer(out, resume=True).fit()
    first, second = recording_writer.made
    assert first.closed and second.closed
    assert first.purge_step is None and second.purge_step == 4
    assert second.scalars and min(s for _, _, s in second.scalars) >= 4


@pytest.mark.skipif(HAVE_TENSORBOARD, reason="the tensorboard package is installed")
def test_tensorboard_missing_is_one_line_before_any_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], synthetic_dataset_dir: Path
) -> None:
    for argv in (
        ["train-wm", "--model", "arx"],
        ["train-policy", "--objective", "flow"],
    ):
        out = tmp_path / argv[0]
        assert (
            main([*argv, "--data", str(synthetic_dataset_dir), "--out", str(out), "--tensorboard"])
            == 1
        )
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 1 and "pip install tensorboard" in lines[0], lines
        assert lines[0].startswith(f"rmi {argv[0]}: ") and not out.exists()


@pytest.mark.skipif(not HAVE_TENSORBOARD, reason="needs the tensorboard package")
def test_real_tensorboard_events(tmp_path: Path) -> None:
    out = tmp_path / "run"
    line_trainer(out).fit()
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))


def test_closed_form_world_model_writes_its_epoch(
    tmp_path: Path, synthetic_dataset_dir: Path, recording_writer: type[RecordingWriter]
) -> None:
    from rmi_learn.world_models.training import train

    out = tmp_path / "arx"
    train("arx", synthetic_dataset_dir, out, debug=True, progress=False, tensorboard=True)
    (writer,) = recording_writer.made
    (rec,) = metrics_log.epoch_records(out)
    assert ("epoch/val_water_mae_g@64", rec["val_water_mae_g@64"], 0) in writer.scalars
    assert writer.closed
