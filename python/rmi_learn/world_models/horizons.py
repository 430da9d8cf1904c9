"""The forecast horizons the world models are scored at: the steps reported in the tables
(:data:`HORIZON_STEPS`), the step of the main tables (:data:`MAIN_STEP`) and their labels in
seconds. Imports no torch, so the training settings can name a selection step."""

from __future__ import annotations

from rmi_learn.data.schema import CONTROL_DT

#: Forecast steps reported in the tables (0.16, 0.32, 0.64, 1.28 s at 20 ms).
HORIZON_STEPS: tuple[int, ...] = (8, 16, 32, 64)
#: The step of the main tables (0.64 s).
MAIN_STEP = 32


def horizon_label(step: int) -> str:
    """'0.64 s' for step 32 at 20 ms."""
    return f"{step * CONTROL_DT:.2f} s"
