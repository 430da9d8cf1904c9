"""Time one full planning decision (K = 8 policy samples + W_T scoring) on the CPU.

One decision = encode the history/goal once, draw K chunks of H_pi = 32 commands in one
batch (16 DDIM steps for diffusion, 20 Euler steps for flow), destandardise and clip forces,
roll the K chunks through the causal Transformer W_T (width 256, 8 heads, 3 + 4 layers) and
take the argmin of J. Weights are random (the cost of a forward pass does not depend on
them). Prints the median and quartiles in ms for both objectives.

    .venv/bin/python benches/bench_planning.py [--threads 2] [--reps 30] [--steps 16,8]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--reps", type=int, default=30)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--k", type=int, default=8)
    p.add_argument(
        "--diffusion-steps", default="16", help="comma list of DDIM steps to time (paper: 16)"
    )
    p.add_argument("--flow-steps", default="20", help="comma list of Euler steps (paper: 20)")
    p.add_argument("--json", action="store_true", help="print one JSON line per setting")
    args = p.parse_args()

    import torch

    from rmi_learn.policies.diffusion import DiffusionObjective
    from rmi_learn.policies.flow import FlowObjective
    from rmi_learn.policies.ranking import Planner, Standardiser, world_model_scorer
    from rmi_learn.policies.unet import PolicyUNet, UNetConfig
    from rmi_learn.world_models import build

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    net = PolicyUNet(UNetConfig()).eval()
    wm = build({"kind": "transformer"}).eval()
    std = Standardiser(
        z_mean=torch.zeros(18), z_std=torch.full((18,), 0.1),
        u_mean=torch.tensor([150.0, 0.0]), u_std=torch.tensor([80.0, 0.01]),
    )  # fmt: skip
    hist = torch.randn(1, 16, 23)
    mask = torch.ones(1, 16, 23)
    goal = torch.tensor([0.5])
    water = torch.tensor([1.0])
    settings: list[tuple[str, object, int]] = []
    for s in args.diffusion_steps.split(","):
        settings.append(("diffusion", DiffusionObjective(n_sample_steps=int(s)), int(s)))
    for s in args.flow_steps.split(","):
        settings.append(("flow", FlowObjective(n_sample_steps=int(s)), int(s)))
    for name, objective, steps in settings:
        planner = Planner(net, objective, world_model_scorer(wm), std, k=args.k)
        gen = torch.Generator().manual_seed(0)
        times = []
        with torch.inference_mode():
            for i in range(args.warmup + args.reps):
                t0 = time.perf_counter()
                planner.plan(hist, mask, goal, water, None, gen)
                dt = (time.perf_counter() - t0) * 1e3
                if i >= args.warmup:
                    times.append(dt)
            # split: sampling alone vs scoring alone
            goal_vec = std.goal_vector(goal, water)
            ts, tw = [], []
            for _ in range(max(5, args.reps // 3)):
                t0 = time.perf_counter()
                u = planner.sample(hist, mask, goal_vec, gen)
                t1 = time.perf_counter()
                planner.score(hist, mask, u, std.water_to_kg(goal))
                t2 = time.perf_counter()
                ts.append((t1 - t0) * 1e3)
                tw.append((t2 - t1) * 1e3)
        q = statistics.quantiles(times, n=4)
        rec = {
            "objective": name,
            "steps": steps,
            "k": args.k,
            "threads": args.threads,
            "median_ms": statistics.median(times),
            "q1_ms": q[0],
            "q3_ms": q[2],
            "sampling_median_ms": statistics.median(ts),
            "scoring_median_ms": statistics.median(tw),
        }
        if args.json:
            print(json.dumps(rec))
        else:
            print(
                f"{name:9s} steps={steps:2d} K={args.k} threads={args.threads}: "
                f"median {rec['median_ms']:.1f} ms (IQR {q[0]:.1f}-{q[2]:.1f}); "
                f"sampling {rec['sampling_median_ms']:.1f} ms, "
                f"scoring {rec['scoring_median_ms']:.1f} ms"
            )


if __name__ == "__main__":
    main()
