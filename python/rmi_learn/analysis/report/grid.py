"""The report's run-grid section: what the sweep ran, finished and used for learning, and the
lift success by holding force."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.inputs import note_missing, read_json


def section_grid(doc: Doc, out: Path) -> None:
    """The run grid: counts, particle sizes, wall time, runs used for learning, lift
    success by holding force."""

    doc.h(2, "Run grid")
    index_path = out / "sweep" / "index.parquet"
    if not index_path.exists():
        note_missing(doc, "the run index", "sweep")
        return
    idx = pl.read_parquet(index_path)
    grid = read_json(out / "sweep" / "grid.json") or {}
    ok = idx.filter(pl.col("status") == "ok")
    ds = read_json(out / "dataset" / "dataset.json") or {}
    wall = idx["wall_s"].drop_nulls().to_numpy()
    rows = [
        ["grid", f"{grid.get('name', '?')}: {grid.get('description', '')}"],
        ["runs", str(idx.height)],
        ["finished / failed / unstable"]
        + [
            " / ".join(
                str(idx.filter(pl.col("status") == s).height) for s in ("ok", "failed", "unstable")
            )
        ],
        ["lift success", f"{int(ok['lift_success'].sum())} of {ok.height}"],
        ["stable squeeze", f"{int(ok['stable_squeeze'].sum())} of {ok.height}"],
        ["particle radius", f"{grid.get('radius_m', float('nan')) * 1000:.1f} mm"],
        [
            "simulation wall time",
            f"{wall.sum():.0f} s in total, {wall.mean() if wall.size else 0.0:.1f} s per run",
        ],
    ]
    for key in ("n_fluid", "n_solid"):
        if key in idx.columns:
            vals = idx[key].drop_nulls()
            if vals.len():
                lo, hi = int(vals.min()), int(vals.max())  # type: ignore[arg-type]
                rows.append([f"particles ({key[2:]})", f"{lo}-{hi}"])
    if ds:
        splits = ds.get("splits", {})
        rows.append(
            [
                "runs used for learning",
                f"{ds.get('counts', {}).get('kept', '?')} ("
                + ", ".join(f"{k} {v.get('runs', 0)}" for k, v in sorted(splits.items()))
                + ")",
            ]
        )
    doc.table(["", "value"], rows, text=True)
    if ok.height:
        piv = (
            ok.group_by("size_cm", "porosity", "F_hold")
            .agg(pl.col("lift_success").mean().alias("rate"))
            .sort("size_cm", "porosity", "F_hold")
        )
        holds = sorted(piv["F_hold"].unique().to_list())
        trows = []
        for (size, phi), g in piv.group_by(["size_cm", "porosity"], maintain_order=True):
            rates = dict(zip(g["F_hold"].to_list(), g["rate"].to_list(), strict=True))
            trows.append(
                [f"{size} cm, phi {phi:g}"]
                + [f"{100 * rates[h]:.0f} %" if h in rates else "–" for h in holds]
            )
        doc.p("Lift success by holding force (rows: size and porosity; runs that finished).")
        doc.table(["size, porosity"] + [f"{h:g} N" for h in holds], trows)
    doc.p(
        "Query the grid yourself: `pl.read_parquet('OUT/sweep/index.parquet')` or "
        "`rmi_learn.data.runs.scan_runs('OUT/sweep/runs')` for every recorded channel."
    )
