"""What the robot observes: the observation modes (the simulator's full interaction state,
or what a parallel gripper with tactile pads and a wrist force/torque sensor measures), the
sensors' noise and latency, and estimates of the retained water from the sensors."""

from rmi_learn.sensing.modes import (
    OBSERVATION_MODES,
    PRIVILEGED_NAMES,
    SENSOR_NAMES,
    check_observation_mode,
    observation_bounds,
    observation_names,
)
from rmi_learn.sensing.sensor_model import SensorModel, SensorStream, observe_rows
from rmi_learn.sensing.weight import STANDARD_GRAVITY, dry_mass, weight_estimate

__all__ = [
    "OBSERVATION_MODES",
    "PRIVILEGED_NAMES",
    "SENSOR_NAMES",
    "STANDARD_GRAVITY",
    "SensorModel",
    "SensorStream",
    "check_observation_mode",
    "dry_mass",
    "observation_bounds",
    "observation_names",
    "observe_rows",
    "weight_estimate",
]
