"""Do the paper's relative world-model claims survive another choice of held-out runs?

One study's test split holds one to five runs per sponge size, so a single table can turn on
one run. Build the dataset again with other split seeds (``rmi dataset build --seed S``: the
same runs, other groups held out), train and evaluate the models on each (``rmi train-wm``,
``rmi eval-wm --split test``), and give the ``eval-wm`` output directories here, one per split.
Per sponge size and split it prints, at 0.64 s (``--step``), the water MAE (g) and force MAE
(N) of the Baseline, AC-GRU-WM, State-GRU-WM and the shuffled-chunk AC-GRU-WM, and AC-GRU-WM's
water-error reduction against the Baseline. The pooled line per size weights each split's MAE by
its test windows; the claim lines count the splits where each of the paper's relative claims holds.

    .venv/bin/python studies/wm_splits.py --tables T_SEED0 T_SEED1 T_SEED2 [--step 32] [--json]

The splits share training runs, so they are not independent samples: the counts say how often
a claim holds under another choice of held-out groups, not a significance level.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from rmi_learn.world_models.evaluation import SIZES, lookup
from rmi_learn.world_models.horizons import MAIN_STEP, horizon_label

#: The rows compared, keyed as in ``rmi eval-wm``'s results.json.
ROWS: dict[str, dict[str, Any]] = {
    "baseline": {"kind": "baseline"},
    "ac-gru": {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False},
    "state-gru": {"kind": "state-gru", "state_groups": "ALL", "shuffled": False},
    "ac-gru-shuffled": {"kind": "ac-gru", "state_groups": "ALL", "shuffled": True},
}

#: (name, better row, worse row, metric): the paper's relative claims, each per size and split.
CLAIMS: tuple[tuple[str, str, str, str], ...] = (
    ("AC-GRU-WM water < Baseline", "ac-gru", "baseline", "water"),
    ("AC-GRU-WM water < State-GRU-WM", "ac-gru", "state-gru", "water"),
    ("AC-GRU-WM force < State-GRU-WM", "ac-gru", "state-gru", "force"),
    ("AC-GRU-WM water < shuffled chunks", "ac-gru", "ac-gru-shuffled", "water"),
    ("AC-GRU-WM force < shuffled chunks", "ac-gru", "ac-gru-shuffled", "force"),
)


def load(table_dir: str | Path) -> list[dict[str, Any]]:
    """The records of one ``rmi eval-wm`` output directory (its results.json)."""
    path = Path(table_dir) / "results.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no results.json (give rmi eval-wm --out directories)")
    records: list[dict[str, Any]] = json.loads(path.read_text(encoding="utf-8"))
    return records


def split_seed(table_dir: str | Path, records: list[dict[str, Any]]) -> Any:
    """The split seed ``rmi eval-wm`` recorded in ``records`` (``split_seed``), or None for
    tables written before it did; several seeds in one table are an error."""
    seeds: set[Any] = {r.get("split_seed") for r in records} - {None}
    if len(seeds) > 1:
        raise ValueError(f"{table_dir}: records from several split seeds {sorted(seeds)}")
    return seeds.pop() if seeds else None


def load_tables(table_dirs: list[str]) -> dict[str, list[dict[str, Any]]]:
    """``{label: records}`` of several ``rmi eval-wm`` outputs, labelled ``split seed S (DIR)``
    (or ``DIR`` without a recorded seed), refusing two tables of one split seed (the same
    held-out runs counted twice)."""
    tables: dict[str, list[dict[str, Any]]] = {}
    seen: dict[Any, str] = {}
    for t in table_dirs:
        recs = load(t)
        seed = split_seed(t, recs)
        if seed is None:
            tables[str(t)] = recs
            continue
        if seed in seen:
            raise ValueError(f"{seen[seed]} and {t} both evaluate split seed {seed}")
        seen[seed] = t
        tables[f"split seed {seed} ({t})"] = recs
    return tables


def cells(records: list[dict[str, Any]], step: int) -> dict[int, dict[str, dict[str, float]]]:
    """``{size: {row: {"water", "force", "windows"}}}`` at ``step`` for the rows present."""
    out: dict[int, dict[str, dict[str, float]]] = {}
    for size in SIZES:
        row_cells = {}
        for name, key in ROWS.items():
            rec = lookup(records, size_cm=size, **key)
            if rec is None:
                continue
            m = rec["metrics"]
            row_cells[name] = {
                "water": float(m[f"water_mae_g@{step}"]),
                "force": float(m[f"force_mae_n@{step}"]),
                "windows": float(m["windows"]),
            }
        out[size] = row_cells
    return out


def reduction(better: float | None, base: float | None) -> float | None:
    """``1 - better / base`` (0.6 = 60 % lower error), None without both or with base 0."""
    if better is None or base is None or not base > 0:
        return None
    return 1.0 - better / base


def summarise(tables: dict[str, list[dict[str, Any]]], step: int = MAIN_STEP) -> dict[str, Any]:
    """Per size: each split's cells and AC-GRU-WM's reduction against the Baseline, the
    window-weighted pooled MAE of each row over the splits that have it, the pooled reduction,
    and for each claim the number of splits where it holds out of those that have both rows."""
    per_split = {name: cells(recs, step) for name, recs in tables.items()}
    out: dict[str, Any] = {"step": step, "horizon": horizon_label(step), "sizes": {}}
    for size in SIZES:
        splits: dict[str, dict[str, Any]] = {}
        for name, c in per_split.items():
            row = c.get(size, {})
            base = row.get("baseline", {}).get("water")
            ac = row.get("ac-gru", {}).get("water")
            splits[name] = {"cells": row, "ac_gru_water_reduction": reduction(ac, base)}
        pooled: dict[str, dict[str, float]] = {}
        for r in ROWS:
            have = [s["cells"][r] for s in splits.values() if r in s["cells"]]
            n = sum(h["windows"] for h in have)
            if have and n > 0:
                pooled[r] = {
                    metric: sum(h[metric] * h["windows"] for h in have) / n
                    for metric in ("water", "force")
                } | {"windows": n, "splits": len(have)}
        claims = {}
        for claim, better, worse, metric in CLAIMS:
            both = [
                s["cells"] for s in splits.values() if better in s["cells"] and worse in s["cells"]
            ]
            held = sum(c[better][metric] < c[worse][metric] for c in both)
            claims[claim] = {"holds": held, "of": len(both)}
        out["sizes"][size] = {
            "splits": splits,
            "pooled": pooled,
            "pooled_ac_gru_water_reduction": reduction(
                pooled.get("ac-gru", {}).get("water"), pooled.get("baseline", {}).get("water")
            ),
            "claims": claims,
        }
    return out


def _cell(v: float | None, fmt: str = "6.1f") -> str:
    return "     –" if v is None else format(v, fmt)


def _pct(v: float | None) -> str:
    return "    –" if v is None else f"{100 * v:4.0f} %"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tables", nargs="+", required=True, help="rmi eval-wm output directories")
    ap.add_argument("--step", type=int, default=MAIN_STEP, help="forecast step (default 32)")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    a = ap.parse_args(argv)
    try:
        tables = load_tables(a.tables)
    except (OSError, ValueError) as exc:
        print(f"wm_splits: {exc}", file=sys.stderr)
        return 2
    res = summarise(tables, a.step)
    if a.json:
        json.dump(res, sys.stdout, indent=1)
        print()
        return 0
    names = list(ROWS)
    print(f"water MAE (g) / force MAE (N) at {res['horizon']}; reduction = AC-GRU-WM vs Baseline")
    width = max(len(t) for t in tables) + 2
    print(f"  {'split':{width}s} " + "  ".join(f"{n:>17s}" for n in names) + "  reduction")
    for size, s in res["sizes"].items():
        print(f"{size} cm")
        for split, v in s["splits"].items():
            c = v["cells"]
            line = "  ".join(
                f"{_cell(c.get(n, {}).get('water'))} / {_cell(c.get(n, {}).get('force'), '6.1f')}"
                for n in names
            )
            print(f"  {split:{width}s} {line}  {_pct(v['ac_gru_water_reduction'])}")
        p = s["pooled"]
        line = "  ".join(
            f"{_cell(p.get(n, {}).get('water'))} / {_cell(p.get(n, {}).get('force'), '6.1f')}"
            for n in names
        )
        pooled = "pooled (window-weighted)"
        print(f"  {pooled:{width}s} {line}  {_pct(s['pooled_ac_gru_water_reduction'])}")
        for claim, c in s["claims"].items():
            print(f"    {claim}: {c['holds']} of {c['of']} splits")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
