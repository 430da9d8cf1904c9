"""Tests of the generic training loop (rmi_learn.trainer)."""

from __future__ import annotations

import json
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from rmi_learn.trainer import (
    EMA,
    Hook,
    TrainConfig,
    Trainer,
    count_parameters,
    load_weights,
    read_config,
)

torch.set_num_threads(1)


class ToyData:
    """y = x @ w + noise, 2-D x; batch(indices) like the learning WindowSet."""

    def __init__(self, n: int = 96, seed: int = 0) -> None:
        g = torch.Generator().manual_seed(seed)
        self.x = torch.randn(n, 4, generator=g)
        self.y = self.x @ torch.tensor([1.0, -2.0, 0.5, 3.0]) + 0.01 * torch.randn(n, generator=g)

    def __len__(self) -> int:
        return len(self.x)

    def batch(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        i = torch.as_tensor(np.asarray(idx), dtype=torch.long)
        return {"x": self.x[i], "y": self.y[i]}


def make_model(seed: int = 0) -> torch.nn.Module:
    torch.manual_seed(seed)
    return torch.nn.Sequential(
        torch.nn.Linear(4, 16), torch.nn.Dropout(0.2), torch.nn.Linear(16, 1)
    )


def loss_fn(
    model: torch.nn.Module, batch: dict[str, torch.Tensor], state: Any
) -> tuple[torch.Tensor, dict[str, float]]:
    # Uses every RNG the resume must restore: torch (dropout), numpy and python.
    jitter = 1.0 + 1e-3 * float(np.random.rand()) + 1e-3 * random.random()
    pred = model(batch["x"]).squeeze(-1)
    loss = ((pred - batch["y"]) ** 2).mean() * jitter
    return loss, {"jitter": jitter}


def val_fn(data: ToyData) -> Callable[[torch.nn.Module, Any], dict[str, float]]:
    def evaluate(model: torch.nn.Module, state: Any) -> dict[str, float]:
        pred = model(data.x).squeeze(-1)
        return {"val_mse": float(((pred - data.y) ** 2).mean())}

    return evaluate


def cfg(**kw: Any) -> TrainConfig:
    base: dict[str, Any] = dict(
        epochs=3,
        batch_size=16,
        lr=1e-2,
        progress=False,
        select_metric="val_mse",
        patience=None,
        log_every=2,
    )
    base.update(kw)
    return TrainConfig(**base)


def read_metrics(out: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]


def test_trains_and_writes_files(tmp_path: Path) -> None:
    data, val = ToyData(), ToyData(64, seed=1)
    out = tmp_path / "run"
    tr = Trainer(
        make_model(),
        loss_fn,
        data,
        out,
        cfg(epochs=6),
        evaluate=val_fn(val),
        model_config={"kind": "toy"},
        extra_config={"note": "x"},
    )
    summary = tr.fit()
    assert summary["finished"] and not summary["stopped_early"]
    assert summary["epochs"] == 6 and summary["steps"] == 6 * 6
    for name in ("config.json", "model.safetensors", "last.safetensors", "train_state.pt"):
        assert (out / name).exists(), name
    conf = read_config(out)
    assert conf["model"] == {"kind": "toy"} and conf["extra"] == {"note": "x"}
    assert conf["params"] == count_parameters(tr.model) == 4 * 16 + 16 + 16 + 1
    assert json.loads((out / "summary.json").read_text())["best_epoch"] == summary["best_epoch"]
    recs = read_metrics(out)
    kinds = [r["kind"] for r in recs]
    assert kinds[0] == "start" and kinds[-1] == "end" and kinds.count("epoch") == 6
    epochs = [r for r in recs if r["kind"] == "epoch"]
    assert epochs[-1]["val_mse"] < 0.5 * epochs[0]["val_mse"]
    assert "train_jitter" in epochs[0] and "train_loss" in epochs[0]
    # The selected weights are those of the best epoch, reloadable without pickles.
    best = min(epochs, key=lambda r: r["val_mse"])
    assert summary["best_epoch"] == best["epoch"]
    m = load_weights(make_model(5), out).eval()
    with torch.no_grad():
        mse = float(((m(val.x).squeeze(-1) - val.y) ** 2).mean())
    assert mse == pytest.approx(best["val_mse"], rel=1e-5)


def test_refuses_to_overwrite_and_finished_resume_is_noop(tmp_path: Path) -> None:
    data = ToyData()
    out = tmp_path / "run"
    Trainer(make_model(), loss_fn, data, out, cfg(), evaluate=val_fn(data)).fit()
    with pytest.raises(FileExistsError, match="resume"):
        Trainer(make_model(), loss_fn, data, out, cfg(), evaluate=val_fn(data))
    before = (out / "model.safetensors").read_bytes()
    n_lines = len(read_metrics(out))
    s = Trainer(make_model(), loss_fn, data, out, cfg(), evaluate=val_fn(data), resume=True).fit()
    assert s["finished"] and s["epochs"] == 3
    assert (out / "model.safetensors").read_bytes() == before
    assert len(read_metrics(out)) == n_lines


def test_resume_mismatched_settings_raises(tmp_path: Path) -> None:
    data = ToyData()
    out = tmp_path / "run"
    Trainer(make_model(), loss_fn, data, out, cfg(), evaluate=val_fn(data)).fit(stop_after_steps=2)
    with pytest.raises(ValueError, match="lr"):
        Trainer(make_model(), loss_fn, data, out, cfg(lr=0.5), evaluate=val_fn(data), resume=True)


@pytest.mark.parametrize("stop_at", [4, 6, 11])
def test_resume_is_bit_exact(tmp_path: Path, stop_at: int) -> None:
    """Interrupt mid-epoch (or on an epoch boundary), resume with a fresh process state."""
    data, val = ToyData(), ToyData(32, seed=2)
    ref = tmp_path / "ref"
    c = cfg(epochs=3, scheduler="cosine", warmup_steps=3, optimizer="adamw", weight_decay=0.01)
    ema_ref = EMA()
    Trainer(make_model(), loss_fn, data, ref, c, evaluate=val_fn(val), hooks=[ema_ref]).fit()

    out = tmp_path / "cut"
    s = Trainer(make_model(), loss_fn, data, out, c, evaluate=val_fn(val), hooks=[EMA()]).fit(
        stop_after_steps=stop_at
    )
    assert not s["finished"] and s["steps"] == stop_at
    # Scramble every RNG and the initial weights, as a new process would.
    torch.manual_seed(1234)
    np.random.seed(99)
    random.seed(7)
    ema = EMA()
    tr = Trainer(
        make_model(3), loss_fn, data, out, c, evaluate=val_fn(val), hooks=[ema], resume=True
    )
    s = tr.fit()
    assert s["finished"] and s["steps"] == 18
    for name in ("last", "model", "model.ema"):
        a = load_file(str(ref / f"{name}.safetensors"))
        b = load_file(str(out / f"{name}.safetensors"))
        for k in a:
            assert torch.equal(a[k], b[k]), (name, k)
    ref_epochs = [r for r in read_metrics(ref) if r["kind"] == "epoch"]
    out_epochs = [r for r in read_metrics(out) if r["kind"] == "epoch"]
    assert [r["val_mse"] for r in ref_epochs] == [r["val_mse"] for r in out_epochs]
    assert [r["train_loss"] for r in ref_epochs] == pytest.approx(
        [r["train_loss"] for r in out_epochs], rel=1e-12
    )


def test_early_stopping_and_max_mode(tmp_path: Path) -> None:
    data = ToyData()
    calls = []

    def worsening(model: torch.nn.Module, state: Any) -> dict[str, float]:
        calls.append(state.epoch)
        return {"score": -float(state.epoch)}  # best at epoch 1 in max mode... then worse

    out = tmp_path / "run"
    s = Trainer(
        make_model(),
        loss_fn,
        data,
        out,
        cfg(epochs=20, patience=3, select_metric="score", select_mode="max"),
        evaluate=worsening,
    ).fit()
    assert s["stopped_early"] and s["finished"]
    assert s["epochs"] == 4 and s["best_epoch"] == 1 and s["best_metric"] == 0.0
    # model.safetensors holds the epoch-1 weights, not the last ones.
    a = load_file(str(out / "model.safetensors"))
    b = load_file(str(out / "last.safetensors"))
    assert any(not torch.equal(a[k], b[k]) for k in a)


def test_patience_counts_after_min_epochs(tmp_path: Path) -> None:
    data = ToyData()

    def worsening(model: torch.nn.Module, state: Any) -> dict[str, float]:
        return {"score": float(state.epoch)}

    c = cfg(epochs=20, patience=3, select_metric="score", min_epochs=5)
    s = Trainer(make_model(), loss_fn, data, tmp_path / "r", c, evaluate=worsening).fit()
    assert s["stopped_early"] and s["epochs"] == 8 and s["best_epoch"] == 1


def test_selection_waits_for_select_after(tmp_path: Path) -> None:
    """An early, lucky epoch before ``select_after`` is never selected; patience counts from
    the first eligible epoch; a run that ends before any eligible epoch keeps its last one."""
    data = ToyData()

    def worsening(model: torch.nn.Module, state: Any) -> dict[str, float]:
        return {"score": float(state.epoch)}  # best at epoch 1, worse every epoch after

    c = cfg(epochs=20, patience=3, select_metric="score", min_epochs=5, select_after=5)
    s = Trainer(make_model(), loss_fn, data, tmp_path / "r", c, evaluate=worsening).fit()
    assert s["best_epoch"] == 6 and s["best_metric"] == 5.0
    assert s["stopped_early"] and s["epochs"] == 9
    short = cfg(epochs=3, select_metric="score", select_after=5)
    out = tmp_path / "short"
    s = Trainer(make_model(), loss_fn, data, out, short, evaluate=worsening).fit()
    assert s["best_epoch"] == 3 and not s["stopped_early"]
    a = load_file(str(out / "model.safetensors"))
    b = load_file(str(out / "last.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_debug_mode_is_tiny(tmp_path: Path) -> None:
    data = ToyData(n=10_000)
    s = Trainer(
        make_model(),
        loss_fn,
        data,
        tmp_path / "r",
        cfg(epochs=50, debug=True),
        evaluate=val_fn(data),
    ).fit()
    assert s["epochs"] == 2 and s["steps"] == 6
    assert read_config(tmp_path / "r")["train"]["debug"] is True


def test_ema_decay_warms_up_and_hook_weights_saved(tmp_path: Path) -> None:
    ema = EMA(max_decay=0.999)
    decays = []
    for _ in range(3):
        decays.append(ema.decay())
        ema.updates += 1
    assert decays[0] == 0.0  # the first update copies the live weights
    assert decays[1] == pytest.approx(1 - 2**-0.75)
    ema.updates = 10**6
    assert ema.decay() == 0.999

    class Counter(Hook):
        name = "counter"

        def __init__(self) -> None:
            self.steps = 0

        def on_step_end(self, trainer: Trainer) -> None:
            self.steps += 1

        def on_epoch_end(self, trainer: Trainer, metrics: dict[str, float]) -> None:
            metrics["hook_steps"] = float(self.steps)

    data = ToyData()
    hook, ema = Counter(), EMA()
    out = tmp_path / "r"
    Trainer(make_model(), loss_fn, data, out, cfg(), evaluate=val_fn(data), hooks=[hook, ema]).fit()
    assert hook.steps == 18
    assert [r["hook_steps"] for r in read_metrics(out) if r["kind"] == "epoch"] == [6, 12, 18]
    w = load_file(str(out / "model.ema.safetensors"))
    assert set(w) == set(make_model().state_dict())
    model = make_model()
    with ema.applied(model):
        assert torch.equal(model.state_dict()["0.weight"], ema.shadow["0.weight"])
    assert not torch.equal(model.state_dict()["0.weight"], ema.shadow["0.weight"])


def test_select_metric_must_exist(tmp_path: Path) -> None:
    data = ToyData()
    with pytest.raises(KeyError, match="nope"):
        Trainer(
            make_model(),
            loss_fn,
            data,
            tmp_path / "r",
            cfg(select_metric="nope"),
            evaluate=val_fn(data),
        ).fit()
    with pytest.raises(ValueError, match="evaluate"):
        Trainer(make_model(), loss_fn, data, tmp_path / "s", cfg(select_metric="val_mse"))
