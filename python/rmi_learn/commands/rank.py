"""``rmi rank``: rank K = 8 policy samples per test window with the world model W_T.

For every window of the split (per sponge size) and every given policy, the planner draws
K chunks of H_pi = 32 commands in one batch, limits forces to [0, 400] N, scores the chunks and
the collected (original) chunk with W_T and selects the chunk with the smallest combined cost
J (see :mod:`rmi_learn.policy.ranking`). The goal g is the collected M_L at t + 32.

Writes to ``--out``:

- ``table3_ranking.{md,json}``: W_T-predicted terminal water error |M_hat - g| in grams for
  the original chunk, the first sample and the selected sample, per size and objective.
- ``table5_imitation.{md,json}``: force MAE of the first sample against the original chunk and
  its mean absolute force change per step (smooth_F), in N.
- ``tableS1_cost.{md,json}``: combined predicted cost J.
- ``chunks_<objective>.npz``: per window the run, anchor row, goal, the original, first and
  selected chunks in physical units (N, m/s), the selected index and every sample's J, for
  closed-loop execution.

All errors are the scorer's own predictions (biased toward the scorer that selected the
chunk); closed-loop execution in the simulator gives the real error.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from rmi_learn.commands import InputError
from rmi_learn.commands.argtypes import count, positive

SIZES = (8, 10, 12)
LABELS = {"diffusion": "Diffusion policy", "flow": "Flow matching"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi rank``."""
    parser.add_argument("--data", required=True, type=Path, help="built dataset directory")
    parser.add_argument("--wm", required=True, type=Path, help="W_T run directory (train-wm)")
    parser.add_argument("--diffusion", type=Path, default=None, help="diffusion policy run")
    parser.add_argument("--flow", type=Path, default=None, help="flow-matching policy run")
    parser.add_argument("--out", required=True, type=Path, help="directory for the tables")
    parser.add_argument("--split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--k", type=count(1), default=8, help="samples per window")
    parser.add_argument(
        "--max-windows", type=count(0), default=0, help="per size, evenly spaced subset (0: all)"
    )
    parser.add_argument("--batch-size", type=count(1), default=64, help="windows per batch")
    parser.add_argument("--seed", type=count(0), default=0)
    parser.add_argument("--force-limit", type=positive, default=400.0, help="N")
    parser.add_argument("--weights", default="model.ema", help="policy weights file stem")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=count(1), default=None)


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def _markdown(title: str, header: list[str], rows: list[list[str]]) -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join(["---"] + [":---:"] * (len(header) - 1)) + "|")
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _write(out: Path, stem: str, md: str, payload: dict[str, Any]) -> None:
    (out / f"{stem}.md").write_text(md, encoding="utf-8")
    (out / f"{stem}.json").write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")


def _stats_close(a: Any, b: Any) -> bool:
    import numpy as np

    return all(
        np.allclose(np.asarray(getattr(a, k)), np.asarray(b[k]), rtol=1e-6, atol=0.0)
        for k in ("z_mean", "z_std", "u_mean", "u_std")
    )


def run(args: argparse.Namespace) -> int:
    """Rank policy samples and write Tables III, V and S1. Returns 0 on success."""
    import numpy as np
    import torch

    from rmi_learn import models
    from rmi_learn.dataset import load_dataset
    from rmi_learn.policy.checkpoint import goal_from_batch, load_policy
    from rmi_learn.policy.ranking import Planner, Standardiser, world_model_scorer

    if args.threads:
        torch.set_num_threads(args.threads)
    policies = {k: p for k, p in (("diffusion", args.diffusion), ("flow", args.flow)) if p}
    if not policies:
        raise InputError("give --diffusion and/or --flow")
    # Every input is loaded and checked before --out exists: a wrong directory, model kind
    # or horizon is a one-line error, not a traceback after half the work.
    try:
        ds = load_dataset(args.data)
        wm, wm_cfg = models.load(args.wm)
        loaded = {k: load_policy(p, args.weights, args.device) for k, p in policies.items()}
        for name, (net, _, _) in loaded.items():
            h = net.config.horizon
            try:
                wm.check_horizon_length(h)
            except ValueError:
                fixed, longest = wm.fixed_horizon, wm.max_horizon
                takes = f"exactly {fixed}" if fixed is not None else f"at most {longest}"
                raise ValueError(
                    f"--wm {args.wm}: the {wm.kind} world model scores chunks of {takes} "
                    f"steps, the --{name} policy's have {h}"
                ) from None
    except ValueError as exc:
        raise InputError(exc) from exc
    wm = wm.to(args.device)
    wm_stats = (wm_cfg.get("extra") or {}).get("stats")
    if wm_stats is not None and not _stats_close(ds.stats, wm_stats):
        raise InputError("W_T was trained with other standardisation statistics")
    std = Standardiser.from_stats(ds.stats)
    std = Standardiser(*(x.to(args.device) for x in (std.z_mean, std.z_std, std.u_mean, std.u_std)))
    scorer = world_model_scorer(wm)
    args.out.mkdir(parents=True, exist_ok=True)
    sizes = [s for s in SIZES if len(ds.split_runs(args.split, s)) > 0]

    # results[source][size] -> dict of per-window arrays
    per: dict[str, dict[int, dict[str, np.ndarray]]] = {}
    n_windows: dict[int, int] = {}
    timing: dict[str, float] = {}
    for obj_name, (net, objective, pcfg) in loaded.items():
        planner = Planner(net, objective, scorer, std, k=args.k, force_limit=args.force_limit)
        t0 = time.perf_counter()
        per[obj_name] = {}
        chunks: dict[str, list[np.ndarray]] = {}
        for size in sizes:
            ws = ds.windows(
                args.split,
                size,
                history=int(pcfg["model"]["history"]),
                horizon=net.config.horizon,
            )
            idx = np.arange(len(ws))
            if args.max_windows and len(ws) > args.max_windows:
                idx = np.unique(np.linspace(0, len(ws) - 1, args.max_windows).round()).astype(
                    np.int64
                )
            n_windows[size] = int(idx.size)
            gen = torch.Generator().manual_seed(args.seed * 1000 + size)
            acc: dict[str, list[np.ndarray]] = {}
            for start in range(0, idx.size, args.batch_size):
                b = ws.batch(idx[start : start + args.batch_size])
                b = {k: v.to(args.device) for k, v in b.items()}
                g_std, _ = goal_from_batch(b)
                res = planner.plan(
                    b["hist"], b["hist_mask"], g_std, b["water_now"], b["actions"], gen
                )
                assert res.original is not None
                first, sel, orig = res.first, res.selected, res.original
                cols: dict[str, torch.Tensor] = {
                    "orig_JM": res.original_costs["J_M"],
                    "orig_J": res.original_costs["J"],
                    "first_JM": res.first_costs()["J_M"],
                    "first_J": res.first_costs()["J"],
                    "sel_JM": res.selected_costs()["J_M"],
                    "sel_J": res.selected_costs()["J"],
                    "mae_F": (first[..., 0] - orig[..., 0]).abs().mean(-1),
                    "smooth_F": first[..., 0].diff(dim=-1).abs().mean(-1),
                    "orig_smooth_F": orig[..., 0].diff(dim=-1).abs().mean(-1),
                    "sel_mae_F": (sel[..., 0] - orig[..., 0]).abs().mean(-1),
                }
                for k, v in cols.items():
                    acc.setdefault(k, []).append(v.cpu().numpy())
                water_now_kg = std.water_to_kg(b["water_now"])
                for k, v in {
                    "size_cm": torch.full_like(res.goal_kg, float(size)),
                    "run": b["run"],
                    "t": b["t"],
                    "goal_kg": res.goal_kg,
                    "water_now_kg": water_now_kg,
                    "original": orig,
                    "first": first,
                    "selected": sel,
                    "index": res.index,
                    "J_samples": res.costs["J"],
                    "J_M_samples": res.costs["J_M"],
                }.items():
                    chunks.setdefault(k, []).append(v.cpu().numpy())
            per[obj_name][size] = {k: np.concatenate(v) for k, v in acc.items()}
        timing[obj_name] = time.perf_counter() - t0
        arrays = {k: np.concatenate(v) for k, v in chunks.items()}
        arrays["size_cm"] = arrays["size_cm"].astype(np.int64)
        arrays["run_id"] = np.asarray([ds.run_ids[int(r)] for r in arrays["run"]])
        np.savez_compressed(args.out / f"chunks_{obj_name}.npz", **arrays)  # type: ignore[arg-type]

    def mean(obj: str, size: int, key: str) -> float | None:
        d = per.get(obj, {}).get(size)
        return None if d is None or d[key].size == 0 else float(d[key].mean())

    first_obj = next(iter(policies))
    header = ["Method"] + [f"{s} cm" for s in SIZES]

    def row(label: str, obj: str, key: str) -> tuple[list[str], dict[str, Any]]:
        vals = {str(s): mean(obj, s, key) for s in SIZES}
        return [label] + [_fmt(vals[str(s)]) for s in SIZES], {"method": label, **vals}

    common = {
        "split": args.split,
        "k": args.k,
        "n_windows": {str(s): n_windows.get(s, 0) for s in SIZES},
        "scorer": str(args.wm),
        "policies": {k: str(v) for k, v in policies.items()},
        "note": "predicted by the scorer W_T that selects the chunk (biased toward it)",
    }

    def source_rows(metric: str) -> tuple[list[list[str]], list[dict[str, Any]]]:
        """Rows of one metric for the original action, each first sample and each selection
        (Tables III and S1 share this layout)."""
        sources = [("Original controller action", first_obj, f"orig_{metric}")] + [
            item
            for o in policies
            for item in (
                (f"{LABELS[o]}, first sample", o, f"first_{metric}"),
                (f"{LABELS[o]} + W_T", o, f"sel_{metric}"),
            )
        ]
        built = [row(label, obj, key) for label, obj, key in sources]
        return [m for m, _ in built], [j for _, j in built]

    # Table III
    md_rows, js_rows = source_rows("JM")
    _write(
        args.out,
        "table3_ranking",
        _markdown(
            "Table III. W_T-predicted terminal water error |M_hat - g| (g), K = "
            f"{args.k}, {args.split} split",
            header,
            md_rows,
        ),
        {"table": "III", "unit": "g", "rows": js_rows, **common},
    )

    # Table V
    header5 = ["Method"] + [f"{s} cm {q}" for s in SIZES for q in ("MAE_F (N)", "smooth_F (N)")]
    md5, js5 = [], []
    for o in policies:
        vals = {
            str(s): {"MAE_F": mean(o, s, "mae_F"), "smooth_F": mean(o, s, "smooth_F")}
            for s in SIZES
        }
        md5.append(
            [LABELS[o]] + [_fmt(vals[str(s)][q]) for s in SIZES for q in ("MAE_F", "smooth_F")]
        )
        js5.append({"method": LABELS[o], **vals})
    ref = {str(s): {"MAE_F": 0.0, "smooth_F": mean(first_obj, s, "orig_smooth_F")} for s in SIZES}
    md5.append(
        ["Original controller action (reference)"]
        + [
            _fmt(ref[str(s)][q]) if q == "smooth_F" else "-"
            for s in SIZES
            for q in ("MAE_F", "smooth_F")
        ]
    )
    js5.append({"method": "Original controller action (reference)", **ref})
    _write(
        args.out,
        "table5_imitation",
        _markdown(
            "Table V. Force MAE of one policy sample against the collected command and its "
            "mean absolute force change per step (N)",
            header5,
            md5,
        ),
        {"table": "V", "unit": "N", "rows": js5, **common},
    )

    # Table S1
    mds, jss = source_rows("J")
    _write(
        args.out,
        "tableS1_cost",
        _markdown(
            "Table S1. Combined predicted cost J = J_M + 1e-4 J_F + 0.05 J_S + 0.1 J_U",
            header,
            mds,
        ),
        {"table": "S1", "unit": "-", "rows": jss, **common},
    )
    summary = {"out": str(args.out), "n_windows": common["n_windows"], "seconds": timing}
    print(json.dumps(summary, indent=2))
    return 0
