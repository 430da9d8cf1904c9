"""``rmi control-bench``: the goal-reaching benchmark executed in the simulator (see
:mod:`rmi_learn.control_bench`).

``rmi control-bench --protocol control --runs SWEEP_DIR --out DIR [--workers 2] [--threads 1]``
runs the benchmark under a committed protocol (feedback baselines, the sensor mode, held-out
conditions; :mod:`rmi_learn.control_bench.feedback`); the protocol fixes every other choice.

``rmi control-bench --runs SWEEP_DIR --data DATASET --wm WM_DIR --policy POLICY_DIR --out DIR
[--states-per-size 4] [--goals-per-state 2] [--setpoints 5] [--k 8] [--receding 8]
[--scorers wt,ac-gru] [--no-ensemble] [--receding-scorers wt,ensemble]
[--refine-scorers arx-32] [--refine-metrics smooth,l2] [--controllers ranked,refined,...]
[--sizes 8,10]
[--goal-kg G ...]
[--split test] [--seed 0] [--threads N]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.option_types import count, seed


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated model names, got {text!r}")
    return names


def _sizes(text: str) -> list[int]:
    try:
        return [int(n) for n in _names(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected sizes in cm such as 8,10, got {text!r}"
        ) from None


def _goal(text: str) -> float:
    # Range and NaN are checked by the library against the water present (one-line error).
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a mass in kg, got {text!r}") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi control-bench``."""
    parser.add_argument(
        "--runs", required=True, type=Path, metavar="SWEEP_DIR", help="sweep output (index.parquet)"
    )
    parser.add_argument(
        "--data", default=None, type=Path, metavar="DATASET", help="dataset built from SWEEP_DIR"
    )
    parser.add_argument(
        "--wm",
        default=None,
        type=Path,
        metavar="WM_DIR",
        help="directory of `rmi train-wm` runs (or one run): the ranking scorers",
    )
    parser.add_argument(
        "--policy",
        default=None,
        type=Path,
        metavar="POLICY_DIR",
        help="directory holding diffusion/ and/or flow/ `rmi train-policy` runs",
    )
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory")
    parser.add_argument(
        "--protocol",
        default=None,
        metavar="NAME|FILE",
        help="run under a protocol file (or a shipped one: control); --data, --wm, --policy "
        "and the model options do not apply",
    )
    parser.add_argument(
        "--workers", type=count(1), default=1, help="processes sharing the runs (--protocol only)"
    )
    parser.add_argument(
        "--replace-other",
        action="store_true",
        help="(--protocol only) move an output of another protocol in --out to "
        "DIR.<protocol>-<digest> and start over (default: refuse it)",
    )
    # (option, lowest value, default, help) of the integer options.
    counts = (
        ("--states-per-size", 1, 4, "distinct start states per size (a larger N extends a run)"),
        ("--goals-per-state", 0, 2, "goals drawn inside the reachable interval per state"),
        ("--setpoints", 2, 5, "constant setpoints from 0.8 F_hold to the force limit"),
        ("--k", 1, 8, "policy samples"),
        ("--receding", 0, 8, "re-plan every N control steps (0: no receding controller)"),
    )
    for flag, low, default, text in counts:
        parser.add_argument(flag, type=count(low), default=default, metavar="N", help=text)
    parser.add_argument(
        "--scorers",
        type=_names,
        default=None,
        metavar="A,B",
        help="world models that rank (names under WM_DIR, wt = transformer; the first is the "
        "receding controller's) (default: every one that can rank chunks)",
    )
    parser.add_argument(
        "--no-ensemble",
        action="store_true",
        help="do not rank by the ensemble of the scorers (mean forecast, spread as a penalty)",
    )
    parser.add_argument(
        "--receding-scorers",
        type=_names,
        default=(),
        metavar="A,B",
        help="scorers of the receding-horizon controller, ensemble included (default: the "
        "first scorer)",
    )
    parser.add_argument(
        "--refine-scorers",
        type=_names,
        default=(),
        metavar="A,B",
        help="scorers whose gradient refines the ranked chunk toward the goal, and drives the "
        "model-only controllers (default: the receding scorers)",
    )
    parser.add_argument(
        "--refine-metrics",
        type=_names,
        default=("smooth",),
        metavar="M,N",
        help="metrics of the refinement step: smooth (least step-to-step change) and/or l2 "
        "(least change); the first also drives the receding and model-only controllers",
    )
    parser.add_argument(
        "--controllers",
        type=_names,
        default=None,
        metavar="A,B",
        help="controller families to run: first-sample, ranked, best-of-k, refined, model, "
        "receding, receding-refined, receding-model (default: all; the setpoint sweep, "
        "recorded and constant-best always run)",
    )
    parser.add_argument(
        "--sizes",
        type=_sizes,
        default=None,
        metavar="8,10",
        help="sponge sizes (cm) to draw start states from (default: every size)",
    )
    parser.add_argument(
        "--goal-kg",
        type=_goal,
        action="append",
        default=[],
        metavar="G",
        help="an extra goal (kg) for every start state (repeatable)",
    )
    parser.add_argument(
        "--split",
        choices=("test", "val"),
        default="test",
        help="held-out runs the start states come from (val when test is empty)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of draws and sampling")
    add_threads(parser, "the engine and torch")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


#: Options of the model-based benchmark, with their defaults: a protocol run refuses them.
MODEL_OPTIONS: dict[str, object] = {
    "data": None,
    "wm": None,
    "policy": None,
    "states_per_size": 4,
    "goals_per_state": 2,
    "setpoints": 5,
    "k": 8,
    "receding": 8,
    "scorers": None,
    "no_ensemble": False,
    "receding_scorers": (),
    "refine_scorers": (),
    "refine_metrics": ("smooth",),
    "controllers": None,
    "sizes": None,
    "goal_kg": [],
    "split": "test",
    "seed": 0,
}


def _run_protocol(args: argparse.Namespace) -> int:
    from rmi_learn.control_bench.feedback import run_protocol_bench
    from rmi_learn.errors import InputError

    given = [k for k, d in MODEL_OPTIONS.items() if getattr(args, k, d) != d]
    if given:
        flag = "--" + given[0].replace("_", "-")
        raise InputError(
            f"{flag} does not apply with --protocol (the protocol fixes the benchmark)"
        )
    result = run_protocol_bench(
        args.protocol,
        args.runs,
        args.out,
        args.workers,
        threads_of(args.threads),
        log=lambda msg: print(msg, file=sys.stderr),
        replace_other=args.replace_other,
    )
    brief = {
        "out": str(args.out),
        "protocol": result["protocol"]["name"],
        "median_error_g": {
            f"{c['size_cm']}cm/{c['task']}": {
                x["controller"]: x.get("median_g") for x in c["controllers"]
            }
            for c in result["summary"]
        },
    }
    print(json.dumps(brief, indent=2))
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and write its tables; 0 on success, 2 for unusable inputs, 1 when
    another control-bench writes ``--out``."""
    if args.protocol is not None:
        return _run_protocol(args)
    from rmi_learn.errors import InputError

    if args.replace_other:
        raise InputError("--replace-other applies with --protocol only")
    for name in ("data", "wm", "policy"):
        if getattr(args, name) is None:
            raise InputError(f"--{name} is required (or give --protocol)")
    import torch

    from rmi_learn.control_bench import run_control_bench

    threads = threads_of(args.threads)
    torch.set_num_threads(threads)
    summary = run_control_bench(
        args.runs,
        args.data,
        args.wm,
        args.policy,
        args.out,
        states_per_size=args.states_per_size,
        goals_per_state=args.goals_per_state,
        setpoints=args.setpoints,
        k=args.k,
        receding=args.receding,
        scorers=args.scorers,
        ensemble=not args.no_ensemble,
        receding_scorers=args.receding_scorers,
        refine_scorers=args.refine_scorers,
        refine_metrics=args.refine_metrics,
        controllers=args.controllers,
        sizes=args.sizes,
        goal_kg=args.goal_kg,
        split=args.split,
        seed=args.seed,
        threads=threads,
        progress=not args.no_progress,
        log=lambda msg: print(msg, file=sys.stderr),
    )
    brief = {
        "out": str(args.out),
        "states": summary["states"],
        "median_error_g": {
            kind: {
                size: {c: e["median"] for c, e in s["controllers"].items()}
                for size, s in sizes.items()
            }
            for kind, sizes in summary["summary"].items()
        },
    }
    print(json.dumps(brief, indent=2))
    return 0
