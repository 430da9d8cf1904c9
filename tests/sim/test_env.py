"""The Gymnasium environment rmi_learn.sim.env.SpongeSqueezeEnv on a tiny sponge."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from rmi_learn.data.schema import OBS
from rmi_learn.sim.env import ENV_ID, SpongeSqueezeEnv
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def cfg() -> dict[str, Any]:
    return tiny_config()


def test_env_checker_passes(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, max_episode_steps=5)
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
    # Masked channels hold 0 in the observation and None in the named values.
    for k, name in enumerate(OBS):
        if not info["mask"][k]:
            assert obs[k] == 0.0 and info["y"][name] is None


def test_episode_squeezes_to_the_end(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, max_episode_steps=200)
    obs, info = env.reset(seed=0, options={"goal": 0.7})
    assert info["goal"] == 0.7
    t0, rewards, terminated, truncated = info["time"], [], False, False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(np.array([150.0, 0.02], np.float32))
        rewards.append(reward)
        assert reward == pytest.approx(-abs(info["M_L"] - 0.7))
        assert np.all(np.isfinite(obs))
    assert terminated and not truncated and info["phase"] == "done"
    assert info["time"] - t0 == pytest.approx(0.02 * len(rewards), abs=0.021)
    assert env.sim is not None and env.sim.action is not None
    assert env.sim.action[0] == 150.0 and env.sim.action[1] == pytest.approx(0.02)
    assert env.sim.outcome()["final_water"] == info["M_L"]


def test_truncation_state_option_and_determinism(cfg: dict[str, Any]) -> None:
    env = SpongeSqueezeEnv(cfg, max_episode_steps=3)
    env.reset(seed=1)
    state = env.get_state()
    a = np.array([30.0, 0.0], np.float32)
    out = [env.step(a) for _ in range(3)]
    assert [o[3] for o in out] == [False, False, True]
    env2 = SpongeSqueezeEnv(cfg, max_episode_steps=3, cache_handover=False)
    env2.reset(options={"state": state})
    for o in out:
        o2 = env2.step(a)
        assert np.array_equal(o[0], o2[0]) and o[1] == o2[1]
    with pytest.raises(ValueError):
        env2.step(np.zeros(3, np.float32))
    with pytest.raises(RuntimeError):
        SpongeSqueezeEnv(cfg).step(a)


def test_registered_with_gymnasium(cfg: dict[str, Any]) -> None:
    env = gym.make(ENV_ID, config=cfg, max_episode_steps=2)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (23,)
    env.close()


@pytest.mark.parametrize(
    "kwargs",
    [{"goal_fraction": 1.5}, {"goal_fraction": -0.1}, {"goal_fraction": float("nan")},
     {"goal": -0.01}, {"goal": float("inf")}],
)  # fmt: skip
def test_goals_out_of_range_are_refused(cfg: dict[str, Any], kwargs: dict[str, float]) -> None:
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        SpongeSqueezeEnv(cfg, **kwargs)  # type: ignore[arg-type]


def test_actions_of_the_wrong_size_are_refused(cfg: dict[str, Any]) -> None:
    # One value must not be broadcast against the two bounds into a whole action.
    env = SpongeSqueezeEnv(cfg, max_episode_steps=5)
    env.reset(seed=0)
    sim, goal = env.sim, env.goal
    with pytest.raises(ValueError, match="goal_fraction"):
        env.reset(options={"goal_fraction": 2.0})
    assert env.sim is sim and env.goal == goal  # the episode goes on untouched
    for bad in ([80.0], [80.0, 0.0, 0.0], [[80.0, 0.0]], [float("nan"), 0.0]):
        with pytest.raises(ValueError, match="2 finite values"):
            env.step(bad)
    assert env.steps == 0
    # In range or not, a well-formed action is clipped to the action space and taken.
    env.step([1e6, 0.0])
    assert env.steps == 1
