"""``rmi eval-wm``: evaluate trained world models on the test split and write the paper's
Table II (causal prediction, with the shuffled-action row and W_T), Table III-diagnostic
(Linear-ARX and AC-MLP-WM with and without shuffled chunks) and Table IV (state-group
ablation) as Markdown and JSON, at 0.64 s and also 0.16/0.32/1.28 s, per sponge size.

    rmi eval-wm --runs RUN [RUN ...] --data DATASET --out DIR [--split test]

Each run is evaluated on the sizes it was trained on (its ``--size``, or every size). A run
trained with ``--shuffle-actions`` is evaluated with shuffled test chunks as well. The
Baseline needs no run: it is always evaluated. Errors are in physical units (g, N). Runs
of one model that differ only in ``--seed`` fill one cell with the mean of their errors;
the tables then list each run's 0.64 s water error below them. See
:mod:`rmi_learn.world_models.evaluation`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.option_types import count, device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi eval-wm``."""
    parser.add_argument(
        "--runs",
        nargs="+",
        required=True,
        metavar="DIR",
        help="run directories written by `rmi train-wm`",
    )
    parser.add_argument("--data", required=True, metavar="DIR", help="built dataset directory")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for the tables")
    parser.add_argument(
        "--split", default="test", choices=("train", "val", "test"), help="windows evaluated"
    )
    parser.add_argument("--batch-size", type=count(1), default=256, help="windows per batch")
    parser.add_argument(
        "--max-windows",
        type=count(1),
        default=None,
        help="evaluate at most this many evenly spaced windows per size (default: all)",
    )
    add_threads(parser, "torch")
    parser.add_argument("--device", type=device, default="cpu", help="torch device")
    parser.add_argument(
        "--no-latency", action="store_true", help="skip the 8 chunks x 32 steps latency benchmark"
    )


def run(args: argparse.Namespace) -> int:
    """Evaluate and write the tables; 0 on success, 2 on a user error."""
    import torch

    from rmi_learn.world_models.evaluation import eval_wm

    torch.set_num_threads(threads_of(args.threads))
    paths = eval_wm(
        args.runs,
        args.data,
        args.out,
        split=args.split,
        batch_size=args.batch_size,
        max_windows=args.max_windows,
        device=args.device,
        latency=not args.no_latency,
    )
    print((Path(args.out) / "table2.md").read_text(encoding="utf-8").split("## Horizon")[1])
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0
