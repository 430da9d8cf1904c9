"""The Gymnasium environment rmi_learn.sim.env.SpongeSqueezeEnv on a tiny sponge."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rmi_sph
from rmi_learn.data.schema import FORCE_LIMIT_N, OBS
from rmi_learn.sim.env import DEFAULT_MAX_EPISODE_STEPS, ENV_ID, SpongeSqueezeEnv
from rmi_learn.sim.goal import RELEASE_FRACTION
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def cfg() -> dict[str, Any]:
    return tiny_config()


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"action_mode": "force_velocity", "normalize_actions": True}],
)
def test_env_checker_passes(cfg: dict[str, Any], kwargs: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5, render_mode="rgb_array", **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice on unbounded/unnormalised Box spaces
        check_env(env)


def test_reset_hands_over_after_the_hold(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal_fraction=0.5)
    obs, info = env.reset(seed=0)
    assert obs.shape == (23,) and obs.dtype == np.float32 and np.all(np.isfinite(obs))
    assert env.observation_space.contains(obs)
    assert info["phase"] == "lift" and info["failure"] is None
    assert info["goal"] == pytest.approx(0.5 * info["M_L"])
    assert list(info["y"]) == list(OBS) and info["mask"].shape == (23,)
    assert env.substeps == 10 and env.control_period == pytest.approx(0.02)
    assert env.metadata["render_fps"] == pytest.approx(50.0)
    # Masked channels hold 0 in the observation and None in the named values.
    for k, name in enumerate(OBS):
        if not info["mask"][k]:
            assert obs[k] == 0.0 and info["y"][name] is None


def test_force_mode_is_the_default_and_the_force_loop_sets_v_cmd(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    box = env.action_space
    assert isinstance(box, gym.spaces.Box) and env.action_mode == "force"
    assert box.shape == (1,) and box.low[0] == 0.0 and box.high[0] == FORCE_LIMIT_N
    _, info0 = env.reset(seed=0)
    # Far above the hold: the loop closes the pads, at most at v_close.
    _, _, _, _, info = env.step(np.array([300.0], np.float32))
    assert env.sim is not None and env.sim.action == (300.0, None)
    assert info["F_target"] == 300.0
    assert 0.0 < info["v_cmd"] <= cfg["controller"]["v_close"]
    assert info["v_cmd"] == env.sim.observation()["v_cmd"]
    # Below the load now on the pads: the loop opens them.
    _, _, _, _, info = env.step(np.array([0.0], np.float32))
    assert info["F_target"] == 0.0 and info["v_cmd"] < 0.0


def test_force_velocity_episode_squeezes_to_the_end(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, action_mode="force_velocity")
    box = env.action_space
    assert isinstance(box, gym.spaces.Box) and box.shape == (2,)
    lo, hi = box.low, box.high
    assert list(lo) == [0.0, -np.float32(cfg["controller"]["v_open"])]
    assert list(hi) == [np.float32(FORCE_LIMIT_N), np.float32(cfg["controller"]["v_close"])]
    obs, info = env.reset(seed=0, options={"goal": 0.7})
    assert info["goal"] == 0.7
    t0, terminated, truncated = info["time"], False, False
    rewards: list[float] = []
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(np.array([150.0, 0.02], np.float32))
        if not rewards:
            assert info["v_cmd"] == pytest.approx(0.02)  # executed as given
        rewards.append(reward)
        assert reward == pytest.approx(-abs(info["M_L"] - 0.7))
        assert np.all(np.isfinite(obs))
    assert terminated and not truncated and info["phase"] == "done"
    assert info["time"] - t0 == pytest.approx(0.02 * len(rewards), abs=0.021)
    assert env.sim is not None and env.sim.action is not None
    assert env.sim.action[0] == 150.0 and env.sim.action[1] == pytest.approx(0.02)
    assert env.sim.outcome()["final_water"] == info["M_L"]


def test_normalised_actions_map_onto_the_physical_range(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, action_mode="force_velocity", normalize_actions=True)
    v_open, v_close = cfg["controller"]["v_open"], cfg["controller"]["v_close"]
    box = env.action_space
    assert isinstance(box, gym.spaces.Box) and box.shape == (2,)
    assert np.all(box.low == -1.0) and np.all(box.high == 1.0)
    np.testing.assert_allclose(env.physical_action([-1.0, -1.0]), [0.0, -v_open])
    np.testing.assert_allclose(env.physical_action([1.0, 1.0]), [FORCE_LIMIT_N, v_close])
    np.testing.assert_allclose(
        env.physical_action([0.0, 0.0]), [FORCE_LIMIT_N / 2, (v_close - v_open) / 2]
    )
    # Out of range is clipped to [-1, 1] before the mapping.
    np.testing.assert_allclose(env.physical_action([3.0, -7.0]), [FORCE_LIMIT_N, -v_open])
    force = SpongeSqueezeEnv(cfg, goal=0.5, normalize_actions=True)
    assert force.action_space.shape == (1,)
    np.testing.assert_allclose(force.physical_action([0.5]), [0.75 * FORCE_LIMIT_N])
    force.reset(seed=0)
    _, _, _, _, info = force.step(np.array([-1.0], np.float32))
    assert force.sim is not None and force.sim.action == (0.0, None) and info["F_target"] == 0.0
    # Unnormalised physical actions are clipped the same way.
    raw = SpongeSqueezeEnv(cfg, goal=0.5)
    np.testing.assert_allclose(raw.physical_action([1e6]), [FORCE_LIMIT_N])
    np.testing.assert_allclose(raw.physical_action([-5.0]), [0.0])


def test_the_time_limit_wrapper_alone_truncates(cfg: dict[str, Any]) -> None:
    assert gym.spec(ENV_ID).max_episode_steps == DEFAULT_MAX_EPISODE_STEPS
    # One simulator step per control step: the tiny episode is 351 control steps long,
    # more than the 200 the environment once cut every episode at.
    kw: dict[str, Any] = dict(config=cfg, goal=0.5, control_dt=cfg["dt"])
    a = np.array([100.0], np.float32)

    def run(max_steps: int) -> tuple[int, bool, bool]:
        env = gym.make(ENV_ID, max_episode_steps=max_steps, **kw)
        env.reset(seed=0)
        n, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            _, _, terminated, truncated, _ = env.step(a)
            n += 1
        env.close()
        return n, terminated, truncated

    assert run(250) == (250, False, True)
    n, terminated, truncated = run(1000)
    assert terminated and not truncated and 250 < n < 1000


def test_state_option_and_determinism(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    env.reset(seed=1)
    state = env.get_state()
    a = np.array([30.0], np.float32)
    out = [env.step(a) for _ in range(3)]
    assert not any(o[3] for o in out)  # the environment itself never truncates
    env2 = SpongeSqueezeEnv(cfg, goal=0.5, cache_handover=False)
    env2.reset(options={"state": state})
    for o in out:
        o2 = env2.step(a)
        assert np.array_equal(o[0], o2[0]) and o[1] == o2[1]
    with pytest.raises(RuntimeError):
        SpongeSqueezeEnv(cfg).step(a)


def test_default_goal_is_reached_by_a_strong_squeeze(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg)
    _, info = env.reset(seed=0)
    release = env.reference_release_kg
    assert release is not None and release > 0.0
    assert info["goal"] == pytest.approx(info["M_L"] - RELEASE_FRACTION * release)
    water, gap = info["M_L"], info["M_L"] - info["goal"]
    distances, least, terminated = [], water, False
    while not terminated:
        _, reward, terminated, truncated, info = env.step(np.array([350.0], np.float32))
        assert not truncated
        distances.append(-reward)
        least = min(least, info["M_L"])
    assert info["phase"] == "done" and info["failure"] is None
    # The retained water passes the goal: the reward comes close to 0 on the way ...
    assert min(distances) < 0.25 * gap
    # ... and the squeeze goes on past it, so squeezing hardest is not the answer.
    assert distances[-1] > 0.5 * gap
    # The former default, 80 % of the water at hand-over, is out of such a squeeze's reach.
    assert least > 0.8 * water


def test_goal_options_take_precedence(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.6, release_fraction=0.2)
    _, info = env.reset(seed=0)
    assert info["goal"] == 0.6 and env.reference_release_kg is None  # nothing measured
    _, info = env.reset(seed=0, options={"goal_fraction": 0.9})
    assert info["goal"] == pytest.approx(0.9 * info["M_L"])
    _, info = env.reset(seed=0, options={"goal": 0.3, "goal_fraction": 0.9})
    assert info["goal"] == 0.3
    frac = SpongeSqueezeEnv(cfg, goal_fraction=0.95)
    _, info = frac.reset(seed=0)
    assert info["goal"] == pytest.approx(0.95 * info["M_L"])


def test_rgb_array_render_draws_the_pads_moving(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first is not None and first.shape == (240, 320, 3) and first.dtype == np.uint8
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 3  # not a blank frame
    for _ in range(10):
        env.step(np.array([350.0], np.float32))
    later = env.render()
    assert later is not None and later.shape == first.shape
    assert np.count_nonzero(np.any(later != first, axis=2)) > 500
    small = SpongeSqueezeEnv(cfg, goal=0.5, render_mode="rgb_array", render_shape=(60, 80))
    small.reset(seed=0)
    frame = small.render()
    assert frame is not None and frame.shape == (60, 80, 3)


def test_render_mode_none_draws_nothing(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    env.reset(seed=0)
    assert env.render() is None and env._view is None


def test_make_vec_runs_two_envs(cfg: dict[str, Any]) -> None:
    envs = gym.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="sync", config=cfg, goal=0.5, max_episode_steps=50
    )
    assert envs.action_space.shape == (2, 1) and envs.observation_space.shape == (2, 23)
    obs, info = envs.reset(seed=0)  # seeds 0 and 1
    assert obs.shape == (2, 23) and obs.dtype == np.float32
    assert info["M_L"].shape == (2,) and info["M_L"][0] != info["M_L"][1]
    for _ in range(2):
        obs, reward, terminated, truncated, info = envs.step(np.full((2, 1), 200.0, np.float32))
        assert obs.shape == (2, 23) and reward.shape == (2,)
        assert terminated.shape == truncated.shape == (2,) and not terminated.any()
    np.testing.assert_allclose(info["F_target"], [200.0, 200.0])
    envs.close()


@pytest.mark.parametrize(
    "kwargs",
    [{"goal_fraction": 1.5}, {"goal_fraction": -0.1}, {"goal_fraction": float("nan")},
     {"goal": -0.01}, {"goal": float("inf")}, {"release_fraction": 1.5},
     {"action_mode": "velocity"}, {"render_mode": "human"}],
)  # fmt: skip
def test_bad_options_are_refused(cfg: dict[str, Any], kwargs: dict[str, Any]) -> None:
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        SpongeSqueezeEnv(cfg, **kwargs)


@pytest.mark.parametrize(
    ("mode", "bad"),
    [("force", ([80.0, 0.0], [[80.0]], [float("nan")], [])),
     ("force_velocity", ([80.0], [80.0, 0.0, 0.0], [[80.0, 0.0]], [float("nan"), 0.0]))],
)  # fmt: skip
def test_actions_of_the_wrong_size_are_refused(
    cfg: dict[str, Any], mode: str, bad: tuple[list[Any], ...]
) -> None:
    # One value must not be broadcast against the bounds into a whole action.
    env = SpongeSqueezeEnv(cfg, goal=0.5, action_mode=mode)
    env.reset(seed=0)
    sim, goal = env.sim, env.goal
    assert sim is not None
    with pytest.raises(ValueError, match="goal_fraction"):
        env.reset(options={"goal_fraction": 2.0})
    assert env.sim is sim and env.goal == goal  # the episode goes on untouched
    t0 = sim.time
    n = len(env.action_names)
    for a in bad:
        with pytest.raises(ValueError, match=f"{n} finite values"):
            env.step(np.array(a, np.float32))
    assert sim.time == t0
    # In range or not, a well-formed action is clipped to the action space and taken.
    env.step(np.full(n, 1e6, np.float32))
    assert sim.time > t0 and sim.action is not None and sim.action[0] == FORCE_LIMIT_N


def test_vector_copies_stay_different_after_an_autoreset(cfg: dict[str, Any]) -> None:
    envs = gym.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="sync", config=cfg, goal=0.5, max_episode_steps=2
    )
    envs.reset(seed=0)  # seeds 0 and 1
    a = np.full((2, 1), 200.0, np.float32)
    first = envs.step(a)[1]
    assert envs.step(a)[3].all()  # the second step truncates both copies
    assert envs.step(a)[1].tolist() == [0.0, 0.0]  # the autoreset step
    second = envs.step(a)[1]
    envs.close()
    assert first[0] != first[1]
    # The unseeded resets continue each copy's random stream: new episodes, still distinct.
    assert second[0] != second[1]
    assert second[0] != first[0] and second[1] != first[1]


def test_a_seeded_reset_is_reproducible_and_unseeded_resets_differ(cfg: dict[str, Any]) -> None:
    a = np.array([200.0], np.float32)

    def episode(env: SpongeSqueezeEnv, seed: int | None) -> tuple[float, float, int]:
        _, info = env.reset(seed=seed)
        assert env.sim is not None
        return info["M_L"], env.step(a)[1], int(env.sim.config["seed"])

    env = SpongeSqueezeEnv(cfg, goal=0.5)
    seeded = episode(env, 5)
    assert seeded[2] == 5  # a seeded reset's trial has that seed, as before
    drawn = [episode(env, None) for _ in range(2)]
    assert drawn[0][2] != drawn[1][2] and drawn[0][:2] != drawn[1][:2]
    assert 5 not in (drawn[0][2], drawn[1][2])
    assert episode(env, 5) == seeded  # bit for bit
    # The stream a seed starts is itself reproducible.
    other = SpongeSqueezeEnv(cfg, goal=0.5, cache_handover=False)
    assert episode(other, 5) == seeded
    assert episode(other, None) == drawn[0]


@pytest.mark.parametrize("seed", [-1, 2**63, 2**64, True])
def test_a_seed_out_of_the_engine_range_is_refused_and_changes_nothing(
    cfg: dict[str, Any], seed: Any
) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    env.reset(seed=3)
    sim, stream = env.sim, env.np_random.bit_generator.state
    with pytest.raises(ValueError) as exc:
        env.reset(seed=seed)
    message = str(exc.value)
    assert message.startswith(f"seed must be an integer in [0, {rmi_sph.SEED_MAX}]")
    assert env.sim is sim and env.np_random.bit_generator.state == stream


def test_a_state_of_another_config_is_refused(cfg: dict[str, Any], tmp_path: Any) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    env.reset(seed=0)
    sim, period = env.sim, env.control_period
    foreign = rmi_sph.Trial(tiny_config(dt=1e-3), num_threads=1)
    path = tmp_path / "foreign.state"
    foreign.save(path)
    with pytest.raises(ValueError, match=r'options\["state"\] .*`dt` differs') as exc:
        env.reset(options={"state": foreign.get_state()})
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match=r'options\["state_path"\] .*`dt` differs'):
        env.reset(options={"state_path": str(path)})
    assert env.sim is sim and env.control_period == period  # the episode goes on untouched
    # A state of the same config with another seed is one of this environment's episodes.
    same = rmi_sph.Trial(dict(cfg, seed=7), num_threads=1)
    _, info = env.reset(options={"state": same.get_state()})
    assert env.sim is not sim and info["phase"] == same.phase


@pytest.mark.parametrize(
    ("options", "error", "names"),
    [({"goal": True}, TypeError, ("goal", ">= 0 kg")),
     ({"goal": np.bool_(False)}, TypeError, ("goal", ">= 0 kg")),
     ({"goal": "0.5"}, TypeError, ("goal", ">= 0 kg")),
     ({"goal": 10**400}, ValueError, ("goal", ">= 0 kg")),
     ({"goal": -1.0}, ValueError, ("goal", ">= 0 kg")),
     ({"goal_fraction": None}, TypeError, ("goal_fraction", "[0, 1]")),
     ({"goal_kg": 0.3}, ValueError, ("'goal_kg'", "goal, goal_fraction, state, state_path")),
     ({"state": 3}, TypeError, ('options["state"]', "bytes")),
     ({"state_path": 3}, TypeError, ('options["state_path"]', "path")),
     ([("goal", 0.3)], TypeError, ("options", "dict"))],
)  # fmt: skip
def test_loose_reset_options_are_refused(
    cfg: dict[str, Any], options: Any, error: type[Exception], names: tuple[str, ...]
) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5)
    with pytest.raises(error) as exc:
        env.reset(options=options)
    message = str(exc.value)
    assert type(exc.value) is error and "\n" not in message
    for name in names:
        assert name in message


def test_complex_actions_are_refused(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5, action_mode="force_velocity")
    env.reset(seed=0)
    assert env.sim is not None
    t0 = env.sim.time
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no imaginary part may be dropped with a warning
        for bad in (np.array([80.0 + 1j, 0.0]), [80.0, 0j], np.array([80, None], dtype=object)):
            with pytest.raises(TypeError, match=r"action must be 2 finite values .*real"):
                env.step(bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="2 finite values.*shape \\(2, 2\\)") as exc:
            env.step(np.zeros((2, 2), np.float32))
        assert "\n" not in str(exc.value)
        with pytest.raises(ValueError, match="2 finite values"):
            env.step([10**400, 0.0])  # type: ignore[arg-type]
    assert env.sim.time == t0


def test_goal_of_the_constructor_must_be_a_number(cfg: dict[str, Any]) -> None:
    with pytest.raises(TypeError, match="goal must be"):
        SpongeSqueezeEnv(cfg, goal=True)
    with pytest.raises(TypeError, match="release_fraction must be in"):
        SpongeSqueezeEnv(cfg, release_fraction="0.5")  # type: ignore[arg-type]


@pytest.mark.parametrize("control_dt", [1e-9, 3e-3, 0.0201, 0.0, float("nan"), True])
def test_control_dt_must_be_whole_engine_steps(cfg: dict[str, Any], control_dt: Any) -> None:
    with pytest.raises((ValueError, TypeError), match=r"control_dt must be .*dt = 0\.002 s"):
        SpongeSqueezeEnv(cfg, control_dt=control_dt)


def test_control_dt_of_whole_engine_steps_is_taken(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, control_dt=3 * cfg["dt"])
    assert env.substeps == 3 and env.control_period == 3 * cfg["dt"]
    assert SpongeSqueezeEnv(cfg, control_dt=0.02 + 1e-12).substeps == 10


def test_the_sensor_mode_observes_what_the_gripper_measures_with_seeded_noise() -> None:
    from rmi_learn.sensing import SENSOR_NAMES

    env = SpongeSqueezeEnv(tiny_config(), observation_mode="sensors")
    assert env.observation_names == SENSOR_NAMES
    assert env.observation_space.shape == (len(SENSOR_NAMES),)
    obs, info = env.reset(seed=3)
    assert obs.shape == (len(SENSOR_NAMES),) and info["mask"].all()
    steps = [env.step(np.array([120.0], dtype=np.float32)) for _ in range(3)]
    again, _ = env.reset(seed=3)
    assert np.array_equal(obs, again)
    replay = [env.step(np.array([120.0], dtype=np.float32)) for _ in range(3)]
    assert np.array_equal(steps[-1][0], replay[-1][0])
    assert "M_L" not in env.observation_names and steps[-1][4]["M_L"] > 0.0
    plain = SpongeSqueezeEnv(tiny_config())
    assert plain.observation_names[0] == "M_L"


def test_an_unknown_observation_mode_or_a_bad_sensor_setting_is_refused() -> None:
    with pytest.raises(ValueError, match="observation_mode must be one of privileged, sensors"):
        SpongeSqueezeEnv(tiny_config(), observation_mode="camera")
    with pytest.raises(ValueError, match=r"sensors.wrist_N must be in \[0, 10.0\]"):
        SpongeSqueezeEnv(tiny_config(), observation_mode="sensors", sensors={"wrist_N": -1})


@pytest.mark.parametrize("mode", ["privileged", "sensors"])
def test_the_observation_space_bounds_what_physics_bounds_and_holds_every_observation(
    cfg: dict[str, Any], mode: str
) -> None:
    env = SpongeSqueezeEnv(cfg, goal=0.5, observation_mode=mode)
    space = env.observation_space
    bounded = {n: (float(lo), float(hi)) for n, lo, hi in
               zip(env.observation_names, space.low, space.high, strict=True)
               if np.isfinite(lo) or np.isfinite(hi)}  # fmt: skip
    flags = {"c": (0.0, 1.0), "r_stick": (0.0, 1.0), "r_slip": (0.0, 1.0), "r_mixed": (0.0, 1.0)}
    if mode == "sensors":
        assert bounded == flags  # noisy loads, areas and width may read below zero
    else:
        inf = float("inf")
        assert bounded == {**flags, "r_none": (0.0, 1.0), **{n: (0.0, inf) for n in
                           ("M_L", "S", "V_pore", "V_sponge", "w", "F_meas", "F_L", "F_R",
                            "A_L", "A_R", "v_res")}}  # fmt: skip
    obs, _ = env.reset(seed=0)
    seen = [obs]
    for f in (300.0, 0.0, 150.0):
        seen.append(env.step(np.array([f], np.float32))[0])
    assert all(space.contains(o) for o in seen)


@pytest.mark.parametrize("autoreset", ["NEXT_STEP", "SAME_STEP"])
def test_both_autoreset_modes_start_new_and_distinct_episodes(
    cfg: dict[str, Any], autoreset: str
) -> None:
    """Whole episodes of two copies through ``make_vec`` in each autoreset mode: the copies'
    episodes differ, and each copy's next episode differs from its first."""
    mode = gym.vector.AutoresetMode[autoreset]
    assert SpongeSqueezeEnv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    envs = gym.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="sync", config=cfg, goal=0.5,
        max_episode_steps=3, vector_kwargs={"autoreset_mode": mode},
    )  # fmt: skip
    first_obs, _ = envs.reset(seed=0)
    a = np.full((2, 1), 200.0, np.float32)
    for _ in range(2):
        envs.step(a)
    obs, _, _, truncated, info = envs.step(a)  # the third step ends both episodes
    assert truncated.all()
    if mode == gym.vector.AutoresetMode.SAME_STEP:
        # The new episodes' first observations come in the same step, the last ones in info.
        new_obs = obs
        assert info["final_obs"].shape == (2,) and info["_final_obs"].all()
        assert not np.array_equal(info["final_obs"][0], new_obs[0])
    else:
        new_obs, reward, *_ = envs.step(a)  # the autoreset step
        assert reward.tolist() == [0.0, 0.0]
    envs.close()
    assert not np.array_equal(new_obs[0], new_obs[1])
    assert not np.array_equal(new_obs[0], first_obs[0])
    assert not np.array_equal(new_obs[1], first_obs[1])
