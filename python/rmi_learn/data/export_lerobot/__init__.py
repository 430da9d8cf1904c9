"""Export of a built learning dataset to LeRobot's dataset layout: :func:`export_lerobot`
(``rmi dataset export --format lerobot [--codebase-version v3.0|v2.1]``).

The export needs polars and numpy only, not the ``lerobot`` package. One episode per run,
on the dataset's control grid (20 ms, 50 fps), in the rows the dataset keeps (the learning
phases). Codebase v3.0 (the default, :mod:`.layout_v30`) is what current LeRobot reads;
v2.1 (:mod:`.layout_v21`) is kept for tools that still read that one.

Columns of every episode (the features of ``info.json``, :mod:`.episodes`):

- ``observation.state`` (23 float32): the observation ``y_t`` in ``schema.OBS`` order, SI
  units. A value the dataset holds as NaN (only ``v_res``, undefined without contact) is
  written as 0, and ``observation.state_mask`` (23 float32) is 1 where the value was finite
  and 0 where it was filled, as the world models' ``hist_mask``.
- ``action`` (float32): the action channels the dataset was built with, named by its
  ``stats.json`` (``u_names``); one channel is a scalar column, as LeRobot stores a feature
  of shape [1], several a fixed-length list.
- ``timestamp`` (float32, s): ``frame_index / fps``. LeRobot requires consecutive
  timestamps one frame apart, while the dataset drops the ``waiting`` phase between lift
  and squeeze; ``sim_time`` (float32, s) keeps the simulated time of each frame, so the
  jump at that gap shows there.
- ``phase_index`` (int64): the controller phase, an index into ``schema.PHASES``.
- ``frame_index``, ``episode_index``, ``index`` (global frame number), ``task_index``
  (int64) and ``next.done`` (bool, true on an episode's last frame).

Episodes are ordered by split (train, val, test), then by the dataset's run number, so that
``info.json``'s ``splits`` are the ranges ``"0:a"``, ``"a:b"``, ``"b:n"`` of the dataset's
own grouped split (an empty split is left out). Statistics (:mod:`.stats`) are population
statistics of the exported values (the filled zeros included) over every frame, as LeRobot
computes them; the dataset's own ``stats.json`` covers the training split only.

The export is written into a temporary directory beside ``out_dir`` and renamed to it at
the end, so ``out_dir`` either does not exist or holds a complete export; the temporary
directory of an export that was killed is removed by the next export into the same
directory (see :mod:`rmi_learn.data.staging`).
"""

from rmi_learn.data.export_lerobot.driver import CODEBASE_VERSIONS, export_lerobot
from rmi_learn.data.export_lerobot.episodes import TASK, features
from rmi_learn.data.export_lerobot.stats import feature_stats, table_stats

__all__ = [
    "CODEBASE_VERSIONS",
    "TASK",
    "export_lerobot",
    "feature_stats",
    "features",
    "table_stats",
]
