"""Which scorer, and which ensemble weight, should rank the policy's samples?

Ranking picks one of the K samples that ``rmi control-bench`` already executed and kept in
``control_samples.parquet``, so every scorer's controller can be measured again, as executed,
from those files alone (:func:`rmi_learn.control_bench.rerank.rerank`). This script re-ranks a
finished benchmark output with each world model under ``--wm`` on its own, and with ensembles
of them at several disagreement weights (J_D, the spread of the members' water forecasts in
grams), and prints per size and policy the executed error, the paired ratio to the first
sample and the mean Spearman correlation of predicted and executed error.

    .venv/bin/python studies/scorer_rerank.py --control OUT/control [--wm OUT/wm] \\
        [--ensembles all,wt+ac-gru] [--weights 0,0.5,1,2] [--kind drawn] [--json]

Choose on one split's states (``rmi control-bench --split val``) and report on another's.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from rmi_learn import world_models as models
from rmi_learn.control_bench.inputs import SCORER_NAMES
from rmi_learn.control_bench.rerank import load_samples, rerank, summary
from rmi_learn.planning.cost import CostWeights
from rmi_learn.planning.scorers import EnsembleScorer, can_score, world_model_scorer


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--control", type=Path, required=True, help="rmi control-bench output")
    ap.add_argument("--wm", type=Path, default=None, help="world models (default: the bench's)")
    ap.add_argument("--ensembles", default="all", help="'+'-joined members, comma-separated")
    ap.add_argument("--weights", default="0,0.5,1,2", help="disagreement weights of ensembles")
    ap.add_argument("--kind", default="drawn", choices=("drawn", "logged", "given"))
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = ap.parse_args(argv)
    torch.set_num_threads(2)

    _, info = load_samples(args.control)
    wm_dir = args.wm or Path(info["wm"])
    horizon = int(info["horizon"])
    fns: dict[str, Any] = {}
    for cfg in sorted(wm_dir.glob("*/config.json")):
        model, _ = models.load(cfg.parent)
        if can_score(model, horizon) is None:
            fns[SCORER_NAMES.get(cfg.parent.name, cfg.parent.name)] = world_model_scorer(model)
    configs: dict[str, tuple[Any, Any]] = {n: (f, None) for n, f in fns.items()}
    for spec in (s for s in args.ensembles.split(",") if s.strip()):
        members = list(fns) if spec == "all" else spec.split("+")
        missing = [m for m in members if m not in fns]
        if missing:
            print(f"scorer_rerank: --ensembles {spec}: no scorer {missing}", file=sys.stderr)
            return 2
        ens = EnsembleScorer({m: fns[m] for m in members})
        for w in (float(x) for x in args.weights.split(",")):
            configs[f"ens[{spec}] w={w:g}"] = (ens, replace(CostWeights(), disagreement=w))
    ranked = rerank(args.control, configs)
    result = {name: summary(groups, args.kind) for name, groups in ranked.items()}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    sizes = sorted({s for r in result.values() for s in r}, key=int)
    objs = sorted({o for r in result.values() for s in r.values() for o in s})
    for obj in objs:
        print(
            f"\n{args.kind} goals, policy {obj}: median executed error (g) | ratio to first "
            "[95 % CI] | W/T/L | Spearman"
        )
        print("| scorer | " + " | ".join(f"{s} cm err | ratio | W/T/L | rho" for s in sizes) + " |")
        print("|---|" + "---:|" * (4 * len(sizes)))
        any_res = next(iter(result.values()))
        for label, key in (("first sample", "first_median"), ("best-of-K", "best_of_k_median")):
            cells = [
                f"{any_res[s][obj][key]:.2f} | - | - | -"
                if obj in any_res.get(s, {})
                else "- | - | - | -"
                for s in sizes
            ]
            print(f"| {label} | " + " | ".join(cells) + " |")
        for name, res in result.items():
            cells = []
            for s in sizes:
                e = res.get(s, {}).get(obj)
                if e is None:
                    cells.append("- | - | - | -")
                    continue
                lo, hi = e["ratio_median_ci"]
                rho = "n/a" if e["spearman_mean"] is None else f"{e['spearman_mean']:.2f}"
                cells.append(
                    f"{e['median']:.2f} | {e['ratio_median']:.2f} [{lo:.2f}, {hi:.2f}] | "
                    f"{e['wins']}/{e['ties']}/{e['losses']} | {rho}"
                )
            print(f"| {name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
