"""``rmi rank``: rank K = 8 policy samples per test window with the Transformer world model
W_T and write the ranking tables and the ranked chunks (see :mod:`rmi_learn.planning.ranking`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.option_types import count, device, positive, seed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi rank``."""
    parser.add_argument("--data", required=True, type=Path, help="built dataset directory")
    parser.add_argument(
        "--wm", required=True, type=Path, help="`rmi train-wm` run of the scoring world model"
    )
    parser.add_argument(
        "--diffusion", type=Path, default=None, help="diffusion policy run (default: none)"
    )
    parser.add_argument(
        "--flow", type=Path, default=None, help="flow-matching policy run (default: none)"
    )
    parser.add_argument("--out", required=True, type=Path, help="directory for the tables")
    parser.add_argument(
        "--split", default="test", choices=("train", "val", "test"), help="windows ranked"
    )
    parser.add_argument("--k", type=count(1), default=8, help="samples per window")
    parser.add_argument(
        "--max-windows", type=count(0), default=0, help="per size, evenly spaced subset (0: all)"
    )
    parser.add_argument("--batch-size", type=count(1), default=64, help="windows per batch")
    parser.add_argument("--seed", type=seed, default=0, help="seed of the policy samples")
    parser.add_argument(
        "--force-limit",
        type=positive,
        default=FORCE_LIMIT_N,
        help="the samples' target grip forces are clipped to this (N)",
    )
    parser.add_argument("--weights", default="model.ema", help="policy weights file stem")
    parser.add_argument("--device", type=device, default="cpu", help="torch device")
    add_threads(parser, "torch")


def run(args: argparse.Namespace) -> int:
    """Rank policy samples and write the ranking tables. Returns 0 on success."""
    import torch

    from rmi_learn.planning.ranking import rank

    torch.set_num_threads(threads_of(args.threads))
    summary = rank(
        args.data,
        args.wm,
        args.out,
        diffusion=args.diffusion,
        flow=args.flow,
        split=args.split,
        k=args.k,
        max_windows=args.max_windows,
        batch_size=args.batch_size,
        seed=args.seed,
        force_limit=args.force_limit,
        weights=args.weights,
        device=args.device,
    )
    print(json.dumps(summary, indent=2))
    return 0
