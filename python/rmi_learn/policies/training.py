"""Training of the goal-conditioned UNet policy, diffusion or flow matching:
:func:`train_policy` (``rmi train-policy``).

Data: ``Dataset.windows(split, history=16, horizon=32)``; the goal of a window is
``[g, Delta M]`` with ``g`` = M_L at ``t + 32`` (standardised with the training-split M_L mean
and std) and ``Delta M = g - M_L(t)`` (divided by the same std). AdamW, lr 1e-4, batch 64, at
most 80 epochs, patience 12, EMA with warm-up. Checkpoint selection: Diffusion Policy by the
sampled action MAE on (a fixed subset of) the validation windows with EMA weights; flow
matching by the validation flow MSE with EMA weights (fixed noise and times). The live-weight
validation loss and, for diffusion, the unweighted x0 MSE per noise bucket are logged too.

The run stores the dataset's standardisation statistics (``config["extra"]["stats"]``), so it
acts without the dataset (:func:`rmi_learn.planning.load_policy`); with ``wm`` it also stores
a copy of the world model that ranks its samples (``world_model/``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.errors import InputError
from rmi_learn.metrics_log import require_tensorboard

# torch and the modules built on it are imported inside the functions: the pipeline imports
# this module to describe its training stages on an install without torch.


def _validation_subset(n: int, k: int) -> Any:
    """Indices of at most ``k`` evenly spaced windows out of ``n``."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def train_policy(
    objective: str,
    data: str | Path,
    out: str | Path,
    *,
    size_cm: int | None = None,
    epochs: int = 80,
    batch_size: int = 64,
    lr: float = 1e-4,
    weight_decay: float = 1e-6,
    patience: int = 12,
    seed: int = 0,
    history: int = 16,
    horizon: int = 32,
    ema_decay: float = 0.999,
    snr_floor: float = 0.0,
    val_windows: int = 1024,
    device: str = "cpu",
    max_steps_per_epoch: int | None = None,
    resume: bool = False,
    debug: bool = False,
    deterministic: bool = False,
    progress: bool = True,
    channels: tuple[int, ...] = (64, 128, 256),
    tensorboard: bool = False,
    wm: str | Path | None = None,
) -> dict[str, Any]:
    """Train one policy (``objective`` ``"diffusion"`` or ``"flow"``) on the dataset ``data``
    into the run directory ``out`` and return the run summary (see the module docstring).

    ``history`` and ``horizon`` are the window lengths (control steps; the horizon H_pi must
    be divisible by 4), ``channels`` the UNet widths, ``ema_decay`` the cap of the EMA decay,
    ``snr_floor`` the floor of the min-SNR weight (diffusion), ``val_windows`` the size of
    the evenly spaced validation subset that selects the checkpoint. Every epoch's training
    and validation losses and selection metrics go to ``metrics.jsonl``; ``tensorboard``
    also writes them as TensorBoard events (needs ``tensorboard``). ``wm`` names a
    world-model run to copy into the run's ``world_model/`` once training ends (checked
    against the dataset's statistics and the horizon before training starts). Raises
    :class:`~rmi_learn.errors.InputError` for a UNet shape it cannot build, a dataset without
    training or validation windows, a world model that does not fit, or an output directory
    that holds a run without ``resume`` (or with other settings).
    """
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.checkpoint import make_objective, model_config
    from rmi_learn.policies.ema import EMA
    from rmi_learn.trainer import fetch_batch, seed_everything

    if tensorboard:
        require_tensorboard()
    # The UNet's initial weights come from torch's global generator, which torch seeds at
    # random in every process: seeded here, the same seed gives the same policy.
    seed_everything(seed, deterministic)
    unet_cfg, model = _build_unet(horizon, channels)
    ds = load_dataset(data)
    train = ds.windows("train", size_cm, history=history, horizon=horizon)
    val = ds.windows("val", size_cm, history=history, horizon=horizon)
    if len(train) == 0 or len(val) == 0:
        raise InputError(f"need train and val windows (got {len(train)}, {len(val)})")
    stats = ds.stats.to_json()
    if wm is not None:
        from rmi_learn.policies.policy import check_world_model

        check_world_model(wm, stats, horizon)
    kwargs: dict[str, Any] = {"snr_floor": snr_floor} if objective == "diffusion" else {}
    obj = make_objective(objective, **kwargs)
    ema = EMA(max_decay=ema_decay)
    n_val = min(val_windows, 64) if debug else val_windows
    val_batch = fetch_batch(val, _validation_subset(len(val), n_val), device)
    f_std = float(ds.stats.u_std[0])
    select = "val_action_mae" if objective == "diffusion" else "val_flow_mse"
    cfg = _train_config(
        select,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        weight_decay=weight_decay,
        patience=patience,
        seed=seed,
        deterministic=deterministic,
        device=device,
        debug=debug,
        max_steps_per_epoch=max_steps_per_epoch,
        progress=progress,
    )
    extra = {
        "data": str(Path(data).resolve()),
        "size_cm": size_cm,
        "train_windows": len(train),
        "val_windows": len(val),
        "val_windows_scored": int(val_batch["actions"].shape[0]),
        "goal": "[g, g - M_L(t)] / std(M_L); g = M_L(t + horizon)",
        "water_std_kg": float(ds.stats.z_std[0]),
        "weights_for_sampling": "model.ema.safetensors",
        "stats": stats,
    }
    summary = _fit(
        model,
        obj,
        train,
        out,
        cfg,
        _evaluator(obj, ema, val_batch, seed, f_std),
        model_config(unet_cfg, obj, history),
        extra,
        ema,
        resume,
        tensorboard,
    )
    if wm is not None:
        from rmi_learn.policies.policy import attach_world_model

        summary["world_model"] = str(attach_world_model(out, wm))
    return summary


def _build_unet(horizon: int, channels: tuple[int, ...]) -> tuple[Any, Any]:
    """The UNet's configuration and the untrained network; InputError for a shape it cannot
    build."""
    from rmi_learn.policies.unet import PolicyUNet, UNetConfig

    try:
        unet_cfg = UNetConfig(horizon=horizon, channels=channels)
        model = PolicyUNet(unet_cfg)
    except ValueError as exc:
        raise InputError(exc) from exc
    return unet_cfg, model


def _batch_loss(
    obj: Any, net: Any, b: dict[str, Any], gen: Any = None
) -> tuple[Any, dict[str, Any]]:
    """The objective's loss on a window batch (noise from ``gen`` when given)."""
    from rmi_learn.policies.checkpoint import goal_from_batch

    _, goal = goal_from_batch(b)
    return obj.loss(
        net,
        b["actions"],
        b["hist"],
        b["hist_mask"],
        goal,
        gen,
    )


def _evaluator(obj: Any, ema: Any, val_batch: dict[str, Any], seed: int, f_std: float) -> Any:
    """The per-epoch validation on ``val_batch`` with fixed noise: the live weights' loss
    (for diffusion, also the x0 MSE per noise bucket) and the selection metric of the EMA
    weights (diffusion: sampled action MAE; flow: flow MSE)."""
    import torch

    from rmi_learn.policies.checkpoint import goal_from_batch
    from rmi_learn.policies.diffusion import DiffusionObjective

    def evaluate(net: torch.nn.Module, state: Any) -> dict[str, float]:
        b = val_batch
        _, goal = goal_from_batch(b)
        metrics: dict[str, float] = {}
        live, info = _batch_loss(obj, net, b, torch.Generator().manual_seed(seed + 12345))
        metrics["val_loss"] = float(live)
        if isinstance(obj, DiffusionObjective):
            buckets = info["t"] // 10
            for k in range(5):
                sel = buckets == k
                if sel.any():
                    metrics[f"val_x0_mse_t{10 * k:02d}_{10 * k + 9:02d}"] = float(
                        info["mse"][sel].mean()
                    )
        with ema.applied(net) as ema_net:
            if isinstance(obj, DiffusionObjective):
                gen = torch.Generator().manual_seed(seed + 54321)
                sample = obj.sample(
                    ema_net,
                    b["hist"],
                    b["hist_mask"],
                    goal,
                    gen,
                )
                err = (sample - b["actions"]).abs()
                metrics["val_action_mae"] = float(err.mean())
                metrics["val_force_mae_N"] = float(err[..., 0].mean()) * f_std
            else:
                ema_loss, _ = _batch_loss(
                    obj, ema_net, b, torch.Generator().manual_seed(seed + 12345)
                )
                metrics["val_flow_mse"] = float(ema_loss)
        return metrics

    return evaluate


def _train_config(select: str, **settings: Any) -> Any:
    """AdamW settings selecting the checkpoint by the smallest ``select``."""
    from rmi_learn.trainer import TrainConfig

    return TrainConfig(optimizer="adamw", select_metric=select, select_mode="min", **settings)


def _fit(
    model: Any,
    obj: Any,
    train: Any,
    out: str | Path,
    cfg: Any,
    evaluate: Any,
    model_cfg: dict[str, Any],
    extra: dict[str, Any],
    ema: Any,
    resume: bool,
    tensorboard: bool,
) -> dict[str, Any]:
    """Train with the shared loop and the EMA hook; InputError for an output directory the
    loop refuses."""
    from rmi_learn.trainer import Trainer

    def loss_fn(net: Any, batch: dict[str, Any], state: Any) -> Any:
        return _batch_loss(obj, net, batch)[0]

    try:
        trainer = Trainer(
            model,
            loss_fn,
            train,
            out,
            cfg,
            evaluate=evaluate,
            model_config=model_cfg,
            extra_config=extra,
            hooks=[ema],
            resume=resume,
            tensorboard=tensorboard,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    summary: dict[str, Any] = trainer.fit()
    return summary
