"""World-model scoring latency: 8 action chunks of 32 steps against one shared history.

For every model (trained run directories, or untrained models of the given kinds) it times
the inference path (``torch.no_grad``) and, for the GRU models, also their torch rollout
(``native`` off) and the differentiable training loop on the same inputs, interleaved in
blocks so that all see the same machine load. The GRUs' inference path is the native rollout
(``rmi_sph.GruForecaster``), on ``--threads`` threads like torch. Prints the median of the
block medians and the best block, in ms (the target: 5 ms on 2 cores).

    .venv/bin/python benches/bench_wm_latency.py [--runs DIR ...] [--kinds ac-gru,state-gru]
        [--threads 1] [--blocks 20] [--calls 15]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any


def _block(
    model: Any, hist: Any, mask: Any, actions: Any, calls: int, native: bool, **kw: Any
) -> float:
    import torch

    if hasattr(model, "native"):
        model.native = native
    with torch.no_grad():
        for _ in range(3):
            model(hist, mask, actions, **kw)
        times = []
        for _ in range(calls):
            t0 = time.perf_counter()
            model(hist, mask, actions, **kw)
            times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--runs", nargs="*", default=[], help="rmi train-wm run directories")
    p.add_argument("--kinds", default="ac-gru,state-gru,ac-mlp,transformer")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--blocks", type=int, default=20)
    p.add_argument("--calls", type=int, default=15)
    p.add_argument("--json", action="store_true", help="print one JSON line per model")
    args = p.parse_args()

    import torch

    from rmi_learn.world_models import build, load
    from rmi_learn.world_models.evaluation import latency_inputs

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    models: list[tuple[str, Any]] = [(r, load(r)[0]) for r in args.runs]
    if not args.runs:
        models = [(k, build({"kind": k}).eval()) for k in args.kinds.split(",") if k]
    for name, model in models:
        hi, ma, actions = latency_inputs(model)
        # An empty teacher dict selects the GRUs' differentiable loop (no forcing at tf 0).
        paths: dict[str, dict[str, Any]] = {"inference": {"native": True}}
        if getattr(model, "recurrent", False):
            paths["torch rollout"] = {"native": False}
            paths["training loop"] = {"native": False, "teacher": {}}
        blocks: dict[str, list[float]] = {k: [] for k in paths}
        for _ in range(args.blocks):
            for path, kw in paths.items():
                blocks[path].append(_block(model, hi, ma, actions, args.calls, **kw))
        for path, b in blocks.items():
            rec = {
                "model": name,
                "path": path,
                "threads": args.threads,
                "median_ms": round(statistics.median(b), 3),
                "best_block_ms": round(min(b), 3),
            }
            if args.json:
                print(json.dumps(rec))
            else:
                print(
                    f"{name:40s} {path:14s} median {rec['median_ms']:7.2f} ms  "
                    f"best block {rec['best_block_ms']:7.2f} ms  ({args.threads} thread(s))"
                )


if __name__ == "__main__":
    main()
