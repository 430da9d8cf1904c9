"""Control steps per second of the Gymnasium environment's registered variants.

For each variant: one environment, and ``gym.make_vec`` with 1 and 2 worker processes
(``vectorization_mode="async"``, one copy per worker), each on one engine thread, driven
by seeded uniform random actions with autoreset, over ``--steps`` control steps per copy.
A variant with a pool of start seeds (``start_seeds``) first caches every hand-over state
(``prepare_start_states``), so the rate is a long run's, resets included; the time of a
scripted approach and of a restored reset are printed beside it. The default variant
(10 cm at r = 5 mm, one fixed goal) is measured over fewer steps (``--default-steps``): its
episode is 500 steps and its reset runs the approach.

    .venv/bin/python benches/bench_env_rate.py [--steps 600] [--variant ID ...] [--json FILE]

Runs take minutes on two cores; run nothing else meanwhile.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
from machine import cpu_model

from rmi_learn.sim.env import SpongeSqueezeEnv
from rmi_learn.sim.variants import ENV_ID, FAST_ENV_ID, variants


def reset_times(env_id: str) -> dict[str, float]:
    """Seconds of a reset that runs the scripted approach and of one that restores it."""
    env = gym.make(env_id)
    base: SpongeSqueezeEnv = env.unwrapped  # type: ignore[assignment]
    base.reset(seed=0)  # measures the default goal's reference squeeze, if any
    t0 = time.perf_counter()
    env.reset(seed=1)
    approach = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=1)
    restore = time.perf_counter() - t0
    return {"approach_s": approach, "restore_s": restore}


def single_rate(env_id: str, steps: int) -> float:
    """Control steps per second of one environment over ``steps`` random actions."""
    env = gym.make(env_id)
    env.unwrapped.prepare_start_states()  # type: ignore[attr-defined]
    env.reset(seed=0)
    env.action_space.seed(0)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


def vector_rate(env_id: str, workers: int, steps: int) -> float:
    """Control steps per second, summed over copies, of ``workers`` async copies."""
    vec = gym.make_vec(env_id, num_envs=workers, vectorization_mode="async")
    try:
        vec.call("prepare_start_states")
        vec.reset(seed=list(range(workers)))
        vec.action_space.seed(0)
        t0 = time.perf_counter()
        for _ in range(steps):
            vec.step(vec.action_space.sample())
        return workers * steps / (time.perf_counter() - t0)
    finally:
        vec.close()


def measure(env_id: str, steps: int) -> dict[str, Any]:
    """Every figure of one variant."""
    row: dict[str, Any] = {"variant": env_id, "steps_per_copy": steps}
    row.update(reset_times(env_id))
    row["one_env"] = single_rate(env_id, steps)
    for w in (1, 2):
        row[f"vector_{w}"] = vector_rate(env_id, w, steps)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--variant",
        action="append",
        choices=sorted(variants()),
        help="a registered variant (repeatable; default both)",
    )
    ap.add_argument("--steps", type=int, default=600, help="control steps per copy, >= 1")
    ap.add_argument(
        "--default-steps", type=int, default=40, help="the same for the default variant, >= 1"
    )
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    a = ap.parse_args(argv)
    for name in ("steps", "default_steps"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(a, name)}")
    rows = []
    for env_id in a.variant or [FAST_ENV_ID, ENV_ID]:
        rows.append(measure(env_id, a.default_steps if env_id == ENV_ID else a.steps))
        r = rows[-1]
        print(
            f"{env_id}: one env {r['one_env']:.0f} steps/s; vector 1 / 2 workers "
            f"{r['vector_1']:.0f} / {r['vector_2']:.0f} steps/s; reset {r['approach_s']:.2f} s "
            f"(scripted approach), {r['restore_s'] * 1e3:.1f} ms (restored)",
            flush=True,
        )
    if a.json is not None:
        a.json.write_text(json.dumps({"cpu": cpu_model(), "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
