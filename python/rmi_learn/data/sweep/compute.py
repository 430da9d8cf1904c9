"""Computing and storing the runs of a sweep, in whichever process runs them.

:func:`compute_run` and :func:`compute_group` run trials and return their run files' bytes
(or their error records) without writing anything, so a Ray worker on another machine can
compute them; :func:`store_run` writes one result atomically under the sweep's ``runs/``
tree; :func:`execute_run` and :func:`execute_group` do both, for a worker that shares the
driver's disk. A runner that raises never stops the sweep: its run is recorded as
``unstable`` (the engine's ``SimulationUnstableError``) or ``failed``.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rmi_sph
from rmi_learn.data.runs import (
    ERROR_FILE,
    RUN_FILE,
    atomic_write_bytes,
    run_file_bytes,
    run_path,
    write_error,
)
from rmi_learn.data.sweep.configs import is_perturbed
from rmi_learn.data.sweep.grid import RunSpec
from rmi_learn.errors import RunFileError

#: Runs one trial: ``runner(config, *, num_threads) -> {"columns", "outcome"}``, like
#: ``rmi_sph.run_trial``. It must be picklable (a module-level function): local workers are
#: spawned processes and Ray ships it to its workers.
Runner = Callable[..., Mapping[str, Any]]
#: Told of each run's result as the sweep learns of it: ``{"run_id", "status", "wall_s",
#: "error"}``.
Record = Callable[[Mapping[str, Any]], None]


@dataclass(frozen=True)
class RunSettings:
    """How a sweep computes and stores its runs: the ``runs/`` tree they are written to, the
    runner (None: the engine's), the engine threads of each run, and whether runs recorded
    as failed are run again."""

    runs_root: str
    runner: Runner | None = None
    threads_per_run: int = 1
    retry_failed: bool = False

    def execute(
        self, group: list[RunSpec], configs: Mapping[str, dict[str, Any]]
    ) -> list[dict[str, Any]]:
        """:func:`execute_group` of ``group`` (``configs`` by run id) in this process."""
        return execute_group(group, group_configs(group, configs), *self.worker_args())

    def worker_args(self) -> tuple[str, Runner | None, int, bool]:
        """The trailing arguments of :func:`execute_group` (as a worker process gets them)."""
        return self.runs_root, self.runner, self.threads_per_run, self.retry_failed


def group_configs(
    group: list[RunSpec], configs: Mapping[str, dict[str, Any]]
) -> list[dict[str, Any]]:
    """The trial configs of the runs of ``group``, in its order (``configs`` by run id)."""
    return [configs[s.run_id] for s in group]


def is_done(run_dir: Path, retry_failed: bool = False) -> bool:
    """Whether the run in ``run_dir`` needs no work: its run file exists, or it failed and
    failures are not retried."""
    if (run_dir / RUN_FILE).exists():
        return True
    return (not retry_failed) and (run_dir / ERROR_FILE).exists()


def _status_of_exception(exc: BaseException) -> str:
    names = {c.__name__ for c in type(exc).__mro__}
    return "unstable" if "SimulationUnstableError" in names else "failed"


def compute_run(
    spec: RunSpec, config: dict[str, Any], runner: Runner | None = None, threads_per_run: int = 1
) -> dict[str, Any]:
    """Run one grid point and return its result without writing anything: ``{"run_id",
    "status", "wall_s", "error", "data", "record"}`` with status ``ok`` (``data``: the run
    file's bytes, :func:`rmi_learn.data.runs.run_file_bytes`), or ``failed`` / ``unstable``
    (``record``: the body of its ``error.json``). ``runner`` None runs the engine's
    ``rmi_sph.run_trial``. Never raises for a failing runner.
    :func:`store_run` writes the result where the sweep's output lives, which for a Ray
    worker is another machine's disk."""
    t0 = time.perf_counter()
    try:
        run: Runner = rmi_sph.run_trial if runner is None else runner
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
    specs: list[RunSpec], configs: Mapping[str, dict[str, Any]], runner: Runner | None = None
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
    runner: Runner | None = None,
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
    runner: Runner | None = None,
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
    runner: Runner | None = None,
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


def record_lost(group: list[RunSpec], runs_root: str, err: str, record: Record) -> None:
    """Records every run of ``group`` whose run file is missing as failed with ``err``."""
    for spec in group:
        path = run_path(runs_root, spec.params)
        if path.exists():
            continue
        write_error(path.parent, spec.params, {"status": "failed", "error": err, "wall_s": None})
        record({"run_id": spec.run_id, "status": "failed", "error": err})
