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
They must be picklable (module-level functions), because local workers are spawned
processes (fork and the engine's rayon pools do not mix). With the default runner, the runs
that differ only in their squeeze force are one job each, run from one shared prefix
(:func:`prefix_groups`, :func:`compute_group`); an injected runner runs every trial alone.

The modules, one concept each: :mod:`.grid` (grids and their runs), :mod:`.configs` (the
runs' trial configs), :mod:`.compute` (computing and storing runs), :mod:`.index` (the run
index), :mod:`.lock` (the output directory's lock file and a killed sweep's temporaries),
:mod:`.local` and :mod:`.ray_runner` (the backends) and :mod:`.run` (the driver).
"""

from rmi_learn.data.sweep.compute import (
    Runner,
    RunSettings,
    compute_group,
    compute_run,
    execute_group,
    execute_run,
    is_done,
    prefix_groups,
    store_run,
)
from rmi_learn.data.sweep.configs import (
    ConfigMaker,
    check_stale,
    config_of,
    configs_of,
    is_perturbed,
    with_later_fields,
)
from rmi_learn.data.sweep.grid import (
    PRESETS,
    RunSpec,
    expand_grid,
    load_grid,
    perturbation_override,
    size_overrides,
    validate_grid,
)
from rmi_learn.data.sweep.index import (
    INDEX_FILE,
    INDEX_SCHEMA,
    RUNS_SUBDIR,
    build_index,
    index_frame,
)
from rmi_learn.data.sweep.lock import LOCK_FILE
from rmi_learn.data.sweep.run import (
    GRID_FILE,
    SweepResult,
    estimate_wall_time,
    longest_first,
    run_sweep,
    sweep,
)

__all__ = [
    "GRID_FILE",
    "INDEX_FILE",
    "INDEX_SCHEMA",
    "LOCK_FILE",
    "PRESETS",
    "RUNS_SUBDIR",
    "ConfigMaker",
    "RunSettings",
    "RunSpec",
    "Runner",
    "SweepResult",
    "build_index",
    "check_stale",
    "compute_group",
    "compute_run",
    "config_of",
    "configs_of",
    "estimate_wall_time",
    "execute_group",
    "execute_run",
    "expand_grid",
    "index_frame",
    "is_done",
    "is_perturbed",
    "load_grid",
    "longest_first",
    "perturbation_override",
    "prefix_groups",
    "run_sweep",
    "size_overrides",
    "store_run",
    "sweep",
    "validate_grid",
    "with_later_fields",
]
