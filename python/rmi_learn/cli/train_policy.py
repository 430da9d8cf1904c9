"""``rmi train-policy``: train the goal-conditioned UNet policy (diffusion or flow matching)
on a built dataset (see :mod:`rmi_learn.policies.training`).

``--config FILE`` holds any of the options as JSON (see :mod:`rmi_learn.cli.options_file`);
options on the command line override it. ``--tensorboard`` also writes TensorBoard events.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rmi_learn.cli.options_file import add_config_option
from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.cli.train_wm import add_tensorboard_option
from rmi_learn.option_types import count, counts, device, non_negative, positive, real, seed

#: ``--config FILE`` holds this command's options (see :mod:`rmi_learn.cli.options_file`).
OPTIONS_FILE = True


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi train-policy``."""
    parser.add_argument(
        "--objective",
        choices=("diffusion", "flow"),
        required=True,
        help="denoising diffusion or flow matching",
    )
    parser.add_argument("--data", required=True, type=Path, help="built dataset directory")
    parser.add_argument("--out", required=True, type=Path, help="run directory (new or --resume)")
    parser.add_argument(
        "--size-cm", type=int, default=None, help="train on one sponge size (default: all sizes)"
    )
    parser.add_argument("--epochs", type=count(1), default=80, help="maximum epochs")
    parser.add_argument("--batch-size", type=count(1), default=64, help="windows per batch")
    parser.add_argument("--lr", type=positive, default=1e-4, help="learning rate")
    parser.add_argument(
        "--weight-decay", type=non_negative, default=1e-6, help="AdamW weight decay"
    )
    parser.add_argument(
        "--patience", type=count(1), default=12, help="early-stopping patience (epochs)"
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of initialisation and draws")
    parser.add_argument(
        "--history", type=count(1), default=16, help="observed control steps before a chunk"
    )
    parser.add_argument(
        "--horizon",
        type=count(4),
        default=32,
        help="control steps of one action chunk, divisible by 4",
    )
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
    parser.add_argument("--device", type=device, default="cpu", help="torch device")
    add_threads(parser, "torch")
    parser.add_argument(
        "--max-steps-per-epoch",
        type=count(1),
        default=None,
        help="cap the optimiser steps per epoch (default: every window once)",
    )
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument("--debug", action="store_true", help="shrink the run to seconds")
    parser.add_argument(
        "--deterministic", action="store_true", help="use torch's deterministic algorithms only"
    )
    parser.add_argument("--no-progress", action="store_true", help="no tqdm bars")
    parser.add_argument(
        "--channels",
        type=counts,
        default=(64, 128, 256),
        help="UNet channel widths, comma separated, multiples of 8",
    )
    add_tensorboard_option(parser)
    add_config_option(parser)
    parser.add_argument(
        "--wm",
        type=Path,
        default=None,
        help="world-model run to store in the run (world_model/) for ranking",
    )


def run(args: argparse.Namespace) -> int:
    """Train one policy; prints the run summary as JSON. 0 on success, 2 on a user error
    (output directory holds a run without --resume, resume settings differ, or the --wm
    world model does not fit the dataset or the horizon)."""
    import torch

    from rmi_learn.policies.training import train_policy

    torch.set_num_threads(threads_of(args.threads))
    summary = train_policy(
        args.objective,
        args.data,
        args.out,
        size_cm=args.size_cm,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        weight_decay=args.weight_decay,
        patience=args.patience,
        seed=args.seed,
        history=args.history,
        horizon=args.horizon,
        ema_decay=args.ema_decay,
        snr_floor=args.snr_floor,
        val_windows=args.val_windows,
        device=args.device,
        max_steps_per_epoch=args.max_steps_per_epoch,
        resume=args.resume,
        debug=args.debug,
        deterministic=args.deterministic,
        progress=not args.no_progress,
        channels=args.channels,
        tensorboard=args.tensorboard,
        wm=args.wm,
    )
    print(json.dumps(summary, indent=2))
    return 0
