"""How much of a world model's forecast error is its training seed.

Give several runs of one model trained with the same settings and different ``--seed``.
Per sponge size it prints the water MAE (g) and force MAE (N) of the free rollouts of the
Baseline, of every run, and of their average (the members' standardised states averaged step
by step, the contact and friction probabilities averaged and turned back into logits), at
0.16, 0.32, 0.64 and 1.28 s. The spread between the runs is what one training run can move a
table cell; the average shows how much of the error is that variance rather than bias.

    .venv/bin/python studies/wm_seeds.py --runs RUN_SEED0 RUN_SEED1 RUN_SEED2 \\
        --data DATASET [--split val|test|train] [--json]

Choose settings on ``--split val``; the test split is for reporting what was chosen.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from rmi_learn.world_models.horizons import HORIZON_STEPS as STEPS
from rmi_learn.world_models.horizons import horizon_label

SIZES = (8, 10, 12)


def average_forecasts(outs: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """The members' mean forecast: mean ``z``; contact and friction probabilities averaged,
    returned as logits (sigmoid / softmax of the result give the mean probabilities)."""
    z = torch.stack([o["z"] for o in outs]).mean(0)
    p_c = torch.stack([torch.sigmoid(o["contact_logit"]) for o in outs]).mean(0)
    p_f = torch.stack([torch.softmax(o["friction_logit"], dim=-1) for o in outs]).mean(0)
    return {"z": z, "contact_logit": torch.logit(p_c, eps=1e-7), "friction_logit": p_f.log()}


class Average(torch.nn.Module):
    """A world model whose forecast is :func:`average_forecasts` of ``members``."""

    def __init__(self, members: Sequence[torch.nn.Module]) -> None:
        super().__init__()
        self.members = torch.nn.ModuleList(members)

    def forward(
        self, hist: torch.Tensor, mask: torch.Tensor, actions: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        return average_forecasts([m(hist, mask, actions) for m in self.members])


def evaluate(runs: list[str], data: str, split: str) -> dict[str, Any]:
    """``{size: {name: metrics}}`` for the Baseline, each run and their average."""
    from rmi_learn import world_models as models
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.world_models.baseline import BaselineWM
    from rmi_learn.world_models.evaluation import evaluate_rollouts

    ds = load_dataset(data)
    members = [models.load(r)[0].eval() for r in runs]
    named: list[tuple[str, torch.nn.Module]] = [("Baseline", BaselineWM())]
    named += [(Path(r).name, m) for r, m in zip(runs, members, strict=True)]
    named.append((f"average of {len(runs)}", Average(members)))
    out: dict[str, Any] = {}
    for size in SIZES:
        ws = ds.windows(split, size_cm=size)
        if len(ws) == 0:
            continue
        out[str(size)] = {
            name: evaluate_rollouts(m, ws, ds.stats.z_std, steps=STEPS) for name, m in named
        }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="+", required=True, help="run directories (one per seed)")
    ap.add_argument("--data", required=True, help="built dataset directory")
    ap.add_argument("--split", default="val", choices=("train", "val", "test"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="print the metrics as JSON")
    a = ap.parse_args(argv)
    if len(a.runs) < 2:
        ap.error("--runs needs at least two runs")
    torch.set_num_threads(a.threads)
    res = evaluate(a.runs, a.data, a.split)
    if a.json:
        json.dump(res, sys.stdout, indent=1)
        print()
        return 0
    at = ", ".join(horizon_label(s) for s in STEPS)
    print(f"split {a.split}; water MAE (g) / force MAE (N) at {at}")
    for size, rows in res.items():
        print(f"{size} cm")
        for name, r in rows.items():
            cells = "  ".join(
                f"{r[f'water_mae_g@{s}']:6.2f} / {r[f'force_mae_n@{s}']:5.2f}" for s in STEPS
            )
            print(f"  {name:28s} {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
