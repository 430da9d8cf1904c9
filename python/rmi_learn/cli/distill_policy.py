"""``rmi distill-policy``: distil a trained policy into a 1- or 2-step student for the
real-time decision path (see :mod:`rmi_learn.policies.distill`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.option_types import count, positive, seed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi distill-policy``."""
    parser.add_argument("--policy", required=True, type=Path, help="teacher policy run")
    parser.add_argument("--dataset", required=True, type=Path, help="built dataset directory")
    parser.add_argument("--out", required=True, type=Path, help="new student run directory")
    parser.add_argument("--steps", type=int, choices=(1, 2), default=1,
                        help="student sampler steps")  # fmt: skip
    parser.add_argument("--epochs", type=count(1), default=20, help="training epochs")
    parser.add_argument("--batch-size", type=count(1), default=64, help="pairs per batch")
    parser.add_argument("--lr", type=positive, default=1e-4, help="learning rate")
    parser.add_argument("--max-windows", type=count(1), default=4096,
                        help="training windows that give (noise, teacher chunk) pairs")  # fmt: skip
    parser.add_argument("--pairs-per-window", type=count(1), default=1,
                        help="(noise, teacher chunk) pairs per training window")  # fmt: skip
    parser.add_argument("--val-windows", type=count(1), default=256,
                        help="validation windows (evenly spaced subset)")  # fmt: skip
    parser.add_argument("--teacher-steps", type=count(1), default=None,
                        help="teacher sampler steps (default: the teacher run's)")  # fmt: skip
    parser.add_argument("--weights", default="model.ema", help="teacher weights file stem")
    parser.add_argument("--seed", type=seed, default=0, help="seed of draws and initialisation")
    add_threads(parser, "torch")
    parser.add_argument("--no-progress", action="store_true", help="no per-epoch lines")


def run(args: argparse.Namespace) -> int:
    """Distil one policy; prints the summary as JSON. 0 on success, 2 on a user error."""
    import torch

    from rmi_learn.policies.distill import distill_policy

    torch.set_num_threads(threads_of(args.threads))
    summary = distill_policy(
        args.policy,
        args.dataset,
        args.out,
        steps=args.steps,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        max_windows=args.max_windows,
        pairs_per_window=args.pairs_per_window,
        val_windows=args.val_windows,
        teacher_steps=args.teacher_steps,
        weights=args.weights,
        seed=args.seed,
        progress=not args.no_progress,
    )
    print(json.dumps(summary, indent=2))
    return 0
