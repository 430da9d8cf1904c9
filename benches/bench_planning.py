"""Time one planning decision (K = 8 policy samples + world-model scoring) on the CPU.

One decision = encode the history/goal once, draw K chunks of H_pi = 32 commands in one
batch, destandardise and clip forces, roll the K chunks through a world model and take the
argmin of J. Weights are random (the cost of a forward pass does not depend on them), or,
with ``--run OUT``, those of a pipeline output: its ``policy/diffusion`` and ``policy/flow``,
``wm/transformer`` and ``wm/ac-gru``, its dataset's statistics and a test window's history;
a distilled student beside a policy (``policy/flow-1step``, from ``rmi distill-policy``) is
timed too, at its own step count.

Settings compared, interleaved decision by decision so that a shared machine's load falls
on all of them alike:

- ``ref``: the reference :class:`Planner` with the objective's own sampler (16 DDIM steps
  for diffusion, 20 Euler steps for flow: the paper's tables);
- ``fast``: :class:`RealtimePlanner` (``policies/realtime.py``) at each step count of
  ``--fast-steps`` (a distilled student runs at 1 or 2 steps);

each with the Transformer W_T (width 256, 8 heads, 3 + 4 layers), the AC-GRU-WM (native
rollout where the extension has it) and the 32-step Linear-ARX (``arx``; ``wm/arx-32`` of a
pipeline output) as scorer. Prints p50/p95 in ms and decisions
per second, and with ``--breakdown`` where one decision's time goes (condition encoding,
one UNet pass over the K samples in eager torch and on the fast path, with its FLOPs,
each scorer alone, and the Linear-ARX's refinement of the chosen chunk).

    .venv/bin/python benches/bench_planning.py [--threads 2] [--reps 30] [--breakdown] [--run OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

from machine import cpu_model


def percentiles(times: list[float]) -> tuple[float, float]:
    """(p50, p95) of ``times`` (at least two values)."""
    q = statistics.quantiles(times, n=20, method="inclusive")
    return statistics.median(times), q[18]


def median_ms(fn: Callable[[], Any], reps: int, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` in ms."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(ts)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--reps", type=int, default=30, help="decisions per setting (>= 2)")
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--k", type=int, default=8)
    p.add_argument("--objectives", default="diffusion,flow")
    p.add_argument("--fast-steps", default="1,2,4,8,ref",
                   help="fast-path step counts; 'ref': the paper's 16 / 20")  # fmt: skip
    p.add_argument("--scorers", default="gru,wt,arx", help="comma list of gru, wt, arx")
    p.add_argument("--no-reference", action="store_true", help="skip the reference planner")
    p.add_argument("--refine", action="store_true",
                   help="also time each fast/student decision with the Linear-ARX scorer "
                   "followed by refinement of the chosen chunk (RealtimePlanner.act, "
                   "refine='smooth', 4 iterations)")  # fmt: skip
    p.add_argument("--breakdown", action="store_true", help="time the parts of a decision")
    p.add_argument("--json", action="store_true", help="print one JSON line per setting")
    p.add_argument("--run", default=None, help="a pipeline output with trained policies and models")
    args = p.parse_args()

    import torch

    from rmi_learn.planning.planner import Planner
    from rmi_learn.planning.realtime import RealtimePlanner
    from rmi_learn.planning.scorers import world_model_scorer
    from rmi_learn.planning.standardiser import Standardiser
    from rmi_learn.policies.diffusion import DiffusionObjective
    from rmi_learn.policies.fast_sampler import FastSampler
    from rmi_learn.policies.flow import FlowObjective
    from rmi_learn.policies.unet import PolicyUNet, UNetConfig
    from rmi_learn.world_models import build
    from rmi_learn.world_models.gru import _native_class

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    paper = {"diffusion": 16, "flow": 20}
    make = {"diffusion": DiffusionObjective, "flow": FlowObjective}
    objectives = args.objectives.split(",")
    students: dict[str, tuple[Any, int]] = {}
    if args.run is None:
        net = PolicyUNet(UNetConfig()).eval()
        nets = {obj: net for obj in objectives}
        wms = {"wt": build({"kind": "transformer"}).eval(),
               "gru": build({"kind": "ac-gru"}).eval(),
               "arx": build({"kind": "arx", "horizon": 32}).eval()}  # fmt: skip
        std = Standardiser(
            z_mean=torch.zeros(18), z_std=torch.full((18,), 0.1),
            u_mean=torch.tensor([150.0]), u_std=torch.tensor([80.0]),
        )  # fmt: skip
        hist = torch.randn(1, 16, 23)
        mask = torch.ones(1, 16, 23)
        goal = torch.tensor([0.5])
        water = torch.tensor([1.0])
    else:
        nets, students, wms, std, (hist, mask, goal, water) = trained(args.run, objectives)
    scorers = {name: world_model_scorer(wms[name]) for name in args.scorers.split(",")}

    planners: list[tuple[dict[str, Any], Any]] = []
    for obj in objectives:
        for sc_name, scorer in scorers.items():
            if not args.no_reference:
                ref = Planner(nets[obj], make[obj](), scorer, std, k=args.k)
                planners.append(({"path": "ref", "objective": obj, "steps": paper[obj],
                                  "scorer": sc_name}, ref))  # fmt: skip
            for s in args.fast_steps.split(","):
                n = paper[obj] if s == "ref" else int(s)
                fast = RealtimePlanner(nets[obj], make[obj](), scorer, std, k=args.k, steps=n)
                planners.append(({"path": "fast", "objective": obj, "steps": n,
                                  "scorer": sc_name}, fast))  # fmt: skip
            if obj in students:
                snet, n = students[obj]
                fast = RealtimePlanner(snet, make[obj](), scorer, std, k=args.k, steps=n)
                planners.append(({"path": "student", "objective": obj, "steps": n,
                                  "scorer": sc_name}, fast))  # fmt: skip
    if args.refine and "arx" in scorers:
        for rec in [r for r, _ in planners if r["scorer"] == "arx" and r["path"] != "ref"]:
            obj = rec["objective"]
            net = students[obj][0] if rec["path"] == "student" else nets[obj]
            act = RealtimePlanner(net, make[obj](), scorers["arx"], std, k=args.k,
                                  steps=rec["steps"], refine="smooth")  # fmt: skip
            planners.append(({**rec, "scorer": "arx+refine"}, _Act(act, std)))

    header = {
        "cpu": cpu_model(),
        "threads": args.threads,
        "k": args.k,
        "torch": torch.__version__,
        "gru_native": _native_class() is not None,
        "date": time.strftime("%Y-%m-%d"),
    }
    print(json.dumps(header) if args.json else " ".join(f"{k}={v}" for k, v in header.items()))

    gen = torch.Generator().manual_seed(0)
    times: list[list[float]] = [[] for _ in planners]
    with torch.inference_mode():
        for rep in range(args.warmup + args.reps):
            # Interleaved: one decision of every setting per round.
            for i, (_, planner) in enumerate(planners):
                t0 = time.perf_counter()
                planner.plan(hist, mask, goal, water, None, gen)
                dt = (time.perf_counter() - t0) * 1e3
                if rep >= args.warmup:
                    times[i].append(dt)
    for (rec, _), ts in zip(planners, times, strict=True):
        p50, p95 = percentiles(ts)
        rec = {**rec, "p50_ms": p50, "p95_ms": p95, "decisions_per_s": 1e3 / p50, "n": len(ts)}
        if args.json:
            print(json.dumps(rec))
        else:
            print(f"{rec['path']:4s} {rec['objective']:9s} steps={rec['steps']:2d} "
                  f"scorer={rec['scorer']:3s}: p50 {p50:6.1f} ms  p95 {p95:6.1f} ms  "
                  f"{rec['decisions_per_s']:5.1f} decisions/s")  # fmt: skip

    if args.breakdown:
        breakdown(nets[objectives[0]], wms, hist, mask, args, FastSampler, FlowObjective)


class _Act:
    """A decision through ``RealtimePlanner.act`` (selection, then refinement), called like
    ``Planner.plan`` by the timing loop."""

    def __init__(self, planner: Any, std: Any) -> None:
        self.planner, self.std = planner, std

    def plan(self, hist: Any, mask: Any, goal: Any, water: Any, original: Any, gen: Any) -> Any:
        goal_kg = float(self.std.water_to_kg(goal[:1])[0])
        return self.planner.act(hist[0], mask[0], goal_kg, gen)


def trained(run: str, objectives: list[str]) -> tuple[Any, ...]:
    """The trained inputs of a pipeline output ``run``: policies by objective, distilled
    students by objective (network, steps), scorers, statistics and one test window's
    (history, mask, goal, water now), standardised, with a goal 5 g below the water now."""
    from pathlib import Path

    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.planning.standardiser import Standardiser
    from rmi_learn.policies.checkpoint import load_policy
    from rmi_learn.world_models import load

    root = Path(run)
    nets = {obj: load_policy(root / "policy" / obj)[0].eval() for obj in objectives}
    students = {}
    for obj in objectives:
        d = root / "policy" / f"{obj}-1step"
        if (d / "config.json").exists():
            net, objective, _ = load_policy(d)
            students[obj] = (net.eval(), int(objective.n_sample_steps))
    wms = {"wt": load(root / "wm" / "transformer")[0], "gru": load(root / "wm" / "ac-gru")[0]}
    if (root / "wm" / "arx-32" / "config.json").exists():
        wms["arx"] = load(root / "wm" / "arx-32")[0]
    ds = load_dataset(root / "dataset")
    std = Standardiser.from_stats(ds.stats)
    ws = ds.windows("test", None, 16, 32)
    item = ws[len(ws) // 2]
    water_now = item["water_now"].view(1)
    goal = water_now - 0.005 / std.z_std[0]
    window = (item["hist"][None], item["hist_mask"][None], goal, water_now)
    return nets, students, wms, std, window


def breakdown(net: Any, wms: dict[str, Any], hist: Any, mask: Any, args: Any,
              fast_sampler: Any, flow: Any) -> None:  # fmt: skip
    """Median ms of each part of one decision, and the UNet pass's FLOPs."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    k, reps = args.k, max(args.reps, 10)
    goal_vec = torch.randn(1, 2)
    x = torch.randn(k, 32, 1)
    t = torch.full((k,), 10.0)
    u = torch.randn(k, 32, 1)
    sampler = fast_sampler(net, flow(), 1)
    parts: dict[str, float] = {}
    with torch.inference_mode():
        cond = net.encode_condition(hist, mask, goal_vec)
        film = sampler.film(cond)[0]
        with FlopCounterMode(display=False) as counter:
            net.denoise(x, t, cond.expand(k, -1))
        gflop = counter.get_total_flops() / 1e9
        parts["encode history+goal (1 window)"] = median_ms(
            lambda: net.encode_condition(hist, mask, goal_vec), reps
        )
        parts[f"UNet pass, eager, batch {k}"] = median_ms(
            lambda: net.denoise(x, t, cond.expand(k, -1)), reps
        )
        parts["FiLM tables, fast path (per decision)"] = median_ms(lambda: sampler.film(cond), reps)
        parts[f"UNet pass, fast path, batch {k}"] = median_ms(
            lambda: sampler.denoise(x, film, 1), reps
        )
        parts[f"W_T scoring {k} x 32"] = median_ms(
            lambda: wms["wt"].predict(hist.expand(k, -1, -1), mask.expand(k, -1, -1), u), reps
        )
        parts[f"AC-GRU-WM scoring {k} x 32"] = median_ms(
            lambda: wms["gru"].predict(hist, mask, u), reps)  # fmt: skip
        if "arx" in wms:
            parts[f"Linear-ARX (32) scoring {k} x 32"] = median_ms(
                lambda: wms["arx"].predict(hist.expand(k, -1, -1), mask.expand(k, -1, -1), u),
                reps)  # fmt: skip
    if "arx" in wms:
        # Refinement of the chosen chunk by the scorer's gradient (control/refine.py): outside
        # inference mode, since it differentiates through the model.
        from rmi_learn.planning.refine import refine_chunk
        from rmi_learn.planning.scorers import world_model_scorer
        from rmi_learn.planning.standardiser import Standardiser

        std = Standardiser(torch.zeros(18), torch.full((18,), 0.1), torch.tensor([150.0]),
                           torch.tensor([80.0]))  # fmt: skip
        scorer = world_model_scorer(wms["arx"])
        chunk = torch.full((1, 32, 1), 150.0)
        goal = refine_chunk(scorer, std, hist, mask, chunk, torch.zeros(1), iterations=0)
        target = goal.pred_before_kg + 0.003
        for n in (1, 4):
            parts[f"Linear-ARX refinement, {n} iteration(s)"] = median_ms(
                lambda n=n: refine_chunk(scorer, std, hist, mask, chunk, target, iterations=n),
                reps)  # fmt: skip
    for name, ms in parts.items():
        print(f"{name:40s} {ms:7.2f} ms")
    for name in (f"UNet pass, eager, batch {k}", f"UNet pass, fast path, batch {k}"):
        print(f"{name:40s} {gflop:.2f} GFLOP -> {gflop / parts[name] * 1e3:.0f} GFLOP/s")


if __name__ == "__main__":
    main()
