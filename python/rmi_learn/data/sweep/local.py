"""The local backend of a sweep: a pool of spawned worker processes on this machine."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
from collections.abc import Mapping
from typing import Any

from rmi_learn.data.sweep.compute import (
    Record,
    RunSettings,
    execute_group,
    group_configs,
    record_lost,
)
from rmi_learn.data.sweep.grid import RunSpec


def run_local(
    groups: list[list[RunSpec]],
    configs: Mapping[str, dict[str, Any]],
    settings: RunSettings,
    workers: int,
    record: Record,
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
                pool.submit(execute_group, g, group_configs(g, configs), *settings.worker_args()): g
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
                            record_lost([spec], settings.runs_root, err, record)
                        else:
                            retry.append([spec])
        todo = retry
