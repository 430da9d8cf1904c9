"""Python-side overhead of `rmi_sph.Trial.step` against the engine's own stepping.

Prints per-step wall times (ms) for the same trial config: `step(1)` called from a Python
loop, `step(n)` in one call (the GIL released for the whole chunk), and `run_trial` (the loop
in Rust), each after the same warm-up, plus the cost of `observation()`. Medians over
`--reps` repetitions; compare ratios within one run (shared machines are noisy).

    .venv/bin/python benches/bench_python_overhead.py [--steps 200] [--reps 5] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import time

import rmi_sph


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--radius", type=float, default=0.008)
    a = ap.parse_args()
    cfg = rmi_sph.trial_config(8, 0.6, 40.0, 60.0, radius=a.radius)
    warm = rmi_sph.Trial(cfg, num_threads=a.threads)
    warm.step(300)  # into the close phase, with contacts soon
    state = warm.get_state()

    def timed(fn: object) -> float:
        sim = rmi_sph.Trial.from_state(state, num_threads=a.threads)
        t0 = time.perf_counter()
        fn(sim)  # type: ignore[operator]
        return (time.perf_counter() - t0) / a.steps * 1e3

    def loop(sim: rmi_sph.Trial) -> None:
        for _ in range(a.steps):
            sim.step(1)

    def chunk(sim: rmi_sph.Trial) -> None:
        sim.step(a.steps)

    def observe(sim: rmi_sph.Trial) -> None:
        for _ in range(a.steps):
            sim.step(1)
            sim.observation()

    rows = {}
    cases = (("step(1) loop", loop), ("step(n) chunk", chunk), ("step(1)+observation", observe))
    for name, fn in cases:
        rows[name] = statistics.median(timed(fn) for _ in range(a.reps))
    dt = rmi_sph.Trial(cfg).dt
    print(f"config: 8 cm sponge, r = {a.radius} m, dt = {dt} s, {a.threads} threads")
    base = rows["step(n) chunk"]
    for name, ms in rows.items():
        print(f"{name:22s} {ms:8.3f} ms/step  ({ms / base:5.3f}x chunk)")


if __name__ == "__main__":
    main()
