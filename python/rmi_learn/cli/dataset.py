"""``rmi dataset``: build the learning dataset from run files, or describe a built one.

``rmi dataset build --runs DIR --out DIR [--seed 0]`` (``rmi dataset --runs DIR --out DIR``
is the same) and ``rmi dataset info DIR``.
"""

from __future__ import annotations

import argparse
import json

from rmi_learn.cli.argtypes import seed
from rmi_learn.errors import InputError, input_errors


def _build_args(p: argparse.ArgumentParser, sub: bool) -> None:
    # On the subcommand an option that is not given must not overwrite the one given before
    # it (`rmi dataset --runs R --out D build`), so its default is "absent".
    none: object = argparse.SUPPRESS if sub else None
    p.add_argument("--runs", default=none, metavar="DIR", help="directory of run files")
    p.add_argument("--out", default=none, metavar="DIR", help="dataset directory")
    seed_default: object = argparse.SUPPRESS if sub else 0
    p.add_argument(
        "--seed",
        type=seed,
        default=seed_default,
        help="seed of the train/val/test split (default: 0)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands ``build`` and ``info``; bare options mean ``build``, and the build options
    may stand before or after ``build``."""
    _build_args(parser, sub=False)
    sub = parser.add_subparsers(dest="dataset_command", metavar="{build,info}")
    # The subcommands lay out their help as their parent does.
    b = sub.add_parser(
        "build",
        help="resample runs to 20 ms, split, standardise, cache",
        formatter_class=parser.formatter_class,
    )
    _build_args(b, sub=True)
    i = sub.add_parser(
        "info",
        help="print counts and statistics of a built dataset",
        formatter_class=parser.formatter_class,
    )
    i.add_argument("dir", metavar="DIR", help="dataset directory")
    i.add_argument("--json", action="store_true", help="print the full JSON summary")


def run(args: argparse.Namespace) -> int:
    """Run ``build`` or ``info``; 0 on success, 2 on bad input (missing or damaged runs)."""
    from rmi_learn.data.dataset import build, describe

    if getattr(args, "dataset_command", None) == "info":
        with input_errors(OSError, ValueError):
            d = describe(args.dir)
        if args.json:
            print(json.dumps(d, indent=2))
        else:
            info = d["info"]
            print(f"dataset {args.dir} (seed {info['seed']}, dt {info['dt']} s)")
            print("counts: " + ", ".join(f"{k} {v}" for k, v in info["counts"].items()))
            for key, v in d["by_split_and_size"].items():
                print(
                    f"  {key:10s} runs {v['runs']:4d}  rows {v['rows']:7d}  "
                    f"windows {v['windows']:7d}"
                )
        return 0
    if not args.runs or not args.out:
        raise InputError("give --runs DIR and --out DIR (or use `info DIR`)")
    out = build(args.runs, args.out, seed=args.seed)
    info = json.loads((out / "dataset.json").read_text())
    print(
        f"dataset -> {out}: {info['counts']['kept']} of {info['counts']['run_files']} runs, "
        + ", ".join(f"{s} {v['runs']} runs / {v['rows']} rows" for s, v in info["splits"].items())
    )
    return 0
