"""The Ray backend on a cluster of several nodes on this machine (``ray.cluster_utils``):
workers return each run file's bytes and the driver writes them, so the runs and the index
are on the driver's disk and equal those of a local sweep, even when a node dies mid-sweep.

One cluster (a head and one worker node, 1 CPU each, its files under a pytest temporary
directory) serves the module: starting one takes seconds.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import polars as pl
import pytest
from polars.testing import assert_frame_equal
from sweep_doubles import fake_make_config, fake_runner, grid, logged

from rmi_learn.data.runs import iter_run_files, read_run
from rmi_learn.data.sweep import INDEX_FILE, expand_grid, run_sweep, validate_grid
from tiny_trial import TINY

ray = pytest.importorskip("ray")
cluster_utils = pytest.importorskip("ray.cluster_utils")

#: Outcome fields and index columns that measure wall time, different in every sweep.
WALL = ("wall_s", "sweep_wall_s")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """A head and one worker node of 1 CPU each, with the driver connected; the workers
    import rmi_learn and the test doubles through this process's ``sys.path``."""
    temp = tmp_path_factory.mktemp("ray")
    (temp / "ray").mkdir()  # Ray's files go to $RAY_TMPDIR/ray, which it expects to exist
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RAY_TMPDIR", str(temp))
        node_args = {"num_cpus": 1, "temp_dir": str(temp / "ray"), "include_dashboard": False}
        c = cluster_utils.Cluster(initialize_head=True, head_node_args=node_args)
        try:
            c.add_node(num_cpus=1)
            c.wait_for_nodes()
            ray.init(
                address=c.address,
                log_to_driver=False,
                runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}},
            )
            yield c
        finally:
            ray.shutdown()
            c.shutdown()


def assert_same_sweep(a: Path, b: Path) -> None:
    """Two sweep directories hold the same runs: equal rows, metadata and index, wall-time
    fields aside."""
    files_a = [p.relative_to(a) for p in iter_run_files(a / "runs")]
    assert files_a and files_a == [p.relative_to(b) for p in iter_run_files(b / "runs")]
    for rel in files_a:
        (frame_a, meta_a), (frame_b, meta_b) = read_run(a / rel), read_run(b / rel)
        assert_frame_equal(frame_a, frame_b, check_exact=True)
        for meta in (meta_a, meta_b):
            for key in WALL:
                meta["outcome"].pop(key, None)
        assert meta_a == meta_b
    index_a, index_b = (pl.read_parquet(d / INDEX_FILE).drop(WALL, strict=False) for d in (a, b))
    assert_frame_equal(index_a, index_b, check_exact=True)


def test_ray_runs_of_the_engine_land_on_the_driver_and_equal_a_local_sweep(
    cluster: Any, tmp_path: Path
) -> None:
    g = validate_grid(
        {
            "sizes_cm": [8],
            "porosities": [0.8],
            "hold_forces_N": [20],
            "squeeze_forces_N": [150],
            "seeds": [0, 1],
            "radius_m": 0.01,
            "overrides": TINY,
        }
    )
    specs = expand_grid(g)
    res = run_sweep(specs, tmp_path / "ray", backend="ray", progress=False, grid=g)
    assert res.ok == 2 and res.failed == 0
    run_sweep(specs, tmp_path / "local", workers=0, progress=False, grid=g)
    assert_same_sweep(tmp_path / "ray", tmp_path / "local")


def test_a_node_lost_mid_sweep_is_retried_and_the_result_equals_a_local_sweep(
    cluster: Any, tmp_path: Path
) -> None:
    log = tmp_path / "starts.log"
    g = grid(
        sizes_cm=[8],
        porosities=[0.5, 0.7],
        hold_forces_N=[30, 150],
        overrides={"sleep": 1.5, "log": str(log)},
    )
    specs = expand_grid(g)
    kwargs: dict[str, Any] = {"runner": fake_runner, "make_config": fake_make_config}
    outcome: dict[str, Any] = {}

    def sweep() -> None:
        try:
            outcome["result"] = run_sweep(
                specs, tmp_path / "ray", backend="ray", progress=False, grid=g, **kwargs
            )
        except BaseException as exc:  # noqa: BLE001 - re-raised by the test thread
            outcome["error"] = exc

    thread = threading.Thread(target=sweep)
    thread.start()
    # Two runs in flight on two nodes of 1 CPU: one of them runs on the worker node.
    deadline = time.monotonic() + 60
    while len(logged(log)) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(logged(log)) == 2
    cluster.remove_node(next(iter(cluster.worker_nodes)), allow_graceful=False)
    thread.join(timeout=120)
    assert not thread.is_alive()
    if "error" in outcome:
        raise outcome["error"]
    res = outcome["result"]
    assert (res.ok, res.failed) == (len(specs), 0)
    # The run lost with its node started again, on the head node.
    assert len(logged(log)) == len(specs) + 1
    run_sweep(specs, tmp_path / "local", workers=0, progress=False, grid=g, **kwargs)
    assert_same_sweep(tmp_path / "ray", tmp_path / "local")
