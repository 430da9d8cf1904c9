"""The Ray backend of a sweep: one Ray task per group of runs, on this machine or a cluster;
the driver writes every run, so the runs and the index land on its disk."""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from typing import Any

from rmi_learn.data.sweep.compute import (
    Record,
    RunSettings,
    compute_group,
    group_configs,
    record_lost,
    store_run,
)
from rmi_learn.data.sweep.grid import RunSpec


def import_ray() -> Any:
    """The ``ray`` module; a ``RuntimeError`` saying how to install it when it is missing."""
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError(
            "the ray backend needs Ray: pip install 'rmi[ray]' (or pip install ray)"
        ) from exc
    return ray


def run_ray(
    groups: list[list[RunSpec]],
    configs: Mapping[str, dict[str, Any]],
    settings: RunSettings,
    workers: int | None,
    record: Record,
) -> None:
    """One Ray task per :func:`prefix_groups` group (``num_cpus`` the threads per run);
    ``ray.init()`` locally or on the cluster of ``$RAY_ADDRESS`` unless Ray is already
    initialised. A task returns its runs' file bytes (:func:`compute_group`) and this process
    writes them (:func:`store_run`), so the runs and the index land on the driver's disk
    whichever node ran them. A task whose node is lost is retried once on another node
    (Ray's ``max_retries``)."""
    ray = import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        _init_ray(ray, workers, settings.threads_per_run)
    try:
        runs_root, threads = settings.runs_root, settings.threads_per_run
        remote = ray.remote(num_cpus=threads, max_retries=1)(compute_group)
        refs = {
            remote.remote(g, group_configs(g, configs), settings.runner, threads): g for g in groups
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
                    record_lost(group, runs_root, err, record)
                else:
                    for spec, result in zip(group, results, strict=True):
                        record(store_run(result, spec, runs_root))
    finally:
        if started_here:
            ray.shutdown()


def _init_ray(ray: Any, workers: int | None, threads_per_run: int) -> None:
    """``ray.init()`` on the cluster of ``$RAY_ADDRESS``, else a Ray on this machine."""
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
