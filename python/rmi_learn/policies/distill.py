"""Few-step students of a trained policy: :func:`distill_policy` (``rmi distill-policy``).

The teacher (a diffusion or flow policy run, sampled with its own 16 DDIM or 20 Euler
steps) turns a fixed noise chunk into a chunk for a window's condition. The student is the
same UNet, initialised from the teacher, sampled with the same objective's sampler at
``steps`` (1 or 2) network evaluations, and trained so that from the same noise and
condition it lands on the teacher's chunk:

    loss = mean | sampler_steps(student, eps, cond) - sampler_teacher(teacher, eps, cond) |^2

with the gradient taken through the ``steps`` student evaluations. For a flow teacher this
is rectified-flow distillation on (noise, teacher sample) pairs: the one-step student
regresses the velocity ``A_teacher - eps`` at t = 0, i.e. it is the straight path the
teacher's ODE takes on average. For a diffusion teacher the one-step student is the
x0-prediction at t = T - 1 regressed onto the teacher's DDIM end point (the consistency
target at the last step, computed exactly by the teacher's full sampler rather than by
bootstrapping between adjacent steps).

Pairs come from the training windows (evenly spaced subset of at most ``max_windows``,
``pairs_per_window`` noise draws each); a held-out set of pairs from the validation windows
measures the student's mean squared distance to the teacher's chunks, before training (the
teacher's weights sampled with ``steps`` steps) and after each epoch; the epoch with the
smallest distance is kept.

The output is a policy run directory that :func:`~rmi_learn.policies.checkpoint.load_policy`
reads (``config.json``, ``model.safetensors`` and ``model.ema.safetensors``, the same
weights): its objective's ``n_sample_steps`` is the student's step count, and
``config["distill"]`` records the teacher, its step count and the distances.
"""

from __future__ import annotations

import copy
import json
import time
from pathlib import Path
from typing import Any

from rmi_learn.errors import InputError


def few_step_sample(net: Any, sched: Any, obs_cond: Any, noise: Any) -> Any:
    """The sampler ``sched`` (:class:`~rmi_learn.policies.fast_sampler.Schedule`) over ``net``
    with autograd: chunks (N, H, A) from ``noise`` (N, H, A) and encoded conditions (N, C)."""
    import torch

    x = noise
    for s in range(sched.steps):
        t = torch.full((x.shape[0],), sched.times[s], device=x.device)
        out = net.denoise(x, t, obs_cond)
        x = sched.gain[s] * out + sched.keep[s] * x
    return x


def _pairs(
    sampler: Any,
    net: Any,
    windows: Any,
    indices: Any,
    per_window: int,
    generator: Any,
    batch: int = 256,
) -> dict[str, Any]:
    """(condition, noise, teacher chunk) for ``per_window`` noise draws per window."""
    import torch

    from rmi_learn.policies.checkpoint import goal_from_batch

    acc: dict[str, list[Any]] = {"hist": [], "hist_mask": [], "goal": [], "noise": [], "target": []}
    cfg = net.config
    for start in range(0, len(indices), batch):
        b = windows.batch(indices[start : start + batch])
        _, goal = goal_from_batch(b)
        # Noise outside inference mode: the student's training graph takes it as input.
        shape = (goal.shape[0] * per_window, cfg.horizon, cfg.action_dim)
        noise = torch.randn(shape, generator=generator)
        with torch.inference_mode():
            cond = net.encode_condition(b["hist"], b["hist_mask"], goal)
            target = sampler.sample_from_condition(cond, noise)
        acc["hist"].append(b["hist"].repeat_interleave(per_window, 0))
        acc["hist_mask"].append(b["hist_mask"].repeat_interleave(per_window, 0))
        acc["goal"].append(goal.repeat_interleave(per_window, 0))
        acc["noise"].append(noise)
        acc["target"].append(target.clone())
    return {k: torch.cat(v) for k, v in acc.items()}


def _subset(n: int, k: int) -> Any:
    import numpy as np

    if k <= 0 or n <= k:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def distill_policy(
    policy: str | Path,
    dataset: str | Path,
    out: str | Path,
    *,
    steps: int = 1,
    epochs: int = 20,
    batch_size: int = 64,
    lr: float = 1e-4,
    max_windows: int = 4096,
    pairs_per_window: int = 1,
    val_windows: int = 256,
    teacher_steps: int | None = None,
    weights: str = "model.ema",
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Distil the policy run ``policy`` into a ``steps``-step student written to ``out``
    (see the module docstring) and return its summary: the teacher, the step counts, the
    number of pairs, the validation distance before training and per epoch, the kept epoch.

    ``teacher_steps`` overrides the teacher's sampler steps (default: its run's, 16 DDIM or
    20 Euler); ``weights`` names the teacher's weights file. Raises
    :class:`~rmi_learn.errors.InputError` for a teacher that is not a policy run or whose
    weights do not load, a dataset it was not trained on (other statistics), a dataset
    without training or validation windows, a step count outside 1..2, or an ``out`` that
    already holds a run.
    """
    import copy

    import torch

    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.checkpoint import load_policy, make_objective, model_config
    from rmi_learn.policies.fast_sampler import FastSampler, schedule
    from rmi_learn.policies.policy import check_trained_on
    from rmi_learn.trainer import CONFIG_FILE, save_weights

    if steps not in (1, 2):
        raise InputError(f"the student samples with 1 or 2 steps, got {steps}")
    out = Path(out)
    if (out / CONFIG_FILE).exists():
        raise InputError(f"{out} already holds a run; choose another output directory")
    try:
        teacher, objective, tcfg = load_policy(policy, weights)
    except (FileNotFoundError, NotADirectoryError, KeyError, TypeError, ValueError) as exc:
        raise InputError(exc) from exc
    m = tcfg["model"]
    history = int(m["history"])
    size_cm = (tcfg.get("extra") or {}).get("size_cm")
    ds = load_dataset(dataset)
    # The teacher's chunks are only its own for inputs standardised as in its training.
    check_trained_on(policy, tcfg, ds.stats.to_json(), dataset)
    horizon = teacher.config.horizon
    train = ds.windows("train", size_cm, history=history, horizon=horizon)
    val = ds.windows("val", size_cm, history=history, horizon=horizon)
    if len(train) == 0 or len(val) == 0:
        raise InputError(f"{dataset}: need train and val windows (got {len(train)}, {len(val)})")

    gen = torch.Generator().manual_seed(seed)
    t_sampler = FastSampler(teacher, objective, teacher_steps)
    train_pairs = _pairs(t_sampler, teacher, train, _subset(len(train), max_windows),
                         pairs_per_window, gen)  # fmt: skip
    val_pairs = _pairs(t_sampler, teacher, val, _subset(len(val), val_windows), 1, gen)

    s_cfg = {**m["objective_config"], "n_sample_steps": steps}
    s_objective = make_objective(m["objective"], **s_cfg)
    sched = schedule(s_objective)
    student = copy.deepcopy(teacher).train()
    opt = torch.optim.AdamW(student.parameters(), lr=lr, weight_decay=0.0)
    out.mkdir(parents=True, exist_ok=True)
    best, history_rows, seconds = _train_student(
        student, opt, sched, train_pairs, val_pairs, epochs, batch_size, gen, progress
    )
    student.load_state_dict(best[2])
    distill = {
        "teacher": str(Path(policy).resolve()),
        "teacher_weights": weights,
        "teacher_objective": m["objective"],
        "teacher_steps": t_sampler.schedule.steps,
        "steps": steps,
        "method": "flow-pair-distillation" if m["objective"] == "flow" else "x0-pair-distillation",
        "pairs": int(train_pairs["noise"].shape[0]),
        "val_pairs": int(val_pairs["noise"].shape[0]),
        "epochs": epochs,
        "lr": lr,
        "batch_size": batch_size,
        "seed": seed,
        "val_distance_initial": history_rows[0]["val_distance"],
        "val_distance": best[0],
        "selected_epoch": best[1],
    }
    config = {
        "model": model_config(student.config, s_objective, history),
        "distill": distill,
        "extra": {
            **(tcfg.get("extra") or {}),
            "data": str(Path(dataset).resolve()),
            "stats": ds.stats.to_json(),
        },
    }
    tensors = {k: v for k, v in student.state_dict().items()}
    save_weights(tensors, out / "model.safetensors")
    save_weights(tensors, out / "model.ema.safetensors")
    _write_run_files(out, history_rows, config, CONFIG_FILE)
    return {"out": str(out), "seconds": seconds, "history": history_rows, **distill}


def _val_distance(net: Any, sched: Any, val_pairs: dict[str, Any]) -> float:
    """Mean squared distance of the student's chunks to the teacher's (validation)."""
    import torch

    net.eval()
    total, n = 0.0, 0
    with torch.no_grad():
        for start in range(0, val_pairs["noise"].shape[0], 256):
            sl = slice(start, start + 256)
            cond = net.encode_condition(val_pairs["hist"][sl], val_pairs["hist_mask"][sl],
                                        val_pairs["goal"][sl])  # fmt: skip
            x = few_step_sample(net, sched, cond, val_pairs["noise"][sl])
            total += float((x - val_pairs["target"][sl]).pow(2).sum())
            n += x.numel()
    return total / n


def _train_student(
    student: Any,
    opt: Any,
    sched: Any,
    train_pairs: dict[str, Any],
    val_pairs: dict[str, Any],
    epochs: int,
    batch_size: int,
    gen: Any,
    progress: bool,
) -> tuple[tuple[float, int, dict[str, Any]], list[dict[str, Any]], float]:
    """Train the student on the pairs for ``epochs`` epochs (batches drawn by ``gen``),
    measuring its validation distance before training and after each epoch. Returns the
    best (distance, epoch, weights), one row per epoch (epoch 0: before training) and the
    training time (s)."""
    import torch

    initial = _val_distance(student, sched, val_pairs)
    best = (initial, 0, copy.deepcopy(student.state_dict()))
    history_rows: list[dict[str, Any]] = [{"epoch": 0, "val_distance": initial}]
    n_pairs = train_pairs["noise"].shape[0]
    t0 = time.perf_counter()
    for epoch in range(1, epochs + 1):
        student.train()
        order = torch.randperm(n_pairs, generator=gen)
        losses = []
        for start in range(0, n_pairs, batch_size):
            idx = order[start : start + batch_size]
            cond = student.encode_condition(train_pairs["hist"][idx],
                                            train_pairs["hist_mask"][idx],
                                            train_pairs["goal"][idx])  # fmt: skip
            x = few_step_sample(student, sched, cond, train_pairs["noise"][idx])
            loss = (x - train_pairs["target"][idx]).pow(2).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        dist = _val_distance(student, sched, val_pairs)
        row = {"epoch": epoch, "train_loss": sum(losses) / len(losses), "val_distance": dist}
        history_rows.append(row)
        if progress:
            print(json.dumps(row), flush=True)
        if dist < best[0]:
            best = (dist, epoch, copy.deepcopy(student.state_dict()))
    return best, history_rows, time.perf_counter() - t0


def _write_run_files(
    out: Path, history_rows: list[dict[str, Any]], config: dict[str, Any], config_file: str
) -> None:
    """metrics.jsonl (one row per epoch), then the config (atomically: it marks the run
    directory complete)."""
    with (out / "metrics.jsonl").open("w", encoding="utf-8") as f:
        for row in history_rows:
            f.write(json.dumps(row) + "\n")
    tmp = out / (config_file + ".tmp")
    tmp.write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out / config_file)


__all__ = ["distill_policy", "few_step_sample"]
