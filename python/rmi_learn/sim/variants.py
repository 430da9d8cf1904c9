"""The registered variants of the Gymnasium environment.

- ``rmi/SpongeSqueeze-v0``: the constructor's defaults (the 10 cm sponge at r = 5 mm unless
  given a ``config``), handed over at the lift with one fixed reachable goal: the sponge a
  controller is evaluated on.
- ``rmi/SpongeSqueezeFast-v0``: a coarse sponge for learning (:func:`fast_config`: 8 cm,
  r = 12 mm, dt = 4 ms), handed over at the start of the squeeze, lifted, for the 32 control
  steps (0.64 s) the goal-reaching benchmark scores its reach task after; the goal is drawn
  per episode between the water at hand-over and what a 300 N squeeze releases, and observed
  as the last channel; unseeded resets draw among 64 trial seeds whose hand-over states are
  cached. F_target is bounded to [0.8 F_hold, 400 N], the benchmark's setpoint range, within
which the sponge stays held at any constant setpoint (switching fast between the bounds can
still drop it, which costs the episode ``FAST_FAILURE_COST_KG``). Its rate is in
docs/benchmarks.md (``benches/bench_env_rate.py``).

Only ids and keyword arguments live here, so the module loads without the environment and
the environment registers the variants on import.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

import rmi_sph

ENV_ID = "rmi/SpongeSqueeze-v0"
FAST_ENV_ID = "rmi/SpongeSqueezeFast-v0"
ENTRY_POINT = "rmi_learn.sim.env:SpongeSqueezeEnv"
#: Control steps before ``gym.make``'s ``TimeLimit`` truncates (10 s at 20 ms).
DEFAULT_MAX_EPISODE_STEPS = 500
#: Control steps of the fast variant's episode: the trial ends with them (20 ms each).
FAST_EPISODE_STEPS = 32
#: The fast variant's holding force (N); its agent acts within [0.8, 5] times it.
FAST_HOLD_N = 80.0
#: The fast variant's cost of a failure (kg): more than a whole episode of the largest error.
FAST_FAILURE_COST_KG = 2.0
#: Trial seeds the fast variant's unseeded resets draw from; evaluate on seeds above them.
FAST_START_SEEDS = 64


def fast_config(seed: int = 0) -> dict[str, Any]:
    """The fast variant's trial config: the 8 cm sponge, porosity 0.6, F_hold 80 N, at
    r = 12 mm and dt = 4 ms (5 engine steps per control step), with the control grid's short
    approach and a squeeze phase of ``FAST_EPISODE_STEPS`` control steps."""
    squeeze_s = FAST_EPISODE_STEPS * 0.02
    return rmi_sph.trial_config(
        8,
        0.6,
        FAST_HOLD_N,
        2.0 * FAST_HOLD_N,
        0.012,
        seed=seed,
        dt=0.004,
        settle_time=0.05,
        ramp_time=0.8,
        hold_time=0.6,
        gate_timeout=0.5,
        wait_time=0.1,
        squeeze_ramp_time=0.5 * squeeze_s,
        squeeze_hold_time=0.5 * squeeze_s,
    )


def variants() -> dict[str, dict[str, Any]]:
    """Each variant's id -> its ``kwargs`` and ``max_episode_steps``."""
    return {
        ENV_ID: {"kwargs": {}, "max_episode_steps": DEFAULT_MAX_EPISODE_STEPS},
        FAST_ENV_ID: {
            "kwargs": {
                "config": fast_config(),
                "handover": "squeeze",
                "release_fraction": (0.0, 1.0),
                "observe_goal": True,
                "force_range": (0.8 * FAST_HOLD_N, 400.0),
                "start_seeds": FAST_START_SEEDS,
                "failure_cost": FAST_FAILURE_COST_KG,
            },
            # The trial ends after its squeeze; the limit only guards a longer config.
            "max_episode_steps": 2 * FAST_EPISODE_STEPS,
        },
    }


def register_variants() -> None:
    """Register every variant not registered yet."""
    for env_id, spec in variants().items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, **spec)


__all__ = [
    "DEFAULT_MAX_EPISODE_STEPS",
    "ENV_ID",
    "FAST_ENV_ID",
    "FAST_EPISODE_STEPS",
    "FAST_START_SEEDS",
    "fast_config",
    "register_variants",
    "variants",
]
