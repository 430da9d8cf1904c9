"""Sweep grids: a preset or a JSON file read and checked (:func:`load_grid`), and expanded
into one :class:`RunSpec` per grid point (:func:`expand_grid`).

A grid is the product sizes x porosities x holding forces x squeeze forces x seeds, with the
trial config overrides of its runs (for every run, by sponge size, and the seeded force
targets of the perturbed seeds).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rmi_learn.data.runs import json_kind, read_json_source, run_id
from rmi_learn.data.schema import FORCE_LIMIT_N, SEED_MAX, SPONGE_SIZES_CM

PRESETS: tuple[str, ...] = ("tiny", "quick", "study", "paper", "paper-fine", "control")
_GRID_KEYS = {
    "name",
    "description",
    "sizes_cm",
    "porosities",
    "hold_forces_N",
    "squeeze_forces_N",
    "seeds",
    "radius_m",
    "overrides",
    "overrides_by_size",
    "perturbation",
}


def load_grid(
    preset: str | None = None, path: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """Read and validate a grid: a preset name (``tiny``, ``quick``, ``paper``) or a JSON
    file. Keys: ``sizes_cm`` (8, 10, 12), ``porosities`` (0..1), ``hold_forces_N`` and
    ``squeeze_forces_N`` (0 < F <= 400 N), ``seeds`` (ints), ``radius_m`` (particle radius,
    m), optional ``overrides`` (passed to ``make_config`` as keyword arguments, e.g. trial
    timings), optional ``overrides_by_size`` (``{"10": {"dt": 0.0025}}``: overrides for the
    runs of one sponge size, on top of ``overrides``), optional ``perturbation``
    (``{"seeds": [...], ...}``: the runs of those seeds follow seeded force targets from the
    lift on, see :func:`perturbation_override`),
    ``name`` and ``description``."""
    grid, source = read_json_source("rmi_learn.data.grids", PRESETS, preset, path, "grid")
    return validate_grid(grid, source)


def validate_grid(grid: Mapping[str, Any], source: str = "grid") -> dict[str, Any]:
    """Check a grid dict (see :func:`load_grid`) and return a normalised copy."""
    if not isinstance(grid, Mapping):
        raise ValueError(f"{source}: a grid is a JSON object, got {json_kind(grid)}")
    unknown = set(grid) - _GRID_KEYS
    if unknown:
        raise ValueError(f"{source}: unknown keys {sorted(unknown)} (allowed {sorted(_GRID_KEYS)})")
    need = ["sizes_cm", "porosities", "hold_forces_N", "squeeze_forces_N", "seeds", "radius_m"]
    missing = [k for k in need if k not in grid]
    if missing:
        raise ValueError(f"{source}: missing keys {missing}")
    overrides = grid.get("overrides", {})
    if not isinstance(overrides, Mapping):
        raise ValueError(
            f"{source}: overrides must be an object of trial config fields, "
            f"got {json_kind(overrides)}"
        )
    g: dict[str, Any] = {
        "name": str(grid.get("name", "custom")),
        "description": str(grid.get("description", "")),
        "overrides": dict(overrides),
    }
    for key in ("sizes_cm", "porosities", "hold_forces_N", "squeeze_forces_N", "seeds"):
        vals = grid[key]
        if not isinstance(vals, list) or not vals:
            raise ValueError(f"{source}: {key} must be a non-empty list")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
            raise ValueError(f"{source}: {key} must be a list of numbers, got {vals!r:.80}")
        if len(set(vals)) != len(vals):
            raise ValueError(f"{source}: {key} has duplicates")
        g[key] = list(vals)
    sizes = ", ".join(str(s) for s in SPONGE_SIZES_CM[:-1]) + f" or {SPONGE_SIZES_CM[-1]}"
    for s in g["sizes_cm"]:
        if s not in SPONGE_SIZES_CM:
            raise ValueError(f"{source}: sizes_cm must be {sizes}, got {s!r}")
    for p in g["porosities"]:
        if not (isinstance(p, (int, float)) and 0.0 < p < 1.0):
            raise ValueError(f"{source}: porosity {p!r} outside (0, 1)")
    for key in ("hold_forces_N", "squeeze_forces_N"):
        for f in g[key]:
            if not (isinstance(f, (int, float)) and 0.0 < f <= FORCE_LIMIT_N):
                raise ValueError(f"{source}: {key} value {f!r} outside (0, {FORCE_LIMIT_N}] N")
    for s in g["seeds"]:
        if not isinstance(s, int) or not 0 <= s <= SEED_MAX:
            raise ValueError(f"{source}: seeds must be integers in [0, {SEED_MAX}], got {s!r}")
    by_size = _validate_by_size(grid.get("overrides_by_size"), g["sizes_cm"], source)
    if by_size is not None:  # absent, not null: grids of earlier sweeps compare equal
        g["overrides_by_size"] = by_size
    perturbation = _validate_perturbation(grid.get("perturbation"), g["seeds"], source)
    if perturbation is not None:  # absent, not null: grids of earlier sweeps compare equal
        g["perturbation"] = perturbation
    r = grid["radius_m"]
    if not (isinstance(r, (int, float)) and 0.0 < r < 0.05):
        raise ValueError(f"{source}: radius_m {r!r} outside (0, 0.05) m")
    g["radius_m"] = float(r)
    return g


def _validate_by_size(spec: Any, sizes: list[int], source: str) -> dict[str, dict[str, Any]] | None:
    """The grid's ``overrides_by_size`` entry: keys are sponge sizes of the grid in cm (JSON
    keys, so strings), values objects of trial config fields like ``overrides``."""
    if spec is None:
        return None
    if not isinstance(spec, Mapping):
        raise ValueError(
            f"{source}: overrides_by_size must be an object keyed by size in cm, "
            f"got {json_kind(spec)}"
        )
    out: dict[str, dict[str, Any]] = {}
    for key, value in spec.items():
        size = str(key).strip()
        if not size.isdigit() or int(size) not in sizes:
            raise ValueError(
                f"{source}: overrides_by_size key {key!r} is not one of the grid's sizes_cm {sizes}"
            )
        if not isinstance(value, Mapping):
            raise ValueError(
                f"{source}: overrides_by_size[{key!r}] must be an object of trial config "
                f"fields, got {json_kind(value)}"
            )
        out[str(int(size))] = dict(value)
    return out


def _validate_perturbation(spec: Any, seeds: list[int], source: str) -> dict[str, Any] | None:
    """The grid's ``perturbation`` entry: ``seeds`` (a subset of the grid's seeds) and the
    schedule options of ``controller.perturbation`` (checked by the engine when the configs
    are built), without ``enabled`` and ``seed``, which the sweep sets per run."""
    if spec is None:
        return None
    if not isinstance(spec, Mapping):
        raise ValueError(f"{source}: perturbation must be an object, got {json_kind(spec)}")
    which = spec.get("seeds")
    if not isinstance(which, list) or not which or not all(s in seeds for s in which):
        raise ValueError(
            f"{source}: perturbation.seeds must be a non-empty list of the grid's seeds "
            f"{seeds}, got {which!r:.80}"
        )
    fixed = {"enabled", "seed"} & set(spec)
    if fixed:
        raise ValueError(
            f"{source}: perturbation.{sorted(fixed)[0]} is set by the sweep for each run "
            "(list the perturbed seeds under perturbation.seeds)"
        )
    return {"seeds": list(which), **{k: v for k, v in spec.items() if k != "seeds"}}


def size_overrides(grid: Mapping[str, Any], size_cm: int) -> dict[str, Any]:
    """The trial config overrides of the grid's runs of one sponge size: ``overrides`` with
    that size's ``overrides_by_size`` entry on top."""
    return {**grid["overrides"], **grid.get("overrides_by_size", {}).get(str(int(size_cm)), {})}


def perturbation_override(grid: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """The ``controller.perturbation`` override of the run with ``seed`` (empty when its
    seed is not perturbed): the schedule is seeded by the run's seed, which the engine mixes
    with the run's forces, so every perturbed run follows its own schedule."""
    spec = grid.get("perturbation")
    if not spec or seed not in spec["seeds"]:
        return {}
    options = {k: v for k, v in spec.items() if k != "seeds"}
    return {"perturbation": {**options, "enabled": True, "seed": int(seed)}}


@dataclass(frozen=True)
class RunSpec:
    """One grid point: its parameters and what ``make_config`` receives."""

    params: dict[str, Any]
    radius: float
    overrides: dict[str, Any] = field(default_factory=dict)

    @property
    def run_id(self) -> str:
        return run_id(self.params)


def expand_grid(grid: Mapping[str, Any]) -> list[RunSpec]:
    """Every run of a validated grid, in a fixed order (size, porosity, hold, squeeze, seed)."""
    specs = []
    for size in grid["sizes_cm"]:
        base = size_overrides(grid, int(size))
        for por in grid["porosities"]:
            for fh in grid["hold_forces_N"]:
                for fs in grid["squeeze_forces_N"]:
                    for seed in grid["seeds"]:
                        params = {
                            "size_cm": int(size),
                            "porosity": float(por),
                            "F_hold": float(fh),
                            "F_squeeze": float(fs),
                            "seed": int(seed),
                        }
                        overrides = {**base, **perturbation_override(grid, int(seed))}
                        specs.append(RunSpec(params, grid["radius_m"], overrides))
    return specs
