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
acts without the dataset (:func:`rmi_learn.policies.load_policy`); with ``wm`` it also stores
a copy of the world model that ranks its samples (``world_model/``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rmi_learn.errors import InputError


def _subset(n: int, k: int) -> Any:
    import numpy as np

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
    import torch

    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.checkpoint import goal_from_batch, make_objective, model_config
    from rmi_learn.policies.diffusion import DiffusionObjective
    from rmi_learn.policies.ema import EMA
    from rmi_learn.policies.unet import PolicyUNet, UNetConfig
    from rmi_learn.trainer import TrainConfig, Trainer, TrainState, fetch_batch

    if tensorboard:
        from rmi_learn.metrics_log import require_tensorboard

        require_tensorboard()

    try:
        unet_cfg = UNetConfig(horizon=horizon, channels=channels)
        model = PolicyUNet(unet_cfg)
    except ValueError as exc:
        raise InputError(exc) from exc
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
    val_batch = fetch_batch(val, _subset(len(val), n_val), device)
    water_std = float(ds.stats.z_std[0])
    f_std = float(ds.stats.u_std[0])

    def batch_loss(
        net: torch.nn.Module, b: dict[str, Any], gen: torch.Generator | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """The objective's loss on a window batch (noise from ``gen`` when given)."""
        _, goal = goal_from_batch(b)
        return obj.loss(
            net,  # type: ignore[arg-type]
            b["actions"],
            b["hist"],
            b["hist_mask"],
            goal,
            gen,
        )

    def loss_fn(net: torch.nn.Module, batch: dict[str, Any], state: TrainState) -> Any:
        return batch_loss(net, batch)[0]

    def evaluate(net: torch.nn.Module, state: TrainState) -> dict[str, float]:
        b = val_batch
        _, goal = goal_from_batch(b)
        metrics: dict[str, float] = {}
        live, info = batch_loss(net, b, torch.Generator().manual_seed(seed + 12345))
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
                    ema_net,  # type: ignore[arg-type]
                    b["hist"],
                    b["hist_mask"],
                    goal,
                    gen,
                )
                err = (sample - b["actions"]).abs()
                metrics["val_action_mae"] = float(err.mean())
                metrics["val_force_mae_N"] = float(err[..., 0].mean()) * f_std
            else:
                ema_loss, _ = batch_loss(ema_net, b, torch.Generator().manual_seed(seed + 12345))
                metrics["val_flow_mse"] = float(ema_loss)
        return metrics

    select = "val_action_mae" if objective == "diffusion" else "val_flow_mse"
    cfg = TrainConfig(
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        weight_decay=weight_decay,
        optimizer="adamw",
        patience=patience,
        select_metric=select,
        select_mode="min",
        seed=seed,
        deterministic=deterministic,
        device=device,
        debug=debug,
        max_steps_per_epoch=max_steps_per_epoch,
        progress=progress,
    )
    try:
        trainer = Trainer(
            model,
            loss_fn,
            train,
            out,
            cfg,
            evaluate=evaluate,
            model_config=model_config(unet_cfg, obj, history),
            extra_config={
                "data": str(Path(data).resolve()),
                "size_cm": size_cm,
                "train_windows": len(train),
                "val_windows": len(val),
                "val_windows_scored": int(val_batch["actions"].shape[0]),
                "goal": "[g, g - M_L(t)] / std(M_L); g = M_L(t + horizon)",
                "water_std_kg": water_std,
                "weights_for_sampling": "model.ema.safetensors",
                "stats": stats,
            },
            hooks=[ema],
            resume=resume,
            tensorboard=tensorboard,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    summary: dict[str, Any] = trainer.fit()
    if wm is not None:
        from rmi_learn.policies.policy import attach_world_model

        summary["world_model"] = str(attach_world_model(out, wm))
    return summary
