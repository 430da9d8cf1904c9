"""The reach task on the fast environment variant's hand-over states: the benchmark's
episodes from there are the environment's own, an agent's actions reach the engine as the
environment maps them, and the summary pairs controllers by seed."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from rmi_learn.control_bench.feedback import env_states
from rmi_learn.control_bench.feedback.laws import Fixed
from rmi_learn.sim.env import SpongeSqueezeEnv
from rmi_learn.sim.variants import FAST_ENV_ID, FAST_EPISODE_STEPS

H = FAST_EPISODE_STEPS


@pytest.fixture(scope="module")
def env() -> SpongeSqueezeEnv:
    return gym.make(FAST_ENV_ID, normalize_actions=True).unwrapped  # type: ignore[return-value]


def test_a_benchmark_episode_from_the_hand_over_is_the_environment_episode(env):
    start = env_states.start_of(env, 101)
    bench = env_states.execute(start, Fixed([250.0]), H)
    env.reset(seed=101)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(np.array([(250.0 - 64.0) / 336.0 * 2 - 1]))
        done = term or trunc
    assert bench.status == "ok" and bench.M_L_reach == info["M_L"]


def test_an_agent_acts_through_the_environments_observation_and_action_map(env):
    start = env_states.start_of(env, 102)
    seen = []

    def top(obs: np.ndarray) -> np.ndarray:
        seen.append(obs)
        return np.array([1.0], np.float32)  # normalised: the upper bound, 400 N

    agent = env_states.execute(start, env_states.AgentController(top, env, 0.5), H)
    assert agent.M_L_reach == env_states.constant(start, 400.0, H).M_L_reach
    assert len(seen) == H and seen[0].shape == (len(env.observation_names),)
    assert seen[0][-1] == np.float32(0.5)  # the goal, last
    assert seen[0][env.observation_names.index("M_L")] == np.float32(start.record["M_L"])


def test_goals_lie_between_the_bounds_and_the_oracle_is_at_least_as_close(env):
    start = env_states.start_of(env, 103)
    goal = env_states.drawn_goal(start, H, goal_seed=5)
    lo = env_states.constant(start, start.plant.lo_N, H).M_L_reach
    hi = env_states.constant(start, start.plant.hi_N, H).M_L_reach
    assert goal is not None and hi < goal < lo  # a harder grip holds less water
    best = env_states.oracle_constant(start, goal, H, steps=3)
    assert abs(best.M_L_reach - goal) <= min(abs(lo - goal), abs(hi - goal))
    assert env_states.drawn_goal(start, H, goal_seed=5) == goal


def test_evaluate_and_summarise_pair_every_controller_with_the_reference(env):
    top = {"top": lambda obs: np.array([1.0], np.float32)}
    pi = {"pi-privileged": lambda s, g: env_states.pi_privileged(s, g, 150_000.0)}
    rows = env_states.evaluate(env, [104, 105], top, pi, H, 5)
    names = {"top", "pi-privileged", "hold", "oracle-constant"}
    assert {r["controller"] for r in rows} == names and len(rows) == 8
    summary = {s["controller"]: s for s in env_states.summarise(rows, "pi-privileged", 200)}
    ref = summary["pi-privileged"]
    assert (ref["wins"], ref["ties"], ref["losses"]) == (0, 2, 0)
    assert ref["median_g"] < summary["hold"]["median_g"]  # feedback on M_L reaches the goal
    lo, hi = summary["hold"]["mean_ci_g"]
    assert lo <= summary["hold"]["mean_g"] <= hi
    table = env_states.markdown(list(summary.values()), "pi-privileged")
    assert table.count("\n") == 2 + len(names)


def test_in_the_sensors_mode_pi_closes_on_the_weight_and_agents_see_the_sensors():
    env = gym.make(FAST_ENV_ID, normalize_actions=True, observation_mode="sensors").unwrapped
    val = [env_states.start_of(env, 110)]
    assert val[0].sensors is not None and val[0].m_dry > 0
    offset = env_states.fit_weight_offset(val, H)
    assert np.isfinite(offset) and offset >= 0.0  # the water pressed out weighs on the pads
    seen = []

    def top(obs: np.ndarray) -> np.ndarray:
        seen.append(obs)
        return np.array([1.0], np.float32)

    laws = {"pi-weight": lambda s, g: env_states.pi_weight(s, g, 150_000.0, offset)}
    rows = env_states.evaluate(env, [111], {"top": top}, laws, H, 5)
    assert {r["controller"] for r in rows} == {"top", "pi-weight", "hold", "oracle-constant"}
    assert all(r["status"] == "ok" for r in rows)
    assert "M_L" not in env.observation_names and seen[0].shape == (len(env.observation_names),)
    pi = next(r for r in rows if r["controller"] == "pi-weight")
    hold = next(r for r in rows if r["controller"] == "hold")
    assert pi["M_L_kg"] != hold["M_L_kg"]  # the loop acted on what it sensed
