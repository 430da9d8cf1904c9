"""The learning dataset (paper Sec. V, S4): resampled frames (:mod:`.frames`), grouped split
(:mod:`.split`), statistics (:mod:`.stats`), the build (:mod:`.builder`) and windows
(:mod:`.windows`).

``build_dataset(run_dir, out_dir, seed=0)`` turns a directory of run files into a cached
on-disk dataset; ``load_dataset(out_dir)`` opens it; ``Dataset.windows(split)`` gives a
``torch.utils.data.Dataset`` of (history, action chunk, future) windows.

Processing, in order:

1. Run selection: only runs whose outcome has ``lift_success`` and ``stable_squeeze``.
2. Resampling to the global grid ``t_k = k * CONTROL_DT`` (20 ms; ``k`` integer, so every run
   shares the grid), for the grid times inside the recorded span. Continuous channels (the 18
   entries of z, both recorded commands, ``time``) are *linearly interpolated* at the grid time
   between the two bracketing records (a record that falls on the grid time, within 1e-9 s,
   is taken as is). ``v_res`` is NaN at a grid time unless both bracketing records are
   finite. Categorical channels (``c``, ``r_*``, ``phase``) take the value of the last record
   at or before the grid time (zero-order hold), so they stay exact 0/1 labels. Interpolation
   was chosen over bin averaging so that a grid sample is the state *at* ``t_k`` and the
   action at ``t_k`` is the command issued then, with no half-step shift between them.
3. Row selection: grid rows whose phase is not in ``LEARNING_PHASES`` are dropped (settle,
   the duplicated waiting phase, done), and so is the first grid row of ``close`` (the
   initial velocity command). Dropping ``waiting`` leaves a gap in time between ``lift`` and
   ``squeeze``; the kept rows of a run therefore form contiguous *segments*, and a window
   never spans two segments (nor, a fortiori, two runs).
4. Grouped split: runs sharing (size, porosity, F_hold) form a group; within each size the
   groups are shuffled with ``numpy.random.default_rng([seed, size_cm])`` and
   ``round(0.1 n)`` go to validation and ``round(0.2 n)`` to test (each at least one when
   there are at least three groups), the rest to training (70/10/20 of groups).
5. Statistics: mean and population standard deviation of the 18 continuous channels (NaN
   ignored) and the learned action F_target (``CONTROL_ACTIONS``) over the kept rows of the
   training runs only. A channel that is constant in training gets a divisor of 1.

Cached form written to ``out_dir``: ``frames.parquet`` (kept rows, raw SI values, with
``run``, ``t`` row index within the run, ``k`` grid index, ``segment``), ``runs.parquet``
(one row per run: number, id, parameters, split, row counts), ``stats.json`` and
``dataset.json`` (build facts and counts). They are written whole or not at all: into a
temporary directory inside ``out_dir``, then moved in together, ``dataset.json`` last.
"""

from __future__ import annotations

from rmi_learn.data.dataset.builder import BUILD_FILES, FORMAT_VERSION, build, build_dataset
from rmi_learn.data.dataset.frames import (
    CATEGORICAL,
    WATER_INDEX,
    resample_run,
    select_learning_rows,
)
from rmi_learn.data.dataset.split import FRACTIONS, SPLITS, grouped_split
from rmi_learn.data.dataset.stats import Stats, compute_stats, read_stats
from rmi_learn.data.dataset.windows import Dataset, WindowSet, describe, load_dataset, read_table

__all__ = [
    "BUILD_FILES",
    "CATEGORICAL",
    "Dataset",
    "FORMAT_VERSION",
    "FRACTIONS",
    "SPLITS",
    "Stats",
    "WATER_INDEX",
    "WindowSet",
    "build",
    "build_dataset",
    "compute_stats",
    "describe",
    "grouped_split",
    "load_dataset",
    "read_stats",
    "read_table",
    "resample_run",
    "select_learning_rows",
]
