"""Goal-reaching benchmark executed in the simulator (``rmi control-bench``).

It separates "the policy proposes nothing better" from "the scorer cannot find it": every
controller is executed in the SPH engine from the same start states toward the same goals,
and the executed terminal water error is compared.

- Executed action: a chunk's H force setpoints F_target, each held for one 20 ms control
  step and tracked by the engine's force loop (:mod:`rmi_learn.sim.execute`); v_cmd is the
  force loop's own output and is not executed.
- Start states: held-out windows (test split, else validation) whose anchor lies in an
  acting phase (hold, lift, waiting, squeeze), rebuilt by deterministic replay of the run
  (:mod:`rmi_learn.sim.replay`), drawn in a seeded order and deduplicated by a fingerprint
  of the physical state (:mod:`rmi_learn.sim.fingerprint`).
- Goals: a sweep of constant setpoints from 0.8 F_hold to the force limit gives the
  reachable interval of terminal M_L; goals are drawn uniformly inside it, and the logged
  goal (M_L at t + H) is reported apart.
- Controllers: ``recorded``, ``constant-best`` (hindsight), ``first-sample/<policy>``,
  ``ranked-<scorer>/<policy>``, ``best-of-k/<policy>`` (the ceiling of ranking) and
  ``receding-<n>/<policy>`` (re-planning every n control steps from the observed history).

Modules: :mod:`.inputs` (policies, scorers, candidate start states, goals),
:mod:`.controllers` (the controllers of one start state), :mod:`.checkpoint` (the
checkpointed rows), :mod:`.driver` (:func:`run_control_bench`), :mod:`.measures` (the
statistics, table and figures) and :mod:`.rerank` (ranking the executed samples again);
:mod:`.feedback` runs the benchmark under a committed protocol with the feedback baselines
and the sensor mode (``rmi control-bench --protocol``).
"""

from typing import Any

#: Public name -> module of the model-based benchmark. They load on first use, so that the
#: torch-free protocol benchmark (:mod:`.feedback`) imports without torch.
_LAZY = {
    "SETPOINT_LOW_FRACTION": "rmi_learn.control_bench.controllers",
    "run_control_bench": "rmi_learn.control_bench.driver",
    "ACTING_PHASES": "rmi_learn.control_bench.inputs",
    "ControlBenchError": "rmi_learn.control_bench.inputs",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ACTING_PHASES",
    "SETPOINT_LOW_FRACTION",
    "ControlBenchError",
    "run_control_bench",
]
