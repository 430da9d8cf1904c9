"""The goal-reaching benchmark under a committed protocol (``rmi control-bench --protocol``).

Every controller closes its loop tick by tick in the engine, from the same start states
toward the same goals, on what its observation mode shows: PI on the simulator's M_L
(``privileged``), PI on estimates of M_L from the gripper's sensors (the wrist load's
weight, the width, a learned estimator over the sensor history, and a learned prediction
of the water left after the release; ``sensors``), the held
setpoint, the logged controller, and an executed bisection over constant setpoints that
uses the simulator (an oracle). Conditions are held out by group, and every interval is a
cluster bootstrap over runs.

Modules: :mod:`.protocol` (the file and its checks), :mod:`.held_out` (folds and start
states), :mod:`.episode` (one executed closed loop), :mod:`.laws` (PI, hold, fixed
setpoints), :mod:`.estimators` and :mod:`.fitting` (M_L from the sensors), :mod:`.release` (what the
sponge keeps after the release, learned from executed probes), :mod:`.worker`
(the executions of one run), :mod:`.clusters` (the summary), :mod:`.report` (Markdown) and
:mod:`.driver` (:func:`run_protocol_bench`); :mod:`.env_states` runs the reach task from a
Gymnasium environment's hand-over states, for agents that act through its observation.
"""

from typing import Any

from rmi_learn.control_bench.feedback.protocol import CONTROLLERS, load_protocol


def __getattr__(name: str) -> Any:
    # The driver reads sweeps through modules that load torch; the report's section needs
    # only the table code, so the driver loads on first use.
    if name == "run_protocol_bench":
        from rmi_learn.control_bench.feedback.driver import run_protocol_bench

        globals()[name] = run_protocol_bench
        return run_protocol_bench
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["CONTROLLERS", "load_protocol", "run_protocol_bench"]
