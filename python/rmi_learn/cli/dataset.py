"""``rmi dataset``: build the learning dataset from run files, describe a built one, or
export it to another dataset format.

``rmi dataset build --runs DIR --out DIR [--seed 0]`` (``rmi dataset --runs DIR --out DIR``
is the same), ``rmi dataset info DIR`` and
``rmi dataset export --format lerobot --data DIR --out DIR``.
"""

from __future__ import annotations

import argparse
import json

from rmi_learn.errors import InputError, input_errors
from rmi_learn.option_types import seed


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


#: Formats ``rmi dataset export`` writes.
EXPORT_FORMATS = ("lerobot",)
#: LeRobot layouts (rmi_learn.data.export_lerobot.CODEBASE_VERSIONS), named here so that the
#: command line builds without importing the exporter.
CODEBASE_VERSIONS = ("v3.0", "v2.1")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands ``build``, ``info`` and ``export``; bare options mean ``build``, and the
    build options may stand before or after ``build``."""
    _build_args(parser, sub=False)
    sub = parser.add_subparsers(dest="dataset_command", metavar="{build,info,export}")
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
    e = sub.add_parser(
        "export",
        help="write a built dataset in another format (LeRobot v3.0 or v2.1)",
        formatter_class=parser.formatter_class,
    )
    e.add_argument(
        "--format", choices=EXPORT_FORMATS, default="lerobot", help="output format (lerobot)"
    )
    e.add_argument(
        "--codebase-version",
        choices=CODEBASE_VERSIONS,
        default=CODEBASE_VERSIONS[0],
        help="LeRobot layout: v3.0 (current LeRobot) or v2.1 (one file per episode)",
    )
    e.add_argument("--data", required=True, metavar="DIR", help="built dataset directory")
    # Default "absent", so that `rmi dataset --out O export --data D` keeps O.
    e.add_argument(
        "--out", default=argparse.SUPPRESS, metavar="DIR", help="new or empty output directory"
    )


def run(args: argparse.Namespace) -> int:
    """Run ``build`` or ``info``; 0 on success, 2 on bad input (missing or damaged runs)."""
    from rmi_learn.data.dataset import build, describe

    if getattr(args, "dataset_command", None) == "export":
        return _export(args)
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


def _export(args: argparse.Namespace) -> int:
    """``rmi dataset export``: one summary line on success."""
    from rmi_learn.data.export_lerobot import export_lerobot

    if not args.out:
        raise InputError("give --out DIR, a new or empty directory for the export")
    out = export_lerobot(args.data, args.out, args.codebase_version)
    info = json.loads((out / "meta" / "info.json").read_text())
    print(
        f"{args.format} {info['codebase_version']} dataset -> {out}: "
        f"{info['total_episodes']} episodes, "
        f"{info['total_frames']} frames at {info['fps']} fps ("
        + ", ".join(f"{k} {v}" for k, v in info["splits"].items())
        + ")"
    )
    return 0
