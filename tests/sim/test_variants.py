"""The registered variants of rmi_learn.sim.env, and the constructor options the fast one is
made of: goals drawn per episode and observed, a pool of cached start seeds, bounded grip
forces and the cost of a failure."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import rmi_sph
from rmi_learn.sim.env import SpongeSqueezeEnv
from rmi_learn.sim.variants import (
    ENV_ID,
    FAST_ENV_ID,
    FAST_EPISODE_STEPS,
    FAST_HOLD_N,
    FAST_START_SEEDS,
    variants,
)
from tiny_trial import tiny_config


def test_both_variants_are_registered_with_their_episode_limits():
    for env_id, spec in variants().items():
        assert gym.spec(env_id).max_episode_steps == spec["max_episode_steps"]
    assert {ENV_ID, FAST_ENV_ID} <= set(gym.registry)


def test_fast_variant_draws_observed_goals_from_a_cached_pool_of_start_seeds():
    env = gym.make(FAST_ENV_ID)
    base: SpongeSqueezeEnv = env.unwrapped  # type: ignore[assignment]
    assert base.observation_names[-1] == "goal"
    assert env.observation_space.shape == (len(base.observation_names),)
    np.testing.assert_allclose(env.action_space.low, [0.8 * FAST_HOLD_N])
    np.testing.assert_allclose(env.action_space.high, [400.0])
    obs, info = env.reset(seed=1)
    release = base.reference_release_kg
    assert release is not None and release > 0.005  # a squeeze the goals can ask for
    goals, seeds = [], set()
    for _ in range(4):
        obs, info = env.reset()
        assert obs[-1] == np.float32(info["goal"])
        assert info["M_L"] - release - 1e-9 <= info["goal"] <= info["M_L"] + 1e-9
        goals.append(info["goal"])
        seeds.add(int(base.sim.config["seed"]))
    assert len(set(goals)) == 4
    assert all(s < FAST_START_SEEDS for s in seeds)
    assert set(base._cache) <= set(range(FAST_START_SEEDS)) | {0, 1}
    assert seeds <= set(base._cache)


def test_fast_variant_episode_ends_with_the_squeeze_and_a_restored_reset_replays_it():
    env = gym.make(FAST_ENV_ID)

    def episode() -> list[float]:
        env.reset(seed=FAST_START_SEEDS + 3)
        rewards, steps, done = [], 0, False
        while not done:
            _, r, term, trunc, info = env.step(np.array([150.0], np.float32))
            rewards.append(r)
            steps += 1
            done = term or trunc
        assert term and not trunc and info["failure"] is None and info["phase"] == "done"
        assert steps == FAST_EPISODE_STEPS
        return rewards

    first = episode()  # the scripted approach
    assert episode() == first  # from the cached hand-over state, bit for bit


def test_a_failure_costs_the_failing_step_failure_cost():
    env = SpongeSqueezeEnv(tiny_config(), goal=0.5, failure_cost=3.0)
    env.reset(seed=0)
    for _ in range(200):
        _, reward, term, _, info = env.step(np.array([0.0], np.float32))
        if term:
            break
    assert info["failure"] is not None  # let go, the sponge drops
    assert reward == pytest.approx(-abs(info["M_L"] - 0.5) - 3.0)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"release_fraction": (0.6, 0.2)}, "release_fraction"),
        ({"release_fraction": (0.1, 0.2, 0.3)}, "release_fraction"),
        ({"release_fraction": (0.1, 1.5)}, "release_fraction[1]"),
        ({"start_seeds": 0}, "start_seeds"),
        ({"start_seeds": 2**63}, "start_seeds"),
        ({"force_range": (50.0, 40.0)}, "force_range"),
        ({"force_range": (0.0, 1e4)}, "force_range"),
        ({"force_range": 100.0}, "force_range"),
        ({"failure_cost": -1.0}, "failure_cost"),
        ({"failure_cost": float("nan")}, "failure_cost"),
    ],
)
def test_bad_variant_options_are_refused_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=r"^" + field.replace("[", r"\[").replace("]", r"\]")):
        SpongeSqueezeEnv(rmi_sph.trial_config(8, 0.6, 20, 40, 0.01), **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"start_seeds": 2.5}, "start_seeds"), ({"force_range": ("a", 10)}, "force_range")],
)
def test_options_of_the_wrong_kind_are_refused_naming_the_field(kwargs, field):
    with pytest.raises(TypeError, match=f"^{field}"):
        SpongeSqueezeEnv(rmi_sph.trial_config(8, 0.6, 20, 40, 0.01), **kwargs)


def test_prepare_start_states_caches_the_whole_pool_and_resets_then_only_restore():
    env = SpongeSqueezeEnv(tiny_config(), goal=0.5, start_seeds=3)
    assert env.prepare_start_states() == 3
    assert SpongeSqueezeEnv(tiny_config(), goal=0.5).prepare_start_states() == 0
    env.reset(seed=7)
    env._cache.clear()
    env.prepare_start_states()
    before = dict(env._cache)
    for _ in range(5):
        env.reset()
        assert int(env.sim.config["seed"]) in before
    assert env._cache == before
