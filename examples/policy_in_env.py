"""Drive the Gymnasium environment ``rmi/SpongeSqueeze-v0`` with a trained policy.

Usage (from the repository root, after ``make setup``)::

    .venv/bin/python examples/policy_in_env.py --policy runs/dp [--wm runs/wt]

Two episodes from the same start state: the policy alone (one sample per decision), then the
planner (``--k`` samples ranked by the world model) when a world model is at hand: the one
stored in the policy run (``rmi train-policy --wm``) or ``--wm``. Every decision sends the
first ``--execute`` commands of the chunk, one per 20 ms control step, then decides again
from the new observations (receding horizon). Each episode ends with its final
``|M_L - goal|``.

The environment takes ``[F_target, v_cmd]`` (N, m/s) by default and ``[F_target]`` alone when
made with ``action_mode="force"``; the script sends what the action space has room for,
picking the channels by name, and makes a force-only environment for a policy that was
trained on ``F_target`` alone.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import rmi_learn.sim.env  # noqa: F401  (registers rmi/SpongeSqueeze-v0)
import rmi_sph
from rmi_learn.errors import InputError
from rmi_learn.planning import Policy, load_policy
from rmi_learn.policies.policy import STORED, WORLD_MODEL_DIR

#: Action channels the environment takes, by the size of its action space.
ENV_CHANNELS: dict[int, tuple[str, ...]] = {1: ("F_target",), 2: ("F_target", "v_cmd")}


def env_action(row: np.ndarray, names: tuple[str, ...], space_dim: int) -> np.ndarray:
    """One policy action ``row`` (channels ``names``) as the environment's action: F_target
    alone for a 1-D action space, [F_target, v_cmd] for a 2-D one."""
    if space_dim not in ENV_CHANNELS:
        raise ValueError(f"the environment's action space has {space_dim} values, expected 1 or 2")
    wanted = ENV_CHANNELS[space_dim]
    missing = [n for n in wanted if n not in names]
    if missing:
        raise ValueError(
            f"the environment takes {list(wanted)}, the policy gives {list(names)}; make the "
            "environment with action_mode='force' for a force-only policy"
        )
    return np.asarray([row[names.index(n)] for n in wanted], dtype=np.float32)


def run_episode(
    env: gym.Env[Any, Any],
    policy: Policy,
    execute: int,
    seed: int,
    goal_kg: float | None = None,
) -> dict[str, Any]:
    """One episode: decide, send the first ``execute`` commands of the chunk, repeat until
    the episode ends. Returns the final ``M_L`` and ``goal`` (kg), ``error_kg`` = |M_L - goal|,
    the control ``steps`` and ``decisions`` taken."""
    options = None if goal_kg is None else {"goal": goal_kg}
    obs, info = env.reset(seed=seed, options=options)
    policy.reset()
    history = policy.observe(obs, info)
    space_dim = int(np.prod(env.action_space.shape or (1,)))
    steps = decisions = 0
    done = False
    while not done:
        chunk = policy.act(history, info["goal"])
        decisions += 1
        for row in chunk[:execute]:
            obs, _, terminated, truncated, info = env.step(
                env_action(row, policy.action_names, space_dim)
            )
            history = policy.observe(obs, info)
            steps += 1
            done = terminated or truncated
            if done:
                break
    m_l, goal = float(info["M_L"]), float(info["goal"])
    return {
        "M_L": m_l,
        "goal": goal,
        "error_kg": abs(m_l - goal),
        "steps": steps,
        "decisions": decisions,
        "phase": info["phase"],
        "failure": info["failure"],
    }


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--policy", type=Path, required=True, help="policy run directory")
    p.add_argument(
        "--wm",
        type=Path,
        default=None,
        help="world-model run for the planner (default: the one stored in the policy run, if any)",
    )
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        help="trial config file (default: 8 cm, porosity 0.6, hold 60 N, squeeze 200 N, r 8 mm)",
    )
    p.add_argument("--goal", type=float, default=None, help="goal retained water (kg)")
    p.add_argument(
        "--goal-fraction",
        type=float,
        default=0.8,
        help="goal as a fraction of the water at hand-over (without --goal)",
    )
    p.add_argument("--execute", type=int, default=8, help="commands sent per decision")
    p.add_argument("--max-steps", type=int, default=200, help="control steps per episode")
    p.add_argument("--k", type=int, default=8, help="samples ranked per planner decision")
    p.add_argument("--seed", type=int, default=0, help="episode and sampling seed")
    p.add_argument("--realtime", action="store_true", help="the fast sampling path")
    p.add_argument(
        "--action-mode",
        choices=("both", "force"),
        default=None,
        help="the environment's action mode (default: the environment's own, "
        "'force' for a force-only policy)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the episodes and print their final |M_L - goal|; 0 on success."""
    args = build_parser().parse_args(argv)
    if args.execute < 1:
        print("--execute must be at least 1", file=sys.stderr)
        return 2
    config: Any = (
        rmi_sph.trial_config(8, 0.6, 60.0, 200.0, radius=0.008, dt=0.002)
        if args.config is None
        else args.config
    )
    scorer = args.wm
    if scorer is None and (args.policy / WORLD_MODEL_DIR).is_dir():
        scorer = STORED
    try:
        policy = load_policy(args.policy, realtime=args.realtime, seed=args.seed)
        planner = None
        if scorer is not None:
            planner = load_policy(
                args.policy, realtime=args.realtime, scorer=scorer, k=args.k, seed=args.seed
            )
    except InputError as exc:
        print(f"policy_in_env: {exc}", file=sys.stderr)
        return 2
    env_kwargs: dict[str, Any] = {
        "config": config,
        "goal_fraction": args.goal_fraction,
        "max_episode_steps": args.max_steps,
    }
    mode = args.action_mode
    if mode is None and "v_cmd" not in policy.action_names:
        mode = "force"
    if mode is not None:
        env_kwargs["action_mode"] = mode
    env = gym.make("rmi/SpongeSqueeze-v0", **env_kwargs)
    print(
        f"policy {args.policy}: actions {list(policy.action_names)}, chunks of "
        f"{policy.horizon} steps, {args.execute} executed per decision"
    )
    runs: list[tuple[str, Policy]] = [("policy alone", policy)]
    if planner is not None:
        runs.append((f"planner (K = {args.k}, world model {planner.scorer_source})", planner))
    else:
        print("no world model: pass --wm, or train the policy with --wm, for the planner")
    for label, pol in runs:
        r = run_episode(env, pol, args.execute, args.seed, args.goal)
        print(
            f"{label}: final M_L {r['M_L']:.6f} kg, goal {r['goal']:.6f} kg, "
            f"|M_L - goal| = {1000.0 * r['error_kg']:.3f} g after {r['steps']} steps "
            f"({r['decisions']} decisions, phase {r['phase']}"
            + (f", failure {r['failure']})" if r["failure"] else ")")
        )
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
