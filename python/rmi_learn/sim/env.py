"""Gymnasium environment: squeeze a held, water-filled sponge to a goal water mass.

``SpongeSqueezeEnv`` wraps one ``rmi_sph.Trial``. ``reset`` builds and soaks the
sponge and runs the scripted controller through settle, close, ramp and hold (until the lift
gate releases the lift), or starts from a saved state given in ``options``; from then on
every ``step(action)`` drives the pads for one control step of ``CONTROL_DT`` = 20 ms
(``round(0.02 / dt)`` simulator steps). The phase sequence (lift, waiting, squeeze, done),
the lift gate and the gripper guards keep running underneath.

Actions (``action_mode``):

- ``"force"`` (default): ``[F_target]`` in [0, ``FORCE_LIMIT_N``] N (or ``force_range``).
  The engine's force loop (Eq. 5b) closes or opens the pads toward the target; the closing
  speed it chose is reported as ``info["v_cmd"]``.
- ``"force_velocity"``: ``[F_target (N), v_cmd (m/s)]``, v_cmd in [-v_open, v_close] of the
  config's controller (positive closes), executed as given (within the gripper's guards).

With ``normalize_actions=True`` every channel is in [-1, 1] and maps affinely onto its
physical range (-1 the lower bound, 1 the upper). Out-of-range values are clipped to the
action space (as gymnasium's ``ClipAction`` would); an action of the wrong shape or with a
NaN or inf raises ``ValueError``, one of values that are not real numbers (complex, text,
None) ``TypeError``.

Seeds: ``reset(seed=s)`` gives the episode of trial seed ``s``, the same every time; an
unseeded reset draws the trial's seed from the environment's ``np_random``, so episodes
differ from one reset to the next (see ``SpongeSqueezeEnv.reset``). Both are in
[0, ``SEED_MAX``] (2^63 - 1), the engine's range of seeds; with ``start_seeds=n`` unseeded
resets draw from the first ``n`` seeds only, whose hand-over states are cached, so that a
reset restores a state instead of running the scripted approach again.

Observation (``observation_mode``, names in ``env.observation_names``):

- ``"privileged"`` (default): the 23 values of y_t in ``schema.OBS`` order as float32, with
  the pad loads averaged over the control step. ``v_res`` is undefined without contact (NaN
  in the engine and in run files); the observation holds 0 there and ``info["mask"]`` is
  False for it, so a model can tell "no contact" from "zero slip".
- ``"sensors"``: what a parallel gripper with tactile pads and a wrist force/torque sensor
  measures (``rmi_learn.sensing.SENSOR_NAMES``: width, pad loads, contact areas and flag,
  shear, stick/slip flags, wrist load), through the noise and latency of ``sensors`` (a
  :class:`rmi_learn.sensing.SensorModel` or its fields; default its data-sheet defaults),
  seeded by the sensor model's seed and the episode's trial seed. No M_L, S, V_pore or
  V_sponge: the reward still scores the true M_L, which ``info`` carries for evaluation only.

With ``observe_goal=True`` either mode appends the episode's goal (kg) as a last channel
``goal``, which a goal-conditioned agent needs when goals differ between episodes.

The observation space is bounded where physics bounds a channel
(:func:`rmi_learn.sensing.observation_bounds`): in ``privileged`` masses, volumes, the width,
normal loads, contact areas and the slip speed are at least 0 and the flags within [0, 1];
in ``sensors`` only the flags, since a noisy reading near zero can fall below it.

Vector environments (``gym.make_vec``) may autoreset in either of gymnasium's modes
(``metadata["autoreset_mode"]`` declares NEXT_STEP, their default; ``vector_kwargs=
{"autoreset_mode": AutoresetMode.SAME_STEP}`` works as well): each copy's unseeded resets
continue its own seed stream, so copies stay different episodes after an autoreset.

``info["y"]`` has the y_t values by name (None where undefined), plus ``phase``, ``time``
(s), ``M_L`` and ``M_expelled`` (kg), ``F_target`` (N) and ``v_cmd`` (m/s) of the command
the engine applied last, ``goal`` (kg), ``failure`` (str or None) and ``unstable`` (bool).

Reward: ``-|M_L - goal|`` in kg, the distance of the retained water to the goal mass, less
``failure_cost`` (kg, default 0) in the step that ends the episode by a failure or an
instability, so that an agent cannot shorten its penalties by dropping the sponge.
The goal is, first match wins: ``options["goal"]`` (kg), ``options["goal_fraction"]``, the
constructor's ``goal``, its ``goal_fraction`` (times the water retained at hand-over), else
the reachable default of :mod:`rmi_learn.sim.goal`: the water retained at hand-over less
``release_fraction`` (0.5, or a fraction drawn per episode from a ``(low, high)`` range) of
the water a constant 300 N squeeze releases from the hand-over
of the config's seed to the end of the trial (measured once per environment, at the first
reset that needs it).

Episode end: ``terminated`` when the trial is over (squeeze completed, or a failure: the
sponge dropped or slipped out, the gate timed out) or the simulation became unstable
(``info["unstable"]``; the state stays at the last good step). The environment never
truncates: ``gym.make`` wraps it in ``TimeLimit`` with the registered
``max_episode_steps`` (``DEFAULT_MAX_EPISODE_STEPS``, 10 s of control) unless given another.

Rendering: ``render_mode="rgb_array"`` makes ``render()`` return a side view (x-z) of the
particles, an (H, W, 3) uint8 image (:mod:`rmi_learn.sim.render`); with ``render_mode=None``
it returns None and nothing is drawn.

Registered on import of this module, as the variants of :mod:`rmi_learn.sim.variants`:
``rmi/SpongeSqueeze-v0`` (the default sponge, for evaluation) and
``rmi/SpongeSqueezeFast-v0`` (a coarse sponge with goals drawn per episode, for learning)::

    import gymnasium as gym
    import rmi_learn.sim.env  # registers the ids
    env = gym.make("rmi/SpongeSqueeze-v0", config=rmi_sph.trial_config(8, 0.6, 20, 40, 0.01))
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

import rmi_sph
from rmi_learn.data.schema import CONTROL_DT, FORCE_LIMIT_N, OBS, PHASES, SEED_MAX, checked_seed
from rmi_learn.errors import InputError
from rmi_learn.sensing import (
    SensorModel,
    SensorStream,
    check_observation_mode,
    observation_bounds,
    observation_names,
)
from rmi_learn.sim.goal import (
    REFERENCE_SQUEEZE_N,
    RELEASE_FRACTION,
    goal_mass,
    reachable_goal,
    real_number,
    reference_release,
    shown,
    unit_fraction,
)
from rmi_learn.sim.render import View, side_view, view_of
from rmi_learn.sim.variants import (  # noqa: F401 (re-exported: the ids live with the env)
    DEFAULT_MAX_EPISODE_STEPS,
    ENV_ID,
    FAST_ENV_ID,
    register_variants,
)

#: Action modes and the names of their channels.
ACTION_MODES: dict[str, tuple[str, ...]] = {
    "force": ("F_target",),
    "force_velocity": ("F_target", "v_cmd"),
}
#: Default size (height, width) of a rendered frame (px).
RENDER_SHAPE = (240, 320)
#: The keys ``reset`` accepts in ``options``.
RESET_OPTIONS = ("goal", "goal_fraction", "state", "state_path")
#: How far (in engine steps) ``control_dt`` may be from a whole number of engine steps.
CONTROL_DT_TOLERANCE_STEPS = 1e-6

ObsType = npt.NDArray[np.float32]
ActType = npt.NDArray[np.float32]


class SpongeSqueezeEnv(gym.Env[ObsType, ActType]):
    """Squeeze a lifted sponge to a goal retained-water mass (see the module docstring).

    Parameters
    ----------
    config : dict | str | os.PathLike, optional
        Trial configuration (see ``rmi_sph.Trial``); default
        ``rmi_sph.trial_config(10, 0.6, 40.0, 80.0)``.
    num_threads : int, default 1
        Engine threads per environment (results do not depend on it).
    action_mode : {"force", "force_velocity"}, default "force"
        ``[F_target]`` (N) tracked by the engine's force loop, or ``[F_target, v_cmd]``
        (N, m/s) executed as given.
    normalize_actions : bool, default False
        If True the action space is [-1, 1] per channel, mapped affinely onto the physical
        range.
    goal : float, optional
        Goal retained water mass (kg).
    goal_fraction : float, optional
        Goal as a fraction of the water retained at hand-over, when no goal is given.
    release_fraction : float or (float, float), default ``goal.RELEASE_FRACTION`` (0.5)
        With neither goal nor goal_fraction: the part of the reference squeeze's release
        (``goal.REFERENCE_SQUEEZE_N`` = 300 N) the default goal asks for, in [0, 1]; a pair
        ``(low, high)`` draws it uniformly per episode from the environment's ``np_random``.
    handover : str, default "lift"
        Phase from which the agent drives the gripper; earlier phases run scripted.
    control_dt : float, default ``schema.CONTROL_DT`` (0.02 s)
        Duration of one control step: a whole number (>= 1) of the config's ``dt``, within
        ``CONTROL_DT_TOLERANCE_STEPS`` of a step.
    cache_handover : bool, default True
        Keep the hand-over state per seed given to ``reset`` (and of the config's seed, for
        the default goal), so repeated resets with one seed skip the scripted approach (the
        continuation is bit-identical either way). Seeds drawn by unseeded resets are not
        kept: they hardly ever come again.
    render_mode : {None, "rgb_array"}, default None
        ``"rgb_array"``: ``render()`` returns the side view of the particles.
    render_shape : (int, int), default (240, 320)
        Height and width of a rendered frame (px).
    observation_mode : {"privileged", "sensors"}, default "privileged"
        The simulator's y_t, or what the gripper's sensors report (module docstring).
    sensors : SensorModel or mapping of its fields, optional
        Noise and latency of the ``sensors`` mode (default: ``SensorModel()``).
    observe_goal : bool, default False
        Append the episode's goal (kg) to the observation as channel ``goal``.
    force_range : (float, float), optional
        Bounds of F_target (N), within [0, ``FORCE_LIMIT_N``]; default that whole range. The
        goal-reaching benchmark's controllers act within [0.8 F_hold, 400 N].
    failure_cost : float, default 0
        Subtracted from the reward (kg) of the step in which the trial fails or becomes
        unstable; at least 0.
    start_seeds : int, optional
        Unseeded resets draw the trial seed from [0, ``start_seeds``) and cache each seed's
        hand-over state (with ``cache_handover``); default: from [0, ``SEED_MAX``], uncached.
    """

    # A vector env autoresets a copy in the step after its episode ends (NEXT_STEP, the
    # vector envs' default) or in the same step (SAME_STEP); both keep copies apart.
    metadata: dict[str, Any] = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        config: Any = None,
        *,
        num_threads: int | None = 1,
        action_mode: str = "force",
        normalize_actions: bool = False,
        goal: float | None = None,
        goal_fraction: float | None = None,
        release_fraction: float = RELEASE_FRACTION,
        handover: str = "lift",
        control_dt: float = CONTROL_DT,
        cache_handover: bool = True,
        render_mode: str | None = None,
        render_shape: tuple[int, int] = RENDER_SHAPE,
        observation_mode: str = "privileged",
        sensors: SensorModel | Mapping[str, Any] | None = None,
        observe_goal: bool = False,
        force_range: tuple[float, float] | None = None,
        failure_cost: float = 0.0,
        start_seeds: int | None = None,
    ) -> None:
        super().__init__()
        try:
            self.observation_mode = check_observation_mode(observation_mode)
            self.sensors = (
                sensors if isinstance(sensors, SensorModel) else SensorModel.from_mapping(sensors)
            )
        except InputError as exc:  # one line naming the field, a ValueError like the others
            raise ValueError(str(exc)) from None
        self.observe_goal = bool(observe_goal)
        #: The observation's channel names, in order.
        self.observation_names: tuple[str, ...] = observation_names(self.observation_mode) + (
            ("goal",) if self.observe_goal else ()
        )
        self.start_seeds = None if start_seeds is None else seed_count(start_seeds)
        self.failure_cost = real_number("failure_cost", failure_cost, "a cost >= 0 kg")
        if not (math.isfinite(self.failure_cost) and self.failure_cost >= 0.0):
            raise ValueError(f"failure_cost must be a cost >= 0 kg, got {failure_cost!r}")
        self._stream: SensorStream | None = None
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
        if action_mode not in ACTION_MODES:
            raise ValueError(
                f"action_mode must be one of {list(ACTION_MODES)}, got {action_mode!r}"
            )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_threads = num_threads
        self.default_goal = None if goal is None else goal_mass(goal)
        self.goal_fraction = (
            None if goal_fraction is None else unit_fraction("goal_fraction", goal_fraction)
        )
        self.release_fraction = release_range(release_fraction)
        self.handover = handover
        self.cache_handover = cache_handover
        dt = float(self.config["dt"])
        #: Simulator steps per control step, and the resulting control period (s).
        self.substeps = substeps_per_control(control_dt, dt)
        self.control_period = self.substeps * dt
        # Frames are one control step apart; an instance attribute, as it follows control_dt.
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.control_period}
        self.render_mode = render_mode
        self.render_shape = (int(render_shape[0]), int(render_shape[1]))

        self.action_mode = action_mode
        self.action_names = ACTION_MODES[action_mode]
        ctrl = self.config["controller"]
        bounds = {
            "F_target": checked_force_range(force_range),
            "v_cmd": (-ctrl["v_open"], ctrl["v_close"]),
        }
        #: The physical action range, per channel (N or m/s).
        self.action_low = np.array([bounds[n][0] for n in self.action_names], dtype=np.float64)
        self.action_high = np.array([bounds[n][1] for n in self.action_names], dtype=np.float64)
        self.normalize_actions = bool(normalize_actions)
        k = len(self.action_names)
        if self.normalize_actions:
            self.action_space = spaces.Box(-1.0, 1.0, shape=(k,), dtype=np.float32)
        else:
            self.action_space = spaces.Box(
                self.action_low.astype(np.float32), self.action_high.astype(np.float32)
            )
        low, high = observation_bounds(self.observation_mode)
        if self.observe_goal:
            low, high = np.append(low, np.float32(0.0)), np.append(high, np.float32(np.inf))
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self.sim: rmi_sph.Trial | None = None
        self.goal = 0.0
        #: Water (kg) the reference squeeze releases from the config seed's hand-over;
        #: measured at the first reset that needs the default goal.
        self.reference_release_kg: float | None = None
        self._cache: dict[int, bytes] = {}
        self._view: View | None = None

    # ----------------------------------------------------------------------------------

    def _scripted_approach(self, seed: int, keep: bool) -> rmi_sph.Trial:
        """The trial of ``seed`` at hand-over; ``keep``: cache its state (``cache_handover``)."""
        if self.cache_handover and seed in self._cache:
            return rmi_sph.Trial.from_state(self._cache[seed], num_threads=self.num_threads)
        cfg = dict(self.config, seed=seed)
        sim = rmi_sph.Trial(cfg, num_threads=self.num_threads)
        before = set(PHASES[: PHASES.index(self.handover)])
        limit = sim.time_limit
        while sim.phase in before and sim.time <= limit:
            sim.step(1)
        sim.take_record()  # starts the first averaging interval at hand-over
        if self.cache_handover and keep:
            self._cache[seed] = sim.get_state()
        return sim

    def prepare_start_states(self) -> int:
        """Run the scripted approach of every seed of the ``start_seeds`` pool not cached yet
        and cache its hand-over state, so that every later unseeded reset restores one (as a
        vector env's ``call("prepare_start_states")`` does in each copy before a timed run).
        Returns the number of cached states; 0 without a pool or ``cache_handover``."""
        if self.start_seeds is None or not self.cache_handover:
            return 0
        for seed in range(self.start_seeds):
            if seed not in self._cache:
                self._scripted_approach(seed, keep=True)
        return len(self._cache)

    def _reference_release(self) -> float:
        if self.reference_release_kg is None:
            sim = self._scripted_approach(int(self.config["seed"]), keep=True)
            self.reference_release_kg = reference_release(sim, REFERENCE_SQUEEZE_N, self.substeps)
        return self.reference_release_kg

    def _observe(
        self, record: Mapping[str, Any], unstable: bool = False
    ) -> tuple[ObsType, dict[str, Any]]:
        assert self.sim is not None
        raw = y_values(record)
        mask = np.isfinite(raw)
        seen = None if self._stream is None else self._stream.observe(record)
        obs, obs_mask = observation_vector(raw, seen, self.goal if self.observe_goal else None)
        info: dict[str, Any] = {
            "y": {n: (float(v) if ok else None) for n, v, ok in zip(OBS, raw, mask, strict=True)},
            "mask": obs_mask,
            "phase": str(record["phase"]),
            "time": float(record["time"]),
            "M_L": float(record["M_L"]),
            "M_expelled": float(record["M_expelled"]),
            "F_target": float(record["F_target"]),
            "v_cmd": float(record["v_cmd"]),
            "goal": self.goal,
            "failure": self.sim.failure,
            "unstable": unstable,
        }
        return obs, info

    def physical_action(self, action: Any) -> npt.NDArray[np.float64]:
        """The physical action (N, m/s) an ``action`` of the action space stands for: clipped
        to the space, then mapped from [-1, 1] when actions are normalised. Raises
        ``ValueError`` for a wrong shape or a NaN or inf, ``TypeError`` for values that are
        not real numbers (complex, text, None)."""
        a = self._action_values(action)
        if self.normalize_actions:
            u = 0.5 * (np.clip(a, -1.0, 1.0) + 1.0)
            return self.action_low + u * (self.action_high - self.action_low)
        return np.clip(a, self.action_low, self.action_high)

    def _action_values(self, action: Any) -> npt.NDArray[np.float64]:
        """``action`` as its finite float64 values, checked (see ``physical_action``)."""
        k = len(self.action_names)
        expected = f"action must be {k} finite values [{', '.join(self.action_names)}]"
        try:
            raw = np.asarray(action)
        except ValueError:  # nested lists of unequal lengths
            raise ValueError(f"{expected}, got {shown(action)}") from None
        # Shape first: clipping against the bounds would broadcast a single value into a
        # full action.
        if raw.shape != (k,):
            raise ValueError(f"{expected}, got shape {raw.shape}")
        kind = raw.dtype.kind
        if not (kind in "biuf" or (kind == "O" and all(isinstance(x, numbers.Real) for x in raw))):
            # Converting a complex value would drop its imaginary part with only a warning.
            raise TypeError(f"{expected} of real numbers, got {shown(action)}")
        try:
            a = raw.astype(np.float64)
        except OverflowError:  # an integer beyond the float range
            raise ValueError(f"{expected}, got {shown(action)}") from None
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{expected}, got {shown(action)}")
        return a

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsType, dict[str, Any]]:
        """Start an episode (see the module docstring).

        ``options`` (keys among ``RESET_OPTIONS``): ``state`` (bytes of
        ``Trial.get_state()``) or ``state_path`` (a file of ``Trial.save``) to start from a
        saved state of this environment's config (any seed) instead of the scripted
        approach; ``goal`` (kg) or ``goal_fraction``. Another key, a value of the wrong
        kind or out of range, a ``seed`` outside [0, ``SEED_MAX``] and a state of another
        config raise ``ValueError`` or ``TypeError`` and leave the running episode as it was.

        ``seed`` seeds the environment's random stream ``np_random`` (as gymnasium's
        ``Env.reset`` does) and is the seed of the episode's trial (its pore-water jitter),
        so a seeded reset gives the same episode every time. Without a seed the trial's
        seed is drawn from that stream: successive episodes differ, and copies of a vector
        environment, seeded apart, stay apart after their autoresets. A stream never seeded
        starts from fresh entropy, as in gymnasium.
        """
        if seed is not None:
            seed = checked_seed(seed)
        options = self._checked_options(options)
        goal, frac = options.get("goal"), options.get("goal_fraction")
        if goal is None and frac is None:
            goal, frac = self.default_goal, self.goal_fraction
        use_default = goal is None and frac is None
        release = self._reference_release() if use_default else 0.0
        super().reset(seed=seed)
        sim = self._starting_trial(seed, options)
        record = sim.take_record()
        self.sim = sim
        self._stream = (
            SensorStream(self.sensors, (int(sim.config["seed"]),))
            if self.observation_mode == "sensors"
            else None
        )
        water = float(record["M_L"])
        if goal is not None:
            self.goal = goal
        elif frac is not None:
            self.goal = frac * water
        else:
            low, high = self.release_fraction
            fraction = low if high == low else float(self.np_random.uniform(low, high))
            self.goal = reachable_goal(water, release, fraction)
        self._view = view_of(self.sim, self.render_shape) if self.render_mode else None
        return self._observe(record)

    def _checked_options(self, options: Any) -> dict[str, Any]:
        """The ``options`` of ``reset``, checked before anything changes: None or a dict of
        ``RESET_OPTIONS`` keys, with the goals as floats."""
        if options is None:
            return {}
        accepted = ", ".join(RESET_OPTIONS)
        if not isinstance(options, Mapping):
            raise TypeError(
                f"options must be a dict with keys among {accepted} (or None), "
                f"got {shown(options)} ({type(options).__name__})"
            )
        unknown = [shown(k) for k in options if k not in RESET_OPTIONS]
        if unknown:
            raise ValueError(f"options has unknown keys {', '.join(unknown)}; accepted: {accepted}")
        checked = dict(options)
        if "state" in options and not isinstance(options["state"], (bytes, bytearray)):
            state = options["state"]
            raise TypeError(
                'options["state"] must be bytes of get_state(), '
                f"got {shown(state)} ({type(state).__name__})"
            )
        if "state_path" in options and not isinstance(options["state_path"], (str, os.PathLike)):
            path = options["state_path"]
            raise TypeError(
                'options["state_path"] must be the path (str or os.PathLike) of a state file, '
                f"got {shown(path)} ({type(path).__name__})"
            )
        if "goal" in options:
            checked["goal"] = goal_mass(options["goal"], 'options["goal"]')
        if "goal_fraction" in options:
            frac = options["goal_fraction"]
            checked["goal_fraction"] = unit_fraction('options["goal_fraction"]', frac)
        return checked

    def _starting_trial(self, seed: int | None, options: Mapping[str, Any]) -> rmi_sph.Trial:
        """The trial an episode starts from: a saved state of ``options`` (of this config),
        else the scripted approach of ``seed`` or of a seed drawn from ``np_random``."""
        if "state" in options:
            sim = rmi_sph.Trial.from_state(options["state"], num_threads=self.num_threads)
            return self._of_this_config('options["state"]', sim)
        if "state_path" in options:
            sim = rmi_sph.Trial.load(options["state_path"], num_threads=self.num_threads)
            return self._of_this_config('options["state_path"]', sim)
        if seed is None:
            pooled = self.start_seeds is not None
            seed = int(self.np_random.integers(self.start_seeds if pooled else SEED_MAX + 1))
            return self._scripted_approach(seed, keep=pooled)
        return self._scripted_approach(seed, keep=True)

    def _of_this_config(self, name: str, sim: rmi_sph.Trial) -> rmi_sph.Trial:
        """``sim`` if its config is this environment's, seed aside (every episode has its
        own); a ``ValueError`` naming ``name`` and the first differing field otherwise, as
        ``Trial.set_state`` compares: a state of another ``dt`` would change the control
        step unseen."""
        diff = config_difference({**self.config, "seed": 0}, {**sim.config, "seed": 0})
        if diff is not None:
            field, mine, theirs = diff
            raise ValueError(
                f"{name} is a state of another config (`{field}` differs: {shown(theirs)} in "
                f"the state, {shown(mine)} in this environment's)"
            )
        return sim

    def step(self, action: ActType) -> tuple[ObsType, float, bool, bool, dict[str, Any]]:
        """Apply ``action`` (see the module docstring) for one control step."""
        if self.sim is None:
            raise RuntimeError("call reset() before step()")
        a = self.physical_action(action)
        self.sim.set_action(float(a[0]), float(a[1]) if len(a) > 1 else None)
        unstable = False
        try:
            self.sim.step(self.substeps)
        except rmi_sph.SimulationUnstableError:
            unstable = True
        record = self.sim.take_record()
        obs, info = self._observe(record, unstable)
        reward = -abs(info["M_L"] - self.goal)
        if unstable or self.sim.failure is not None:
            reward -= self.failure_cost
        terminated = bool(self.sim.finished or unstable)
        return obs, float(reward), terminated, False, info

    def render(self) -> npt.NDArray[np.uint8] | None:
        """The side view of the particles (``render_mode="rgb_array"``), else None."""
        if self.render_mode is None:
            return None
        if self.sim is None or self._view is None:
            raise RuntimeError("call reset() before render()")
        return side_view(self.sim, self._view)

    def get_state(self) -> bytes:
        """State of the running episode's simulation (for ``options={"state": ...}``)."""
        if self.sim is None:
            raise RuntimeError("call reset() first")
        return self.sim.get_state()

    def close(self) -> None:
        self.sim = None


def y_values(record: Mapping[str, Any]) -> npt.NDArray[np.float64]:
    """An engine ``record``'s y_t in ``OBS`` order, NaN where a channel is undefined."""
    return np.array([record[n] for n in OBS], dtype=np.float64)


def observation_vector(
    y: npt.NDArray[np.float64], sensed: npt.NDArray[np.float64] | None, goal: float | None = None
) -> tuple[ObsType, npt.NDArray[np.bool_]]:
    """The observation an environment shows and its mask: the sensors' reading ``sensed``
    (``SENSOR_NAMES`` order) in the ``sensors`` mode, else y_t ``y`` (:func:`y_values`) with
    0 where undefined; ``goal`` (kg) appended when given (``observe_goal``). A controller run
    outside the environment (the goal-reaching benchmark's episodes) builds an agent's input
    with it."""
    if sensed is not None:
        obs, mask = sensed.astype(np.float32), np.ones(sensed.size, dtype=bool)
    else:
        mask = np.isfinite(y)
        obs = np.where(mask, y, 0.0).astype(np.float32)
    if goal is not None:
        obs, mask = np.append(obs, np.float32(goal)), np.append(mask, True)
    return obs, mask


def release_range(value: Any) -> tuple[float, float]:
    """``release_fraction`` as its ``(low, high)`` range in [0, 1] (a single fraction is a
    range of one value); a ``ValueError`` or ``TypeError`` naming the field otherwise."""
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise ValueError(
                f"release_fraction must be a fraction or a (low, high) pair, got {shown(value)}"
            )
        low = unit_fraction("release_fraction[0]", value[0])
        high = unit_fraction("release_fraction[1]", value[1])
        if low > high:
            raise ValueError(f"release_fraction must have low <= high, got {shown(value)}")
        return low, high
    f = unit_fraction("release_fraction", value)
    return f, f


def checked_force_range(value: Any) -> tuple[float, float]:
    """``force_range`` as ``(low, high)`` N within [0, ``FORCE_LIMIT_N``], low < high (None:
    that whole range); a ``ValueError`` or ``TypeError`` naming the field otherwise."""
    if value is None:
        return 0.0, FORCE_LIMIT_N
    accepted = f"a (low, high) pair of forces in [0, {FORCE_LIMIT_N:g}] N with low < high"
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"force_range must be {accepted}, got {shown(value)}")
    low = real_number("force_range[0]", value[0], accepted)
    high = real_number("force_range[1]", value[1], accepted)
    if not 0.0 <= low < high <= FORCE_LIMIT_N:
        raise ValueError(f"force_range must be {accepted}, got {shown(value)}")
    return low, high


def seed_count(value: Any) -> int:
    """``start_seeds`` as a count of seeds in [1, ``SEED_MAX``]; a ``ValueError`` (a
    ``TypeError`` for a value that is not an integer) naming the field otherwise."""
    accepted = f"an integer in [1, {SEED_MAX}]"
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"start_seeds must be {accepted}, got {shown(value)}")
    if not 1 <= int(value) <= SEED_MAX:
        raise ValueError(f"start_seeds must be {accepted}, got {value!r}")
    return int(value)


def substeps_per_control(control_dt: Any, dt: float) -> int:
    """Engine steps in a control step of ``control_dt`` (s) at the engine's ``dt`` (s): a
    whole number >= 1, within ``CONTROL_DT_TOLERANCE_STEPS`` of ``control_dt / dt``; a
    ``ValueError`` (``TypeError`` for a value that is not a real number) naming
    ``control_dt`` and the accepted values otherwise."""
    accepted = (
        f"a whole number (>= 1) of the config's dt = {dt} s "
        f"(within {CONTROL_DT_TOLERANCE_STEPS:g} of a step)"
    )
    steps = real_number("control_dt", control_dt, accepted) / dt
    n = round(steps) if math.isfinite(steps) else 0
    if n < 1 or abs(steps - n) > CONTROL_DT_TOLERANCE_STEPS:
        raise ValueError(f"control_dt must be {accepted}, got {control_dt!r} s")
    return n


def config_difference(mine: Any, theirs: Any, path: str = "") -> tuple[str, Any, Any] | None:
    """The first field in which two configs (dicts as ``Trial.config`` gives them) differ:
    its dotted path and its two values (``"missing"`` where one has no such field), or
    None when they are equal."""
    if isinstance(mine, Mapping) and isinstance(theirs, Mapping):
        for key in [*mine, *(k for k in theirs if k not in mine)]:
            field = f"{path}.{key}" if path else str(key)
            if key not in mine or key not in theirs:
                return field, mine.get(key, "missing"), theirs.get(key, "missing")
            found = config_difference(mine[key], theirs[key], field)
            if found is not None:
                return found
        return None
    if isinstance(mine, list) and isinstance(theirs, list) and len(mine) == len(theirs):
        for i, (a, b) in enumerate(zip(mine, theirs, strict=True)):
            found = config_difference(a, b, f"{path}[{i}]")
            if found is not None:
                return found
        return None
    return None if mine == theirs else (path or "config", mine, theirs)


register_variants()
