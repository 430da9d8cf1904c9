"""Gymnasium environment: squeeze a held, water-filled sponge to a goal water mass.

``SpongeSqueezeEnv`` wraps one ``rmi_sph.Trial``. ``reset`` builds and soaks the
sponge and runs the scripted controller through settle, close, ramp and hold (until the lift
gate releases the lift), or starts from a saved state given in ``options``; from then on
every ``step(action)`` applies u_t = [F_target (N), v_cmd (m/s)] for one control step of
``CONTROL_DT`` = 20 ms (``round(0.02 / dt)`` simulator steps). The phase sequence (lift,
waiting, squeeze, done), the lift gate and the gripper guards keep running underneath.

Observation: the 23 values of y_t in ``schema.OBS`` order as float32, with the pad loads
averaged over the control step. ``v_res`` is undefined without contact (NaN in the engine
and in run files); the observation holds 0 there and ``info["mask"]`` (bool, 23) is False
for it, so a model can tell "no contact" from "zero slip". ``info["y"]`` has the values by
name (None where undefined), plus ``phase``, ``time`` (s), ``M_L`` and ``M_expelled`` (kg),
``goal`` (kg), ``failure`` (str or None) and ``unstable`` (bool).

Reward: ``-|M_L - goal|`` in kg, the distance of the retained water to the goal mass.
The goal is ``options["goal"]`` (kg) if given, else the constructor's ``goal``, else
``goal_fraction`` times the water retained at hand-over.

Episode end: ``terminated`` when the trial is over (squeeze completed, or a failure: the
sponge dropped or slipped out, the gate timed out) or the simulation became unstable
(``info["unstable"]``; the state stays at the last good step); ``truncated`` after
``max_episode_steps`` control steps.

Registered as ``rmi/SpongeSqueeze-v0`` on import of this module::

    import gymnasium as gym
    import rmi_learn.sim.env  # registers the id
    env = gym.make("rmi/SpongeSqueeze-v0", config=rmi_sph.trial_config(8, 0.6, 20, 40, 0.01))
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

import rmi_sph
from rmi_learn.data.schema import CONTROL_DT, FORCE_LIMIT_N, OBS, PHASES

ENV_ID = "rmi/SpongeSqueeze-v0"

ObsType = npt.NDArray[np.float32]
ActType = npt.NDArray[np.float32]


def _goal_mass(goal: Any) -> float:
    """A goal retained water mass (kg): finite and not negative."""
    g = float(goal)
    if not (math.isfinite(g) and g >= 0.0):
        raise ValueError(f"goal must be a retained water mass >= 0 kg, got {goal!r}")
    return g


def _goal_fraction(fraction: Any) -> float:
    """A goal as a fraction of the water retained at hand-over: in [0, 1]."""
    f = float(fraction)
    if not 0.0 <= f <= 1.0:
        raise ValueError(f"goal_fraction must be in [0, 1], got {fraction!r}")
    return f


class SpongeSqueezeEnv(gym.Env[ObsType, ActType]):
    """Squeeze a lifted sponge to a goal retained-water mass.

    Parameters
    ----------
    config : dict | str | os.PathLike, optional
        Trial configuration (see ``rmi_sph.Trial``); default
        ``rmi_sph.trial_config(10, 0.6, 40.0, 80.0)``.
    num_threads : int, default 1
        Engine threads per environment (results do not depend on it).
    goal : float, optional
        Goal retained water mass (kg).
    goal_fraction : float, default 0.8
        Goal as a fraction of the water retained at hand-over, when no goal is given.
    handover : str, default "lift"
        Phase from which the agent drives the gripper; earlier phases run scripted.
    max_episode_steps : int, default 200
        Control steps before truncation.
    control_dt : float, default ``schema.CONTROL_DT`` (0.02 s)
        Duration of one control step (rounded to whole simulator steps).
    regulate : bool, default False
        If True, ``v_cmd`` is ignored and the engine's force regulation (Eq. 5b) closes the
        pads toward ``F_target``.
    cache_handover : bool, default True
        Keep the hand-over state per seed, so repeated resets with one seed skip the
        scripted approach (the continuation is bit-identical either way).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        config: Any = None,
        *,
        num_threads: int | None = 1,
        goal: float | None = None,
        goal_fraction: float = 0.8,
        handover: str = "lift",
        max_episode_steps: int = 200,
        control_dt: float = CONTROL_DT,
        regulate: bool = False,
        cache_handover: bool = True,
    ) -> None:
        super().__init__()
        # Checked once here (trial_config returns a checked, complete config); every episode
        # builds its Trial from this dict.
        self.config: dict[str, Any] = (
            rmi_sph.trial_config(10, 0.6, 40.0, 80.0)
            if config is None
            else rmi_sph.validate_config(config)
        )
        if handover not in PHASES or handover in ("settle", "done"):
            raise ValueError(
                f"handover must be a phase from 'close' to 'squeeze', got {handover!r}"
            )
        if max_episode_steps < 1:
            raise ValueError("max_episode_steps must be at least 1")
        if not (control_dt > 0 and math.isfinite(control_dt)):
            raise ValueError("control_dt must be a positive time (s)")
        self.num_threads = num_threads
        self.default_goal = None if goal is None else _goal_mass(goal)
        self.goal_fraction = _goal_fraction(goal_fraction)
        self.handover = handover
        self.max_episode_steps = int(max_episode_steps)
        self.regulate = bool(regulate)
        self.cache_handover = cache_handover
        dt = float(self.config["dt"])
        #: Simulator steps per control step, and the resulting control period (s).
        self.substeps = max(1, round(control_dt / dt))
        self.control_period = self.substeps * dt
        ctrl = self.config["controller"]
        self._low = np.array([0.0, -float(ctrl["v_open"])], dtype=np.float32)
        self._high = np.array([FORCE_LIMIT_N, float(ctrl["v_close"])], dtype=np.float32)
        self.action_space = spaces.Box(low=self._low, high=self._high, dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(len(OBS),), dtype=np.float32)
        self.sim: rmi_sph.Trial | None = None
        self.goal = 0.0
        self.steps = 0
        self._cache: dict[int, bytes] = {}

    # ----------------------------------------------------------------------------------

    def _scripted_approach(self, seed: int) -> rmi_sph.Trial:
        if self.cache_handover and seed in self._cache:
            return rmi_sph.Trial.from_state(self._cache[seed], num_threads=self.num_threads)
        cfg = dict(self.config, seed=seed)
        sim = rmi_sph.Trial(cfg, num_threads=self.num_threads)
        before = set(PHASES[: PHASES.index(self.handover)])
        limit = sim.time_limit
        while sim.phase in before and sim.time <= limit:
            sim.step(1)
        sim.take_record()  # starts the first averaging interval at hand-over
        if self.cache_handover:
            self._cache[seed] = sim.get_state()
        return sim

    def _observe(
        self, record: Mapping[str, Any], unstable: bool = False
    ) -> tuple[ObsType, dict[str, Any]]:
        assert self.sim is not None
        raw = np.array([record[n] for n in OBS], dtype=np.float64)
        mask = np.isfinite(raw)
        obs = np.where(mask, raw, 0.0).astype(np.float32)
        info: dict[str, Any] = {
            "y": {n: (float(v) if ok else None) for n, v, ok in zip(OBS, raw, mask, strict=True)},
            "mask": mask,
            "phase": str(record["phase"]),
            "time": float(record["time"]),
            "M_L": float(record["M_L"]),
            "M_expelled": float(record["M_expelled"]),
            "goal": self.goal,
            "failure": self.sim.failure,
            "unstable": unstable,
        }
        return obs, info

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsType, dict[str, Any]]:
        """Start an episode (see the module docstring).

        ``options``: ``state`` (bytes of ``Trial.get_state()``) or ``state_path`` (a
        file of ``Trial.save``) to start from a saved state instead of the scripted
        approach; ``goal`` (kg) or ``goal_fraction``. ``seed`` seeds the pore-water jitter
        (default: the config's seed).
        """
        super().reset(seed=seed)
        options = dict(options or {})
        # Checked before any work, so a bad option leaves the current episode as it was.
        goal = _goal_mass(options["goal"]) if "goal" in options else self.default_goal
        frac = _goal_fraction(options.get("goal_fraction", self.goal_fraction))
        if "state" in options:
            self.sim = rmi_sph.Trial.from_state(options["state"], num_threads=self.num_threads)
        elif "state_path" in options:
            self.sim = rmi_sph.Trial.load(options["state_path"], num_threads=self.num_threads)
        else:
            self.sim = self._scripted_approach(int(self.config["seed"]) if seed is None else seed)
        record = self.sim.take_record()
        self.goal = frac * float(record["M_L"]) if goal is None else goal
        self.steps = 0
        return self._observe(record)

    def step(self, action: ActType) -> tuple[ObsType, float, bool, bool, dict[str, Any]]:
        """Apply u_t = [F_target, v_cmd] (clipped to the action space) for one control step."""
        if self.sim is None:
            raise RuntimeError("call reset() before step()")
        # Shape first: clipping against the two bounds would broadcast a single value into
        # a full action.
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be 2 finite values [F_target, v_cmd], got {action!r}")
        a = np.clip(a, self._low, self._high)
        self.sim.set_action(float(a[0]), None if self.regulate else float(a[1]))
        unstable = False
        try:
            self.sim.step(self.substeps)
        except rmi_sph.SimulationUnstableError:
            unstable = True
        record = self.sim.take_record()
        self.steps += 1
        obs, info = self._observe(record, unstable)
        reward = -abs(info["M_L"] - self.goal)
        terminated = bool(self.sim.finished or unstable)
        truncated = bool(not terminated and self.steps >= self.max_episode_steps)
        return obs, float(reward), terminated, truncated, info

    def get_state(self) -> bytes:
        """State of the running episode's simulation (for ``options={"state": ...}``)."""
        if self.sim is None:
            raise RuntimeError("call reset() first")
        return self.sim.get_state()

    def close(self) -> None:
        self.sim = None


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="rmi_learn.sim.env:SpongeSqueezeEnv")
