"""Closed-loop execution of ranked action chunks in the simulator (the *real* Table III).

``rmi rank`` reports the terminal water error that the world model W_T predicts for the chunk
it selected itself, which is biased toward W_T. This package executes the original (collected),
first-sample and selected chunks of ``chunks_<objective>.npz`` in the SPH engine and measures
the retained water they really leave after the last command.

Replay (:mod:`rmi_learn.sim.replay`). The engine is deterministic (one config gives
bit-identical trajectories, whatever the thread count), so a window's starting state is rebuilt
from the run's stored config (``rmi.config``): ``rmi_sph.Trial(config)`` is stepped with the
scripted controller to the anchor. The anchor ``t`` of a window in the npz is the *kept-row
index* within the run's learning rows (``frames.parquet`` column ``t``, after resampling to
20 ms and dropping the settle, waiting and done rows and the first close row), not a grid
index. It is mapped to the
grid index ``k`` by redoing that row selection on the run file
(:func:`rmi_learn.data.dataset.resample_run` and
:func:`~rmi_learn.data.dataset.select_learning_rows`), and the anchor is simulated time
``k * CONTROL_DT`` = ``round(k * 0.02 / dt)`` engine steps.
Before any chunk runs, the replayed observation at the anchor is compared with the stored
record there (every channel except the pad loads, which run files average over the record
interval); a difference means the run came from another engine or config and stops the
command (:class:`ClosedLoopError`).

Execution. The state at the anchor is saved once per window (``get_state``); each chunk then
starts from it (``set_state``). Command ``i`` of a chunk (``i`` = 0..31, the action rows
``t..t+31`` of the window) is applied with ``set_action`` and held for one control step of
``round(0.02 / dt)`` engine steps, so the chunk covers ``[t_k, t_k + 0.64 s)``; ``M_L`` is read
after the 32nd command, at the time of the goal row ``t + 32``. The chunks are force
setpoints (``schema.CONTROL_ACTIONS``), clipped to [0, FORCE_LIMIT_N] (the gripper's limit,
N) and sent with ``set_action(F_target)``: the engine's force regulation (paper Eq. 5b) runs
every engine step toward the setpoint, its guards acting on the force limit and minimum width
as always. The phase sequence (lift, waiting, squeeze), the lift gate and the grasp-failure
checks keep running under external commands. During the close phase the collected command is
F_target = 0 with a closing speed, which a force setpoint cannot express.

Phase timing is not fixed by the window: the lift gate of the hold phase watches the grip
loads, so a chunk in the hold can open it earlier, later or not at all; grasp failures
(dropped, slipped out) end the trial early. Each row records the phase reached
(``phase_end``) next to the collected one (``goal_phase``), and ``failure``.

The original chunk is executed from the run file's own commands (f64, identical to the npz
chunk up to its float32 rounding, which is checked); its real error against the goal measures
what the 20 ms zero-order hold of the commands loses (the replay error).

Outputs in ``out_dir``: ``closed_loop_windows.parquet`` (one row per window and chunk,
checkpointed atomically after every window so that an interrupted run resumes; a window
whose replay raised is recorded as ``replay_failed`` and, the engine being deterministic,
not retried),
``table_closed_loop.md`` and ``table_closed_loop.json``. Water is in kg in stored data and in
grams in tables.

Modules: :mod:`.windows` (the chunk files, the windows and their checks), :mod:`.execute`
(a window's chunks executed from its anchor), :mod:`.table` (the checkpointed rows, the
summary and the Markdown table) and :mod:`.driver` (:func:`run_closed_loop`).
"""

from rmi_learn.closed_loop.driver import run_closed_loop
from rmi_learn.closed_loop.execute import execute_chunk
from rmi_learn.closed_loop.table import summarise
from rmi_learn.closed_loop.windows import (
    ClosedLoopError,
    Window,
    check_window,
    load_chunks,
    select_windows,
)

__all__ = [
    "ClosedLoopError",
    "Window",
    "check_window",
    "execute_chunk",
    "load_chunks",
    "run_closed_loop",
    "select_windows",
    "summarise",
]
