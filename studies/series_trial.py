"""The resolution series' trial, shared by the study scripts that run it one at a time.

``studies/drain_depth.py`` and ``studies/pore_balance.py`` each run one scripted
grasp-lift-squeeze trial of the condition of ``studies/grids/resolution/`` (the study's
phases at the engine's default dt = 1 ms, read from its grid file) at a radius of the user's
choice. This module holds their common command-line options, builds the trial's config and
reports the result.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: The resolution series' grid, whose settings (the study's phases, the engine's dt) the trial uses.
SERIES_GRID = Path(__file__).resolve().parent / "grids" / "resolution" / "r8mm.json"


def add_condition_args(ap: argparse.ArgumentParser) -> None:
    """The trial's condition: radius (required), sponge, porosity, forces, seed, threads; and
    ``--json``, the result as JSON instead of text."""
    ap.add_argument("--radius", type=float, required=True, help="particle radius (m)")
    ap.add_argument("--size", type=int, default=8, choices=(8, 10, 12), help="sponge (cm)")
    ap.add_argument("--porosity", type=float, default=0.7)
    ap.add_argument("--hold", type=float, default=140.0, help="holding force (N)")
    ap.add_argument("--squeeze", type=float, default=150.0, help="squeeze force (N)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", action="store_true", help="print the result as JSON")


def trial_config(a: argparse.Namespace, **tables: dict[str, Any]) -> dict[str, Any]:
    """The config of ``a``'s condition with the series' overrides; ``tables`` (e.g.
    ``gripper={"gap": 0.015}``) are merged into the series' own tables of the same name."""
    import rmi_sph
    from rmi_learn.data.sweep import load_grid

    overrides = dict(load_grid(path=SERIES_GRID)["overrides"])
    for name, table in tables.items():
        overrides[name] = {**overrides.get(name, {}), **table}
    return rmi_sph.trial_config(
        a.size, a.porosity, a.hold, a.squeeze, radius=a.radius, seed=a.seed, **overrides
    )


Result = dict[str, Any]


def report(
    prog: str,
    run: Callable[[argparse.Namespace], Result],
    a: argparse.Namespace,
    show: Callable[[argparse.Namespace, Result], None],
) -> int:
    """Runs ``run(a)`` and prints its result, as JSON with ``--json`` or as ``show`` writes it
    otherwise. Exit status 0, or 2 after naming a bad condition (rmi_sph.ConfigError is a
    ValueError that names the field and its range)."""
    try:
        res = run(a)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if a.json:
        json.dump(res, sys.stdout, indent=1)
        print()
    else:
        show(a, res)
    return 0
