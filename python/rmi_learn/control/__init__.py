"""Goal-reaching benchmark executed in the simulator (``rmi control-bench``).

It separates "the policy proposes nothing better" from "the scorer cannot find it": every
controller is executed in the SPH engine from the same start states toward the same goals,
and the executed terminal water error is compared.

- Executed action: a chunk's H force setpoints F_target, each held for one 20 ms control
  step and tracked by the engine's force loop (:mod:`.execute`); v_cmd is the force loop's
  own output and is not executed.
- Start states: held-out windows (test split, else validation) whose anchor lies in an
  acting phase (hold, lift, waiting, squeeze), rebuilt by deterministic replay of the run
  (:func:`rmi_learn.policies.closed_loop.load_track`, ``check_anchor``), drawn in a seeded
  order and deduplicated by a fingerprint of the physical state.
- Goals: a sweep of constant setpoints from 0.8 F_hold to the force limit gives the
  reachable interval of terminal M_L; goals are drawn uniformly inside it, and the logged
  goal (M_L at t + H) is reported apart.
- Controllers: ``recorded``, ``constant-best`` (hindsight), ``first-sample/<policy>``,
  ``ranked-<scorer>/<policy>``, ``best-of-k/<policy>`` (the ceiling of ranking) and
  ``receding-<n>/<policy>`` (re-planning every n control steps from the observed history).

:func:`run_control_bench` is the library entry point; :mod:`.measures` the statistics.
"""

from rmi_learn.control.bench import (
    ACTING_PHASES,
    SETPOINT_LOW_FRACTION,
    ControlBenchError,
    run_control_bench,
)
from rmi_learn.control.execute import execute_forces, run_forces, state_fingerprint

__all__ = [
    "ACTING_PHASES",
    "SETPOINT_LOW_FRACTION",
    "ControlBenchError",
    "execute_forces",
    "run_control_bench",
    "run_forces",
    "state_fingerprint",
]
