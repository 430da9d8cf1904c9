"""``rmi train-policy``: train the goal-conditioned UNet policy (diffusion or flow matching).

Data: ``Dataset.windows(split, history=16, horizon=32)``; the goal of a window is
``[g, Delta M]`` with ``g`` = M_L at ``t + 32`` (standardised with the training-split M_L mean
and std) and ``Delta M = g - M_L(t)`` (divided by the same std). AdamW, lr 1e-4, batch 64, at
most 80 epochs, patience 12, EMA with warm-up. Checkpoint selection: Diffusion Policy by the
sampled action MAE on (a fixed subset of) the validation windows with EMA weights; flow
matching by the validation flow MSE with EMA weights (fixed noise and times). The live-weight
validation loss and, for diffusion, the unweighted x0 MSE per noise bucket are logged too.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from rmi_learn.commands import InputError
from rmi_learn.commands.argtypes import count, counts, non_negative, positive, real


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi train-policy``."""
    parser.add_argument("--objective", choices=("diffusion", "flow"), required=True)
    parser.add_argument("--data", required=True, type=Path, help="built dataset directory")
    parser.add_argument("--out", required=True, type=Path, help="run directory (new or --resume)")
    parser.add_argument("--size-cm", type=int, default=None, help="train on one sponge size")
    parser.add_argument("--epochs", type=count(1), default=80)
    parser.add_argument("--batch-size", type=count(1), default=64)
    parser.add_argument("--lr", type=positive, default=1e-4)
    parser.add_argument("--weight-decay", type=non_negative, default=1e-6)
    parser.add_argument("--patience", type=count(1), default=12)
    parser.add_argument("--seed", type=count(0), default=0)
    parser.add_argument("--history", type=count(1), default=16)
    parser.add_argument("--horizon", type=count(4), default=32, help="H_pi, divisible by 4")
    parser.add_argument(
        "--ema-decay", type=real(0.0, 1.0, high_open=True), default=0.999, help="EMA decay cap"
    )
    parser.add_argument(
        "--snr-floor",
        type=non_negative,
        default=0.0,
        help="floor of the min-SNR weight (diffusion)",
    )
    parser.add_argument(
        "--val-windows",
        type=count(1),
        default=1024,
        help="validation windows (evenly spaced subset) for the selection metric",
    )
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=count(1), default=None, help="torch CPU threads")
    parser.add_argument("--max-steps-per-epoch", type=count(1), default=None)
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--debug", action="store_true", help="shrink the run to seconds")
    parser.add_argument("--deterministic", action="store_true")
    parser.add_argument("--no-progress", action="store_true", help="no tqdm bars")
    parser.add_argument(
        "--channels",
        type=counts,
        default=(64, 128, 256),
        help="UNet channel widths, comma separated, multiples of 8 (default 64,128,256)",
    )


def _subset(n: int, k: int) -> Any:
    import numpy as np

    if n <= k:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def run(args: argparse.Namespace) -> int:
    """Train one policy; prints the run summary as JSON. 0 on success, 2 on a user error
    (output directory holds a run without --resume, or resume settings differ)."""
    import torch

    from rmi_learn.dataset import load_dataset
    from rmi_learn.policy.checkpoint import goal_from_batch, make_objective, model_config
    from rmi_learn.policy.diffusion import DiffusionObjective
    from rmi_learn.policy.ema import EMA
    from rmi_learn.policy.unet import PolicyUNet, UNetConfig
    from rmi_learn.training import TrainConfig, Trainer, TrainState, fetch_batch

    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        unet_cfg = UNetConfig(horizon=args.horizon, channels=args.channels)
        model = PolicyUNet(unet_cfg)
    except ValueError as exc:
        raise InputError(exc) from exc
    ds = load_dataset(args.data)
    train = ds.windows("train", args.size_cm, history=args.history, horizon=args.horizon)
    val = ds.windows("val", args.size_cm, history=args.history, horizon=args.horizon)
    if len(train) == 0 or len(val) == 0:
        raise InputError(f"need train and val windows (got {len(train)}, {len(val)})")
    kwargs: dict[str, Any] = {"snr_floor": args.snr_floor} if args.objective == "diffusion" else {}
    objective = make_objective(args.objective, **kwargs)
    ema = EMA(max_decay=args.ema_decay)
    n_val = min(args.val_windows, 64) if args.debug else args.val_windows
    val_batch = fetch_batch(val, _subset(len(val), n_val), args.device)
    water_std = float(ds.stats.z_std[0])
    f_std = float(ds.stats.u_std[0])
    seed = args.seed

    def batch_loss(
        net: torch.nn.Module, b: dict[str, Any], gen: torch.Generator | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """The objective's loss on a window batch (noise from ``gen`` when given)."""
        _, goal = goal_from_batch(b)
        return objective.loss(
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
        if isinstance(objective, DiffusionObjective):
            buckets = info["t"] // 10
            for k in range(5):
                sel = buckets == k
                if sel.any():
                    metrics[f"val_x0_mse_t{10 * k:02d}_{10 * k + 9:02d}"] = float(
                        info["mse"][sel].mean()
                    )
        with ema.applied(net) as ema_net:
            if isinstance(objective, DiffusionObjective):
                gen = torch.Generator().manual_seed(seed + 54321)
                sample = objective.sample(
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

    select = "val_action_mae" if args.objective == "diffusion" else "val_flow_mse"
    cfg = TrainConfig(
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        weight_decay=args.weight_decay,
        optimizer="adamw",
        patience=args.patience,
        select_metric=select,
        select_mode="min",
        seed=args.seed,
        deterministic=args.deterministic,
        device=args.device,
        debug=args.debug,
        max_steps_per_epoch=args.max_steps_per_epoch,
        progress=not args.no_progress,
    )
    try:
        trainer = Trainer(
            model,
            loss_fn,
            train,
            args.out,
            cfg,
            evaluate=evaluate,
            model_config=model_config(unet_cfg, objective, args.history),
            extra_config={
                "data": str(Path(args.data).resolve()),
                "size_cm": args.size_cm,
                "train_windows": len(train),
                "val_windows": len(val),
                "val_windows_scored": int(val_batch["actions"].shape[0]),
                "goal": "[g, g - M_L(t)] / std(M_L); g = M_L(t + horizon)",
                "water_std_kg": water_std,
                "weights_for_sampling": "model.ema.safetensors",
            },
            hooks=[ema],
            resume=args.resume,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    summary = trainer.fit()
    print(json.dumps(summary, indent=2))
    return 0
