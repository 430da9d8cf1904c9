"""Independent jobs in a pool of spawned processes, their results in the jobs' order.

Spawned, not forked: a worker imports what it needs afresh instead of inheriting the parent's
torch and engine threads. The drivers that share work this way (the pipeline's trainings, the
closed loop's runs, the protocol benchmark's runs) save each result as it comes, so an
interrupted pool loses only the jobs still running.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

J = TypeVar("J")
R = TypeVar("R")


def ordered_map(fn: Callable[[J], R], jobs: Sequence[J], workers: int) -> Iterator[R]:
    """``fn`` of each job, in this process when ``workers`` <= 1, else in a pool of
    ``workers`` spawned processes; yields the results in the jobs' order. When a job raises
    (or the caller stops early) the jobs not started are cancelled, and the pool ends once
    the running ones have."""
    if workers <= 1:
        yield from map(fn, jobs)
        return
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
    try:
        yield from pool.map(fn, jobs)
    finally:
        pool.shutdown(cancel_futures=True)


__all__ = ["ordered_map"]
