"""Resumable parameter sweeps: a grid of trials, one run file each, local or Ray workers.

A grid (a JSON preset in ``rmi_learn/data/grids/`` or a user file, see :func:`load_grid`) is the
product sizes x porosities x holding forces x squeeze forces x seeds. Each grid point is one
run. Its output lives in a hive-style directory under ``OUT/runs`` (see
:func:`rmi_learn.data.runs.run_path`)::

    OUT/grid.json                      the grid of the first sweep into OUT
    OUT/index.parquet                  one row per run, rebuilt from the run directories
    OUT/runs/size_cm=10/porosity=0.6/F_hold=110/F_squeeze=200/seed=0/run.parquet
    OUT/runs/.../error.json            instead of run.parquet when the run raised

Every run is idempotent: a run whose ``run.parquet`` exists is skipped; a run with an
``error.json`` is skipped too unless ``retry_failed`` (deterministic failures are not
recomputed on every resume). Files are written under a temporary name and renamed
atomically, so a sweep killed at any moment (even ``kill -9``) resumes with every finished
run kept and no partial file. A runner exception is recorded in ``error.json`` with status
``unstable`` (the engine's ``SimulationUnstableError``) or ``failed`` (anything else) and the
sweep goes on. ``index.parquet`` is derived from the run directories only
(:func:`build_index`), so it can never disagree with them.

The runner is injectable: ``runner(config: dict, *, num_threads: int) -> {"columns",
"outcome"}`` and ``make_config(size_cm, porosity, hold_force, squeeze_force, radius, seed,
**overrides) -> dict``; the defaults are ``rmi_sph.run_trial`` and ``rmi_sph.trial_config``.
They must be picklable (module-level functions), or ``"module:function"`` strings, because
local workers are spawned processes (fork and the engine's rayon pools do not mix). With the
default runner, the runs that differ only in their squeeze force are one job each, run from
one shared prefix (:func:`prefix_groups`, :func:`compute_group`); an injected runner runs
every trial alone.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import importlib
import json
import math
import multiprocessing
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn.data.runs import (
    ERROR_FILE,
    PARAM_KEYS,
    RUN_FILE,
    TMP_SUFFIX,
    RunFileError,
    atomic_write_bytes,
    atomic_write_json,
    json_kind,
    read_json_source,
    read_run_meta,
    run_file_bytes,
    run_id,
    run_path,
    write_error,
)
from rmi_learn.data.schema import FORCE_LIMIT_N, PHASES, SEED_MAX, SPONGE_SIZES_CM, size_cm
from rmi_learn.errors import InputError, StageFailure

PRESETS: tuple[str, ...] = ("tiny", "quick", "study", "paper", "paper-fine", "control")
RUNS_SUBDIR = "runs"
INDEX_FILE = "index.parquet"
GRID_FILE = "grid.json"
LOCK_FILE = ".sweep.lock"
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

Runner = Callable[..., Mapping[str, Any]]
ConfigMaker = Callable[..., dict[str, Any]]


# --------------------------------------------------------------------------------------
# Grids


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


# --------------------------------------------------------------------------------------
# Executing one run (in a worker process)


def _resolve(ref: Any, default: str) -> Callable[..., Any]:
    ref = default if ref is None else ref
    if callable(ref):
        return ref  # type: ignore[no-any-return]
    module, _, attr = str(ref).partition(":")
    try:
        obj = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise RuntimeError(
            f"cannot load {ref!r}: {exc}"
            + (
                " (this build of rmi_sph has no trial runner yet; pass runner=/make_config=)"
                if module == "rmi_sph"
                else ""
            )
        ) from exc
    return obj  # type: ignore[no-any-return]


def is_done(run_dir: Path, retry_failed: bool = False) -> bool:
    """Whether the run in ``run_dir`` needs no work: its run file exists, or it failed and
    failures are not retried."""
    if (run_dir / RUN_FILE).exists():
        return True
    return (not retry_failed) and (run_dir / ERROR_FILE).exists()


def _config_of(spec: RunSpec, make_config: Any) -> dict[str, Any]:
    """The trial config the engine builds for ``spec`` (``make_config`` or
    ``rmi_sph.trial_config``)."""
    make = _resolve(make_config, "rmi_sph:trial_config")
    p = spec.params
    config: dict[str, Any] = make(
        p["size_cm"],
        p["porosity"],
        p["F_hold"],
        p["F_squeeze"],
        spec.radius,
        p["seed"],
        **spec.overrides,
    )
    return config


def _configs_of(specs: list[RunSpec], make_config: Any) -> dict[str, dict[str, Any]]:
    """Every run's trial config by run id, built before anything is written: an override or
    value the engine refuses would otherwise fail each run of the grid one by one, recorded
    as failed. Raises ``ValueError`` naming the first such run and the engine's message."""
    import rmi_sph

    configs: dict[str, dict[str, Any]] = {}
    for spec in specs:
        try:
            configs[spec.run_id] = _config_of(spec, make_config)
        except rmi_sph.ConfigError as exc:
            raise ValueError(f"run {spec.run_id}: {exc} (no run was started)") from exc
    return configs


#: Trial config fields added after runs were first stored, whose default reproduces what
#: those runs did (``controller.perturbation`` and ``pressure.single_solve`` are off by
#: default): a stored config without them is compared as if it held the default.
_LATER_FIELDS: tuple[str, ...] = ("controller.perturbation", "pressure.single_solve")


def _get_path(config: Mapping[str, Any], dotted: str) -> Any:
    value: Any = config
    for key in dotted.split("."):
        value = value[key]
    return value


def _set_if_absent(config: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A copy of ``config`` with ``value`` at ``dotted`` when the parent exists and the key
    does not."""
    *parents, last = dotted.split(".")
    out: dict[str, Any] = json.loads(json.dumps(config))
    node: Any = out
    for key in parents:
        if not isinstance(node, dict) or key not in node:
            return out
        node = node[key]
    if isinstance(node, dict) and last not in node:
        node[last] = json.loads(json.dumps(value))
    return out


def with_later_fields(stored: dict[str, Any], default: Mapping[str, Any]) -> dict[str, Any]:
    """``stored`` (a run's saved trial config) with each field of ``_LATER_FIELDS`` that it
    lacks set to its value in ``default`` (the engine's default trial config)."""
    for field_path in _LATER_FIELDS:
        stored = _set_if_absent(stored, field_path, _get_path(default, field_path))
    return stored


def _differences(old: Any, new: Any, path: str = "") -> list[str]:
    """Dotted paths where two JSON values differ, with both values."""
    if isinstance(old, dict) and isinstance(new, dict):
        out: list[str] = []
        for k in sorted(set(old) | set(new)):
            sub = f"{path}.{k}" if path else str(k)
            if k not in old or k not in new:
                was = repr(old[k]) if k in old else "<absent>"
                now = repr(new[k]) if k in new else "<absent>"
                out.append(f"{sub}: {was} -> {now}")
            else:
                out.extend(_differences(old[k], new[k], sub))
        return out
    return [] if old == new else [f"{path}: {old!r} -> {new!r}"]


def check_stale(
    specs: Iterable[RunSpec], runs_root: Path, configs: Mapping[str, dict[str, Any]]
) -> None:
    """Refuse to resume over finished runs that the current engine would configure
    differently (a changed default, say): their data would silently mix two physics.
    ``configs``: the config the engine builds now, by run id.

    Raises ``ValueError`` naming the number of stale runs, one of them and the fields that
    differ; the caller removes them or sweeps into a new directory.
    """
    import rmi_sph

    stale: list[tuple[str, list[str]]] = []
    default = rmi_sph.default_config()
    for spec in specs:
        path = run_path(runs_root, spec.params)
        if not path.exists():
            continue
        stored = with_later_fields(read_run_meta(path)["config"], default)
        diff = _differences(stored, json.loads(json.dumps(configs[spec.run_id])))
        if diff:
            stale.append((spec.run_id, diff))
    if stale:
        run_id, diff = stale[0]
        raise ValueError(
            f"{len(stale)} finished run(s) under {runs_root} were made with another trial config "
            f"than this engine builds now, e.g. {run_id}: "
            + "; ".join(diff[:4])
            + f". Sweep into a new --out directory, or delete {runs_root} to recompute them."
        )


def _status_of_exception(exc: BaseException) -> str:
    names = {c.__name__ for c in type(exc).__mro__}
    return "unstable" if "SimulationUnstableError" in names else "failed"


def compute_run(
    spec: RunSpec, config: dict[str, Any], runner: Any = None, threads_per_run: int = 1
) -> dict[str, Any]:
    """Run one grid point and return its result without writing anything: ``{"run_id",
    "status", "wall_s", "error", "data", "record"}`` with status ``ok`` (``data``: the run
    file's bytes, :func:`rmi_learn.data.runs.run_file_bytes`), or ``failed`` / ``unstable``
    (``record``: the body of its ``error.json``). Never raises for a failing runner.
    :func:`store_run` writes the result where the sweep's output lives, which for a Ray
    worker is another machine's disk."""
    t0 = time.perf_counter()
    try:
        run = _resolve(runner, "rmi_sph:run_trial")
        result = run(config, num_threads=threads_per_run)
        return _packaged(spec, config, result, time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - recorded, the sweep goes on
        return _failure(spec, config, exc, time.perf_counter() - t0)


def _packaged(
    spec: RunSpec, config: dict[str, Any], result: Mapping[str, Any], wall: float
) -> dict[str, Any]:
    """A runner's result as :func:`compute_run` returns it; ``wall`` (s) is the runner's time
    as this worker saw it. Raises what :func:`run_file_bytes` raises."""
    outcome = dict(result["outcome"])
    outcome.setdefault("wall_s", wall)  # the engine's own figure wins when given
    outcome["sweep_wall_s"] = wall
    data = run_file_bytes(result["columns"], config, spec.params, outcome)
    return {
        "run_id": spec.run_id,
        "status": "ok",
        "wall_s": wall,
        "error": None,
        "data": data,
        "record": None,
    }


def _failure(spec: RunSpec, config: dict[str, Any], exc: Exception, wall: float) -> dict[str, Any]:
    """The :func:`compute_run` result of a run that raised ``exc`` (call it in the handler)."""
    status = "failed" if isinstance(exc, RunFileError) else _status_of_exception(exc)
    error = f"{type(exc).__name__}: {exc}"
    record = {
        "status": status,
        "error": error,
        "traceback": traceback.format_exc(),
        "wall_s": wall,
        "config": config,
    }
    return {
        "run_id": spec.run_id,
        "status": status,
        "wall_s": wall,
        "error": error,
        "data": None,
        "record": record,
    }


def prefix_groups(
    specs: list[RunSpec], configs: Mapping[str, dict[str, Any]], runner: Any = None
) -> list[list[RunSpec]]:
    """``specs`` grouped by the trial they share up to the squeeze: the same config but for
    ``squeeze_force`` (grid order kept within and between groups). Nothing before the
    squeeze depends on the squeeze force, so the engine runs such a group from one shared
    prefix (:func:`compute_group`). Runs with perturbed force targets (which depend on the
    squeeze force) and runs of an injected ``runner`` stay alone."""
    if runner is not None:
        return [[s] for s in specs]
    groups: dict[str, list[RunSpec]] = {}
    for s in specs:
        config = configs[s.run_id]
        shared = json.dumps({**config, "squeeze_force": None}, sort_keys=True)
        key = s.run_id if is_perturbed(config) else shared
        groups.setdefault(key, []).append(s)
    return list(groups.values())


def compute_group(
    specs: list[RunSpec],
    configs: list[dict[str, Any]],
    runner: Any = None,
    threads_per_run: int = 1,
) -> list[dict[str, Any]]:
    """:func:`compute_run` for each run of a :func:`prefix_groups` group, in its order. Two or
    more runs go through ``rmi_sph.run_squeeze_group`` (each result has the bits of its own
    trial; its ``wall_s`` is the shared prefix's time split evenly plus its own squeeze, and
    ``sweep_wall_s`` the group's wall time split evenly). If the group raises (a member's
    trial failed), each run is computed on its own, so that every failure is recorded as it
    happens when run alone."""
    if len(specs) == 1 or runner is not None:
        return [
            compute_run(s, c, runner, threads_per_run) for s, c in zip(specs, configs, strict=True)
        ]
    import rmi_sph

    t0 = time.perf_counter()
    try:
        forces = [float(c["squeeze_force"]) for c in configs]
        results = rmi_sph.run_squeeze_group(configs[0], forces, num_threads=threads_per_run)
    except Exception as exc:  # noqa: BLE001 - each member is rerun and its own error recorded
        print(
            f"sweep: the group of {specs[0].run_id} raised ({type(exc).__name__}: {exc}); "
            "running its runs one by one",
            file=sys.stderr,
        )
        return [
            compute_run(s, c, runner, threads_per_run) for s, c in zip(specs, configs, strict=True)
        ]
    wall = (time.perf_counter() - t0) / len(specs)
    out = []
    for spec, config, result in zip(specs, configs, results, strict=True):
        try:
            out.append(_packaged(spec, config, result, wall))
        except Exception as exc:  # noqa: BLE001 - recorded, the sweep goes on
            out.append(_failure(spec, config, exc, wall))
    return out


def store_run(result: Mapping[str, Any], spec: RunSpec, runs_root: str | Path) -> dict[str, Any]:
    """Write a :func:`compute_run` result under ``runs_root`` atomically (the run file, or
    ``error.json``) and return it without the bytes: ``{"run_id", "status", "wall_s",
    "error"}``. Raises ``OSError`` if the output directory cannot be written."""
    path = run_path(runs_root, spec.params)
    if result["data"] is not None:
        data = result["data"]
        atomic_write_bytes(path, lambda f: f.write(data))
        (path.parent / ERROR_FILE).unlink(missing_ok=True)  # a retried run that now succeeded
    else:
        write_error(path.parent, spec.params, result["record"])
    return {k: result[k] for k in ("run_id", "status", "wall_s", "error")}


def execute_run(
    spec: RunSpec,
    config: dict[str, Any],
    runs_root: str,
    runner: Any = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
) -> dict[str, Any]:
    """Run one grid point unless it is done, and store its run file or error record
    (:func:`compute_run`, then :func:`store_run`). ``config`` is the trial config
    :func:`run_sweep` built (and the engine checked) for ``spec`` before the sweep started;
    the runner gets it as it is.

    Returns ``{"run_id", "status", "wall_s", "error"}`` with status ``ok``, ``failed``,
    ``unstable`` or ``skipped``. Never raises for a failing runner; raises only if the
    output directory cannot be written.
    """
    if is_done(run_path(runs_root, spec.params).parent, retry_failed):
        return {"run_id": spec.run_id, "status": "skipped", "wall_s": 0.0, "error": None}
    return store_run(compute_run(spec, config, runner, threads_per_run), spec, runs_root)


def execute_group(
    specs: list[RunSpec],
    configs: list[dict[str, Any]],
    runs_root: str,
    runner: Any = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
) -> list[dict[str, Any]]:
    """:func:`execute_run` for a :func:`prefix_groups` group: the runs not yet done are
    computed together (:func:`compute_group`) and stored one by one."""
    todo: list[tuple[RunSpec, dict[str, Any]]] = []
    done: list[dict[str, Any]] = []
    for s, c in zip(specs, configs, strict=True):
        if is_done(run_path(runs_root, s.params).parent, retry_failed):
            done.append({"run_id": s.run_id, "status": "skipped", "wall_s": 0.0, "error": None})
        else:
            todo.append((s, c))
    if not todo:
        return done
    results = compute_group([s for s, _ in todo], [c for _, c in todo], runner, threads_per_run)
    return done + [store_run(r, s, runs_root) for r, (s, _) in zip(results, todo, strict=True)]


# --------------------------------------------------------------------------------------
# Index


def _outcome_row(meta: Mapping[str, Any]) -> dict[str, Any]:
    o = dict(meta.get("outcome", {}))
    row: dict[str, Any] = {
        "lift_success": o.pop("lift_success", None),
        "stable_squeeze": o.pop("stable_squeeze", None),
        "failure": o.pop("failure", None),
        "initial_water": o.pop("initial_water", None),
        "final_water": o.pop("final_water", None),
        "wall_s": o.pop("wall_s", None),
    }
    removed = o.pop("water_removed", None) or {}
    for ph in PHASES:
        row[f"water_removed_{ph}"] = removed.get(ph)
    # Any further scalar the engine reports (particle counts, steps, ...), flattened one level.
    for k, v in o.items():
        if isinstance(v, Mapping):
            for k2, v2 in v.items():
                if isinstance(v2, (bool, int, float, str)) or v2 is None:
                    row[f"{k}_{k2}"] = v2
        elif isinstance(v, (bool, int, float, str)) or v is None:
            row[k] = v
    return row


#: The columns every index has, in order, with their types (engine extras follow them).
INDEX_SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "status": pl.String,
    "error": pl.String,
    "path": pl.String,
    "size_cm": pl.Int64,
    "porosity": pl.Float64,
    "F_hold": pl.Float64,
    "F_squeeze": pl.Float64,
    "seed": pl.Int64,
    "perturbed": pl.Boolean,
    "lift_success": pl.Boolean,
    "stable_squeeze": pl.Boolean,
    "failure": pl.String,
    "initial_water": pl.Float64,
    "final_water": pl.Float64,
    **{f"water_removed_{ph}": pl.Float64 for ph in PHASES},
    "wall_s": pl.Float64,
    "n_records": pl.Int64,
    "duration_s": pl.Float64,
}


def build_index(out_dir: str | os.PathLike[str], write: bool = True) -> pl.DataFrame:
    """One row per run directory under ``OUT/runs`` (run file or error record), sorted by
    run id, and (if ``write``) stored atomically as ``OUT/index.parquet``.

    Columns: ``run_id``, ``status`` (ok / unstable / failed), ``error``, ``path`` (relative to
    OUT), the parameters ``size_cm, porosity, F_hold, F_squeeze, seed``, ``perturbed`` (the
    run followed seeded force targets from the lift on), ``lift_success``,
    ``stable_squeeze``, ``failure``, ``initial_water`` and ``final_water`` (kg),
    ``water_removed_<phase>`` (kg, null where the phase was not reached), ``wall_s`` (s, the
    engine's figure if it gives one; for runs that shared their prefix, the prefix's time split
    evenly plus the run's own squeeze), ``sweep_wall_s`` (s, measured around the runner; the
    group's time split evenly),
    ``n_records``, ``duration_s`` (simulated s), and any other scalar the outcome holds
    (e.g. particle counts). A run file whose outcome ``failure`` mentions "unstable" has
    status ``unstable``.
    """
    out = Path(out_dir)
    df = index_frame(out / RUNS_SUBDIR, out)
    if write:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out / INDEX_FILE, lambda f: df.write_parquet(f))
    return df


def is_perturbed(config: Mapping[str, Any]) -> bool:
    """Whether a stored trial config follows seeded force targets from the lift on."""
    perturbation = config.get("controller", {}).get("perturbation", {})
    return bool(perturbation.get("enabled", False))


def index_frame(root: Path, rel_to: Path) -> pl.DataFrame:
    """The index rows (see :func:`build_index`) of every run directory below ``root``, with
    ``path`` relative to ``rel_to``; an empty frame with the index columns if there is none."""
    rows: list[dict[str, Any]] = []
    seen: set[Path] = set()
    for path in sorted(root.rglob(RUN_FILE)) if root.exists() else []:
        seen.add(path.parent)
        meta = read_run_meta(path)
        stats = (
            pl.scan_parquet(path)
            .select(pl.len().alias("n"), (pl.col("time").max() - pl.col("time").min()).alias("d"))
            .collect()
        )
        orow = _outcome_row(meta)
        failure = orow.get("failure")
        rows.append(
            {
                "run_id": run_id(meta["params"]),
                "status": "unstable" if failure and "unstable" in str(failure).lower() else "ok",
                "error": None,
                "path": path.relative_to(rel_to).as_posix(),
                **{k: meta["params"][k] for k in PARAM_KEYS},
                "perturbed": is_perturbed(meta["config"]),
                **orow,
                "n_records": int(stats["n"][0]),
                "duration_s": float(stats["d"][0]),
            }
        )
    for epath in sorted(root.rglob(ERROR_FILE)) if root.exists() else []:
        if epath.parent in seen:
            continue
        rec = json.loads(epath.read_text())
        params = rec["params"]
        rows.append(
            {
                "run_id": run_id(params),
                "status": rec.get("status", "failed"),
                "error": rec.get("error"),
                "path": epath.relative_to(rel_to).as_posix(),
                **{k: params[k] for k in PARAM_KEYS},
                "perturbed": is_perturbed(rec.get("config", {})),
                "wall_s": rec.get("wall_s"),
            }
        )
    extra = sorted({k for r in rows for k in r} - set(INDEX_SCHEMA))
    columns = list(INDEX_SCHEMA) + extra
    data = {c: [r.get(c) for r in rows] for c in columns}
    return pl.DataFrame(
        {c: pl.Series(c, data[c], dtype=INDEX_SCHEMA.get(c), strict=False) for c in columns}
    ).sort("run_id")


# --------------------------------------------------------------------------------------
# Sweep


@dataclass
class SweepResult:
    """Counts of one sweep call and the index it left behind."""

    total: int
    skipped: int
    ok: int
    failed: int
    unstable: int
    wall_s: float
    index: pl.DataFrame

    def summary(self) -> str:
        return (
            f"{self.total} runs: {self.skipped} already done, {self.ok} ok, "
            f"{self.failed} failed, {self.unstable} unstable in {self.wall_s:.1f} s"
        )


def _clean_temporaries(out: Path) -> int:
    """Remove temporaries left by a killed sweep (``.<name>.<random>.tmp``); returns how many."""
    n = 0
    for tmp in list(out.glob(f".*{TMP_SUFFIX}")) + list(
        (out / RUNS_SUBDIR).rglob(f".*{TMP_SUFFIX}")
    ):
        tmp.unlink(missing_ok=True)
        n += 1
    return n


@contextlib.contextmanager
def _sweep_lock(out: Path) -> Iterator[None]:
    """Exclusive lock on ``OUT/.sweep.lock`` for the sweep's duration: two sweeps never write
    one directory at once. The kernel drops the lock when its holder dies, even by kill -9."""
    f = open(out / LOCK_FILE, "a+b")  # noqa: SIM115 - held for the whole sweep
    try:
        try:
            import fcntl

            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:  # pragma: no cover - not POSIX: no lock
            pass
        except BlockingIOError as exc:
            raise RuntimeError(f"another sweep is writing {out} (lock {out / LOCK_FILE})") from exc
        yield
    finally:
        f.close()


def _check_grid_file(out: Path, grid: Mapping[str, Any] | None) -> None:
    if grid is None:
        return
    gpath = out / GRID_FILE
    if gpath.exists():
        old = json.loads(gpath.read_text())
        if old != json.loads(json.dumps(grid)):
            raise ValueError(
                f"{out} holds a sweep of another grid ({gpath}); use a new --out directory "
                "or remove grid.json if the runs may be mixed"
            )
    else:
        atomic_write_json(gpath, grid)


def run_sweep(
    specs: Iterable[RunSpec],
    out_dir: str | os.PathLike[str],
    *,
    runner: Any = None,
    make_config: Any = None,
    backend: str = "local",
    workers: int | None = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
    progress: bool = True,
    grid: Mapping[str, Any] | None = None,
) -> SweepResult:
    """Execute every run of ``specs`` that is not done into ``out_dir`` and rebuild the index.

    ``backend`` ``"local"``: a process pool of ``workers`` spawned processes (default
    ``cpu_count // threads_per_run``; ``workers=0`` runs in this process, for debugging).
    ``"ray"``: one Ray task per run with ``num_cpus=threads_per_run`` (``ray.init()`` on the
    local machine, or the cluster named by ``$RAY_ADDRESS``). Each run gets
    ``num_threads=threads_per_run``. Prints a tqdm progress bar (runs done, failures, ETA)
    unless ``progress`` is false. ``grid`` is stored as ``grid.json`` on the first sweep
    and must match on later ones.
    """
    specs = list(specs)
    configs = _configs_of(specs, make_config)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with _sweep_lock(out):
        _check_grid_file(out, grid)
        _clean_temporaries(out)
        return _sweep_locked(
            specs,
            configs,
            out,
            runner,
            backend,
            workers,
            threads_per_run,
            retry_failed,
            progress,
        )


def _sweep_locked(
    specs: list[RunSpec],
    configs: Mapping[str, dict[str, Any]],
    out: Path,
    runner: Any,
    backend: str,
    workers: int | None,
    threads_per_run: int,
    retry_failed: bool,
    progress: bool,
) -> SweepResult:
    runs_root = out / RUNS_SUBDIR
    ids = [s.run_id for s in specs]
    if len(set(ids)) != len(ids):
        raise ValueError("the grid names some runs twice")
    if threads_per_run < 1:
        raise ValueError("threads_per_run must be at least 1")
    check_stale(specs, runs_root, configs)
    pending = longest_first(
        [s for s in specs if not is_done(run_path(runs_root, s.params).parent, retry_failed)]
    )
    groups = prefix_groups(pending, configs, runner)
    counts = {"ok": 0, "failed": 0, "unstable": 0}
    t0 = time.perf_counter()

    from tqdm.auto import tqdm  # type: ignore[import-untyped]

    bar = tqdm(
        total=len(specs),
        initial=len(specs) - len(pending),
        desc="sweep",
        unit="run",
        disable=not progress,
        dynamic_ncols=True,
    )

    def record(res: Mapping[str, Any]) -> None:
        st = res["status"]
        if st in counts:
            counts[st] += 1
        if st in ("failed", "unstable"):
            bar.write(f"[{st}] {res['run_id']}: {res['error']}")
        bar.update(1)
        bar.set_postfix(failed=counts["failed"], unstable=counts["unstable"], refresh=False)

    args = (str(runs_root), runner, threads_per_run, retry_failed)
    try:
        if not pending:
            pass
        elif backend == "local":
            n = workers if workers is not None else max(1, (os.cpu_count() or 1) // threads_per_run)
            if n <= 0:
                for g in groups:
                    for res in execute_group(g, [configs[s.run_id] for s in g], *args):
                        record(res)
            else:
                _run_local(groups, configs, args, n, record)
        elif backend == "ray":
            _run_ray(groups, configs, args, threads_per_run, workers, record)
        else:
            raise ValueError(f"unknown backend {backend!r} (local or ray)")
    finally:
        bar.close()
        index = build_index(out)
    return SweepResult(
        total=len(specs),
        skipped=len(specs) - len(pending),
        ok=counts["ok"],
        failed=counts["failed"],
        unstable=counts["unstable"],
        wall_s=time.perf_counter() - t0,
        index=index,
    )


def longest_first(specs: list[RunSpec]) -> list[RunSpec]:
    """``specs`` with the most particles first (the largest sponge, the finest radius), grid
    order kept among equals: started last, a long trial would keep one worker busy while the
    others idle. Each run's result does not depend on the order."""
    import rmi_sph

    volume = {size_cm(d): d[0] * d[1] * d[2] for d in rmi_sph.SPONGE_SIZES_M}

    def particles(s: RunSpec) -> float:
        return volume.get(int(s.params["size_cm"]), 0.0) / s.radius**3

    return sorted(specs, key=lambda s: -particles(s))


def _record_lost(
    group: list[RunSpec], runs_root: str, err: str, record: Callable[[Any], None]
) -> None:
    """Records every run of ``group`` whose run file is missing as failed with ``err``."""
    for spec in group:
        path = run_path(runs_root, spec.params)
        if path.exists():
            continue
        write_error(path.parent, spec.params, {"status": "failed", "error": err, "wall_s": None})
        record({"run_id": spec.run_id, "status": "failed", "error": err})


def _run_local(
    groups: list[list[RunSpec]],
    configs: Mapping[str, dict[str, Any]],
    args: tuple[Any, ...],
    workers: int,
    record: Callable[[Any], None],
) -> None:
    """Process pool with spawn, one task per :func:`prefix_groups` group. A worker that dies
    (e.g. a crash in native code) breaks the pool; the runs of its group are retried one by
    one in a fresh pool (those already stored are skipped), and a run that breaks it twice is
    recorded as failed."""
    ctx = multiprocessing.get_context("spawn")
    attempts: dict[str, int] = {}
    todo = list(groups)
    while todo:
        retry: list[list[RunSpec]] = []
        with cf.ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx) as pool:
            futures = {
                pool.submit(execute_group, g, [configs[s.run_id] for s in g], *args): g
                for g in todo
            }
            for fut in cf.as_completed(futures):
                group = futures[fut]
                try:
                    for res in fut.result():
                        record(res)
                except cf.process.BrokenProcessPool:
                    # Retried one run at a time: one trial's crash costs no other run.
                    for spec in group:
                        attempts[spec.run_id] = attempts.get(spec.run_id, 0) + 1
                        if attempts[spec.run_id] >= 2:
                            err = "worker process died twice while running this trial"
                            _record_lost([spec], args[0], err, record)
                        else:
                            retry.append([spec])
        todo = retry


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError(
            "the ray backend needs Ray: pip install 'rmi[ray]' (or pip install ray)"
        ) from exc
    return ray


def _run_ray(
    groups: list[list[RunSpec]],
    configs: Mapping[str, dict[str, Any]],
    args: tuple[Any, ...],
    threads_per_run: int,
    workers: int | None,
    record: Callable[[Any], None],
) -> None:
    """One Ray task per :func:`prefix_groups` group (``num_cpus=threads_per_run``);
    ``ray.init()`` locally or on the cluster of ``$RAY_ADDRESS`` unless Ray is already
    initialised. A task returns its runs' file bytes (:func:`compute_group`) and this process
    writes them (:func:`store_run`), so the runs and the index land on the driver's disk
    whichever node ran them. A task whose node is lost is retried once on another node
    (Ray's ``max_retries``)."""
    ray = _import_ray()
    started_here = False
    if not ray.is_initialized():
        address = os.environ.get("RAY_ADDRESS") or None
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address is None:
            # A local Ray: workers import rmi_learn (and an injected runner) like this process,
            # and use at most workers x threads_per_run cores if --workers is given.
            kwargs["runtime_env"] = {
                "env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
            }
            if workers:
                kwargs["num_cpus"] = workers * threads_per_run
        ray.init(address=address, **kwargs)
        started_here = True
    try:
        runs_root, runner, _, _ = args
        remote = ray.remote(num_cpus=threads_per_run, max_retries=1)(compute_group)
        refs = {
            remote.remote(g, [configs[s.run_id] for s in g], runner, threads_per_run): g
            for g in groups
        }
        waiting = list(refs)
        while waiting:
            done, waiting = ray.wait(waiting, num_returns=1)
            for ref in done:
                group = refs[ref]
                try:
                    results = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a lost worker, not a runner error
                    err = f"ray task failed: {type(exc).__name__}: {exc}"
                    _record_lost(group, runs_root, err, record)
                else:
                    for spec, result in zip(group, results, strict=True):
                        record(store_run(result, spec, runs_root))
    finally:
        if started_here:
            ray.shutdown()


def estimate_wall_time(per_run_s: float, runs: int, workers: int) -> float:
    """Wall time (s) of ``runs`` runs of ``per_run_s`` seconds each on ``workers`` parallel
    workers (whole waves, no overhead)."""
    return math.ceil(runs / max(1, workers)) * per_run_s


def sweep(
    out_dir: str | os.PathLike[str],
    *,
    preset: str | None = None,
    grid_file: str | os.PathLike[str] | None = None,
    limit: int | None = None,
    backend: str = "local",
    workers: int | None = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
    progress: bool = True,
    runner: Any = None,
    make_config: Any = None,
) -> SweepResult:
    """``rmi sweep``: run the grid of ``preset`` or ``grid_file`` (exactly one), or its first
    ``limit`` points, into ``out_dir`` (see :func:`run_sweep` for the other arguments).

    Raises :class:`~rmi_learn.errors.InputError` for a missing or bad grid and a run the
    engine refuses, :class:`~rmi_learn.errors.StageFailure` when the sweep cannot start
    (another sweep holds the lock, the ray backend is missing)."""
    if not preset and not grid_file:
        raise InputError("give --preset NAME or --grid FILE")
    try:
        grid = load_grid(preset=preset) if preset else load_grid(path=grid_file)
    except (OSError, ValueError) as exc:
        raise InputError(exc) from exc
    specs = expand_grid(grid)
    if limit is not None:
        specs = specs[:limit]
    try:
        return run_sweep(
            specs,
            out_dir,
            runner=runner,
            make_config=make_config,
            backend=backend,
            workers=workers,
            threads_per_run=threads_per_run,
            retry_failed=retry_failed,
            progress=progress,
            grid=grid,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    except RuntimeError as exc:
        raise StageFailure(exc) from exc
