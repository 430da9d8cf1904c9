"""Shared pytest fixtures.

``synthetic_runs_dir`` and ``synthetic_dataset_dir`` (session-scoped) give run files from the
toy ODE of ``rmi_learn.data.synthetic`` and a dataset built from them, for fast tests of the data
and learning code. Their numbers mean nothing physically. ``bench_script`` loads a script of
``benches/`` as a module, to test its pure functions.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from script_module import load_script

BENCHES = Path(__file__).resolve().parents[1] / "benches"


@pytest.fixture
def bench_script() -> Callable[[str], Any]:
    """``bench_script("seed_floor")`` returns ``benches/seed_floor.py`` loaded as a module
    (``benches/`` is a folder of scripts, not a package)."""

    def load(name: str) -> Any:
        return load_script(BENCHES / f"{name}.py")

    return load


#: Runs per sponge size in the shared synthetic fixture (3 sizes -> 36 runs, of which 18
#: complete lift and squeeze and form the dataset; 4 groups per size).
SYNTHETIC_RUNS_PER_SIZE = 12


@pytest.fixture(scope="session")
def synthetic_runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Directory of synthetic run files (grid layout of ``rmi_learn.data.runs.run_path``)."""
    from rmi_learn.data.synthetic import write_synthetic_runs

    root = tmp_path_factory.mktemp("synthetic") / "runs"
    write_synthetic_runs(root, n_per_size=SYNTHETIC_RUNS_PER_SIZE, seed=0)
    return root


@pytest.fixture(scope="session")
def synthetic_dataset_dir(synthetic_runs_dir: Path) -> Path:
    """A dataset built with ``build_dataset(synthetic_runs_dir, ..., seed=0)``: open it with
    ``rmi_learn.data.dataset.load_dataset(synthetic_dataset_dir)``. Treat it as read-only."""
    from rmi_learn.data.dataset import build_dataset

    return build_dataset(synthetic_runs_dir, synthetic_runs_dir.parent / "dataset", seed=0)
