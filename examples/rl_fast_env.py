"""Train a model-free agent (PPO or SAC, stable-baselines3) on the fast environment variant
and evaluate it on the goal-reaching benchmark's reach task beside the feedback baselines.

Steps: train the agent on ``rmi/SpongeSqueezeFast-v0`` (goals drawn per episode and observed,
actions normalised to [-1, 1], observations and rewards normalised by ``VecNormalize``);
tune the PI loops' Ki (and, in the ``sensors`` mode, the weight estimate's offset) on
validation seeds; then, on held-out test seeds (trial seeds above the training pool),
execute the agent, PI on the simulator's M_L, PI on the weight estimate (``sensors`` only),
the held setpoint and the constant-setpoint oracle from each seed's hand-over toward the
goal the benchmark draws (:mod:`rmi_learn.control_bench.feedback.env_states`). The agent is
paired with the PI loop on its own sensing: ``pi-privileged`` or ``pi-weight``. Writes
``summary.md``, ``rows.json``, ``summary.json`` (with the training steps, wall times and
tuned gains), the agent (``agent.zip``) and its normalisation (``vecnormalize.pkl``) into
``--out``, which must be new or empty.

    .venv/bin/python examples/rl_fast_env.py --out results/sac-fast --algo sac [--timesteps N]

Needs the ``rl`` extra (stable-baselines3), part of ``make setup``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from rmi_learn.control_bench.feedback import env_states
from rmi_learn.data.runs import atomic_write_bytes, atomic_write_json
from rmi_learn.data.schema import SEED_MAX
from rmi_learn.sensing import OBSERVATION_MODES
from rmi_learn.sim.env import SpongeSqueezeEnv
from rmi_learn.sim.variants import FAST_ENV_ID, FAST_EPISODE_STEPS, FAST_START_SEEDS

#: The PI gains tried on the validation seeds (N/(kg s)), as in the benchmark's protocols.
KI_CANDIDATES = (50_000.0, 150_000.0, 300_000.0)
#: The agents the example trains (stable-baselines3's).
ALGOS = ("ppo", "sac")
#: The feedback loop on the agent's own sensing, per observation mode: the paired reference.
REFERENCE = {"privileged": "pi-privileged", "sensors": "pi-weight"}
#: First validation and test trial seeds: above the training pool, apart from each other.
VALIDATION_SEED0, TEST_SEED0 = 10_000, 20_000


def parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="new or empty output directory")
    ap.add_argument("--algo", choices=ALGOS, default="sac", help="the agent (default sac)")
    ap.add_argument("--timesteps", type=int, default=100_000, help="training steps, >= 64")
    ap.add_argument("--envs", type=int, default=2, help="training environments (processes)")
    ap.add_argument("--seed", type=int, default=0, help=f"training seed in [0, {SEED_MAX}]")
    ap.add_argument("--observation-mode", choices=OBSERVATION_MODES, default="privileged")
    ap.add_argument("--validation-states", type=int, default=8, help="seeds tuning PI, >= 1")
    ap.add_argument("--test-states", type=int, default=24, help="held-out seeds, >= 1")
    ap.add_argument("--goal-seed", type=int, default=5, help="seed of the drawn goals, >= 0")
    a = ap.parse_args(argv)
    for name, low in (("timesteps", 64), ("envs", 1), ("validation_states", 1), ("test_states", 1)):
        if getattr(a, name) < low:
            ap.error(f"--{name.replace('_', '-')} must be >= {low}, got {getattr(a, name)}")
    for name in ("seed", "goal_seed"):
        if not 0 <= getattr(a, name) <= SEED_MAX:
            ap.error(
                f"--{name.replace('_', '-')} must be in [0, {SEED_MAX}], got {getattr(a, name)}"
            )
    if a.out.exists() and (not a.out.is_dir() or any(a.out.iterdir())):
        ap.error(f"--out {a.out} exists and is not an empty directory; choose a new one")
    return a


def make_env(mode: str) -> gym.Env[Any, Any]:
    return gym.make(FAST_ENV_ID, observation_mode=mode, normalize_actions=True)


def train(a: argparse.Namespace) -> tuple[Any, Any, float]:
    """The trained agent, its VecNormalize and the training wall time (s)."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    torch.set_num_threads(1)
    vec = make_vec_env(
        make_env,
        n_envs=a.envs,
        seed=a.seed,
        vec_env_cls=SubprocVecEnv if a.envs > 1 else None,
        env_kwargs={"mode": a.observation_mode},
    )
    norm = VecNormalize(vec, norm_obs=True, norm_reward=True, gamma=0.99)
    common: dict[str, Any] = {"gamma": 0.99, "seed": a.seed, "device": "cpu", "verbose": 0}
    if a.algo == "ppo":
        agent: Any = PPO("MlpPolicy", norm, n_steps=256, batch_size=64, **common)
    else:
        agent = SAC("MlpPolicy", norm, learning_starts=1_000, batch_size=256, **common)
    t0 = time.perf_counter()
    agent.learn(total_timesteps=a.timesteps, callback=progress(max(a.timesteps // 10, 1)))
    wall = time.perf_counter() - t0
    norm.training = False
    vec.close()
    return agent, norm, wall


def progress(every: int) -> Any:
    """A callback that prints, every ``every`` steps, the mean per-step |M_L - goal| (g) of
    the last 100 training episodes (Monitor's returns, before VecNormalize scales them)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Progress(BaseCallback):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__()
            self.next = every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next and self.model.ep_info_buffer:
                eps = list(self.model.ep_info_buffer)
                err = -1e3 * sum(e["r"] for e in eps) / sum(e["l"] for e in eps)
                print(f"{self.num_timesteps} steps: {err:.2f} g per step", flush=True)
                self.next += every
            return True

    return Progress()


def feedback_laws(
    val: list[env_states.Start], horizon: int, goal_seed: int, mode: str
) -> tuple[dict[str, env_states.Law], dict[str, dict[str, Any]]]:
    """The PI laws of the observation ``mode``, tuned on the validation starts ``val``, and
    what was tuned: PI on M_L always, PI on the weight estimate in the ``sensors`` mode."""
    ki, medians = env_states.tune_ki(val, KI_CANDIDATES, horizon, goal_seed)
    laws: dict[str, env_states.Law] = {
        "pi-privileged": lambda s, g: env_states.pi_privileged(s, g, ki)
    }
    tuning: dict[str, dict[str, Any]] = {"pi-privileged": {"ki": ki, "median_g": medians}}
    if mode == "sensors":
        offset = env_states.fit_weight_offset(val, horizon)

        def weight(s: env_states.Start, g: float, k: float) -> Any:
            return env_states.pi_weight(s, g, k, offset)

        ki_w, med_w = env_states.tune_ki(val, KI_CANDIDATES, horizon, goal_seed, weight)
        laws["pi-weight"] = lambda s, g: weight(s, g, ki_w)
        tuning["pi-weight"] = {"ki": ki_w, "median_g": med_w, "offset_kg": offset}
    return laws, tuning


def policy_of(agent: Any, norm: Any) -> env_states.Policy:
    """The deterministic policy of raw observations."""

    def act(obs: np.ndarray) -> np.ndarray:
        action, _ = agent.predict(norm.normalize_obs(obs[None, :]), deterministic=True)
        return np.asarray(action[0], dtype=np.float32)

    return act


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    agent, norm, train_s = train(a)
    env: SpongeSqueezeEnv = make_env(a.observation_mode).unwrapped  # type: ignore[assignment]
    horizon = FAST_EPISODE_STEPS
    t0 = time.perf_counter()
    val = [env_states.start_of(env, VALIDATION_SEED0 + i) for i in range(a.validation_states)]
    laws, tuning = feedback_laws(val, horizon, a.goal_seed, a.observation_mode)
    reference = REFERENCE[a.observation_mode]
    seeds = [TEST_SEED0 + i for i in range(a.test_states)]
    agents = {a.algo: policy_of(agent, norm)}
    rows = env_states.evaluate(env, seeds, agents, laws, horizon, a.goal_seed)
    summary = env_states.summarise(rows, reference)
    eval_s = time.perf_counter() - t0
    table = env_states.markdown(summary, reference)
    a.out.mkdir(parents=True, exist_ok=True)
    agent.save(a.out / "agent.zip")
    norm.save(str(a.out / "vecnormalize.pkl"))
    atomic_write_json(a.out / "rows.json", rows)
    facts = {
        "algo": a.algo,
        "variant": FAST_ENV_ID,
        "observation_mode": a.observation_mode,
        "timesteps": a.timesteps,
        "envs": a.envs,
        "seed": a.seed,
        "train_s": train_s,
        "eval_s": eval_s,
        "reference": reference,
        "tuning": tuning,
        "training_seeds": [0, FAST_START_SEEDS - 1],
        "validation_seeds": [VALIDATION_SEED0, VALIDATION_SEED0 + a.validation_states - 1],
        "test_seeds": [seeds[0], seeds[-1]],
        "summary": summary,
    }
    atomic_write_json(a.out / "summary.json", facts)
    gains = ", ".join(f"{k} Ki {v['ki']:g} N/(kg s)" for k, v in tuning.items())
    head = (
        f"{a.algo.upper()} on {FAST_ENV_ID} ({a.observation_mode}), {a.timesteps} steps "
        f"in {train_s:.0f} s; "
        f"PI gains tuned on {a.validation_states} validation seeds ({gains}); "
        f"reach error after {horizon} control steps on {a.test_states} held-out seeds.\n\n"
    )
    text = (head + table).encode()
    atomic_write_bytes(a.out / "summary.md", lambda f: f.write(text))
    print(head + table, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
