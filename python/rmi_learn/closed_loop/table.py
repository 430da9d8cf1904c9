"""The closed-loop experiment's results: the checkpointed rows of
``closed_loop_windows.parquet``, their summary and the Markdown table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.closed_loop.windows import OBJECTIVES, ClosedLoopError, Window
from rmi_learn.data.checkpoint_rows import read_rows, write_rows

LABELS = {"diffusion": "Diffusion policy", "flow": "Flow matching"}
WINDOWS_FILE = "closed_loop_windows.parquet"
TABLE_STEM = "table_closed_loop"
#: Metadata key of the inputs' fingerprint in ``closed_loop_windows.parquet``.
FINGERPRINT_KEY = "rmi.closed_loop.fingerprint"

#: Columns of ``closed_loop_windows.parquet`` and their types.
ROW_SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "size_cm": pl.Int64,
    "t": pl.Int64,
    "k": pl.Int64,
    "anchor_time_s": pl.Float64,
    "anchor_phase": pl.String,
    "goal_phase": pl.String,
    "objective": pl.String,
    "chunk": pl.String,
    "sample_index": pl.Int64,
    "command": pl.String,
    "goal_kg": pl.Float64,
    "water_now_kg": pl.Float64,
    "M_L_real_kg": pl.Float64,
    "err_real_g": pl.Float64,
    "err_pred_g": pl.Float64,
    "status": pl.String,
    "failure": pl.String,
    "phase_end": pl.String,
    "dev_M_L_max_g": pl.Float64,
    "dev_F_rms_N": pl.Float64,
    "error": pl.String,
    "wall_s": pl.Float64,
    "replay_wall_s": pl.Float64,
}


def read_checkpoint(path: Path, fingerprint: str) -> list[dict[str, Any]]:
    """The rows stored at ``path`` (none when it does not exist); refuses a file of other
    inputs or columns, since resuming it would mix results."""
    if not path.exists():
        return []
    try:
        meta, df = read_rows(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same advice
        raise ClosedLoopError(f"{path} is not readable ({exc}); delete it to start over") from exc
    if meta.get(FINGERPRINT_KEY) != fingerprint:
        raise ClosedLoopError(
            f"{path} holds results of other inputs (chunk files or --command differ); "
            "use another --out or delete that file to start over"
        )
    if set(df.columns) != set(ROW_SCHEMA):
        raise ClosedLoopError(f"{path} has other columns than this version writes; delete it")
    return df.to_dicts()


def write_checkpoint(path: Path, rows: Sequence[Mapping[str, Any]], meta: dict[str, str]) -> None:
    """Rewrite every row to ``path`` atomically, with the fingerprint metadata ``meta``."""
    write_rows(path, rows, ROW_SCHEMA, meta)


def _mean(xs: Sequence[float]) -> float | None:
    return float(np.mean(xs)) if xs else None


def _std(xs: Sequence[float]) -> float | None:
    return float(np.std(xs)) if xs else None


def summarise(rows: Sequence[Mapping[str, Any]], windows: Sequence[Window]) -> dict[str, Any]:
    """Per size and objective: mean real terminal error (g) of the original, first and
    selected chunks over the windows where all three executed, its standard deviation, the
    scorer's predicted errors of the same windows, the fraction of windows where the selected
    chunk is strictly better (and tied) in reality, the ratio selected / first of the mean
    real errors, grasp failures, chunks that end in another controller phase than the
    collected trajectory at the goal row (e.g. a hold whose lift gate did not open), and
    chunks that could not be executed."""
    wanted = {(w.run_id, w.t) for w in windows}
    by_key: dict[tuple[str, int, str | None, str], Mapping[str, Any]] = {}
    for r in rows:
        if (r["run_id"], r["t"]) in wanted:
            by_key[(r["run_id"], r["t"], r["objective"], r["chunk"])] = r
    out: dict[str, Any] = {}
    for size in sorted({w.size_cm for w in windows}):
        ws = [w for w in windows if w.size_cm == size]
        orig = [by_key.get((w.run_id, w.t, None, "original")) for w in ws]
        ok_orig = [r for r in orig if r is not None and r["status"] == "ok"]
        entry: dict[str, Any] = {
            "n_windows": len(ws),
            "original": {
                "n": len(ok_orig),
                "real_g": _mean([r["err_real_g"] for r in ok_orig]),
                "real_sd_g": _std([r["err_real_g"] for r in ok_orig]),
                "dev_F_rms_N": _mean([r["dev_F_rms_N"] for r in ok_orig]),
                "dev_M_L_max_g": _mean([r["dev_M_L_max_g"] for r in ok_orig]),
                "failures": sum(1 for r in ok_orig if r["failure"]),
                "phase_differs": sum(1 for r in ok_orig if r["phase_end"] != r["goal_phase"]),
            },
        }
        for obj in OBJECTIVES:
            trip = []
            not_run = 0
            for w, o in zip(ws, orig, strict=True):
                if obj not in dict(w.rows):
                    continue
                f = by_key.get((w.run_id, w.t, obj, "first"))
                s = by_key.get((w.run_id, w.t, obj, "selected"))
                if o is None or f is None or s is None:
                    not_run += 1
                    continue
                if any(r["status"] != "ok" for r in (o, f, s)):
                    not_run += 1
                    continue
                trip.append((o, f, s))
            if not trip and not not_run:
                continue
            fr = [f["err_real_g"] for _, f, _ in trip]
            sr = [s["err_real_g"] for _, _, s in trip]
            fp = [f["err_pred_g"] for _, f, _ in trip if f["err_pred_g"] is not None]
            sp = [s["err_pred_g"] for _, _, s in trip if s["err_pred_g"] is not None]
            mf, ms = _mean(fr), _mean(sr)
            entry[obj] = {
                "n": len(trip),
                "not_executed": not_run,
                "original_real_g": _mean([o["err_real_g"] for o, _, _ in trip]),
                "first_real_g": mf,
                "first_real_sd_g": _std(fr),
                "selected_real_g": ms,
                "selected_real_sd_g": _std(sr),
                "first_pred_g": _mean(fp) if len(fp) == len(trip) else None,
                "selected_pred_g": _mean(sp) if len(sp) == len(trip) else None,
                "selected_beats_first": _mean([float(s < f) for f, s in zip(fr, sr, strict=True)]),
                "tied": _mean([float(s == f) for f, s in zip(fr, sr, strict=True)]),
                "ratio_selected_first": (ms / mf) if mf and ms is not None else None,
                "failures_first": sum(1 for _, f, _ in trip if f["failure"]),
                "failures_selected": sum(1 for _, _, s in trip if s["failure"]),
                "phase_differs_first": sum(
                    1 for _, f, _ in trip if f["phase_end"] != f["goal_phase"]
                ),
                "phase_differs_selected": sum(
                    1 for _, _, s in trip if s["phase_end"] != s["goal_phase"]
                ),
            }
        out[str(size)] = entry
    return out


def _fmt(v: float | None, digits: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def markdown(summary: Mapping[str, Any], info: Mapping[str, Any]) -> str:
    sizes = list(summary)
    objs = [o for o in OBJECTIVES if any(o in summary[s] for s in sizes)]
    head = "| Method | " + " | ".join(f"{s} cm" for s in sizes) + " |"
    rule = "|---|" + "|".join(":---:" for _ in sizes) + "|"
    lines = [
        "**Closed-loop terminal water error |M_L - g| (g), executed in the simulator "
        f"(command mode `{info['command']}`, {info['chunk_steps']} commands of 20 ms)**",
        "",
        head,
        rule,
        "| Original controller action (replayed at 20 ms) | "
        + " | ".join(_fmt(summary[s]["original"]["real_g"]) for s in sizes)
        + " |",
    ]
    scorer = info["scorer_name"]
    for o in objs:
        for label, key in (
            (f"{LABELS[o]}, first sample", "first"),
            (f"{LABELS[o]} + {scorer}", "sel"),
        ):
            field = "first_real_g" if key == "first" else "selected_real_g"
            lines.append(
                f"| {label} | "
                + " | ".join(_fmt(summary[s].get(o, {}).get(field)) for s in sizes)
                + " |"
            )
    lines.append(
        "| Windows | " + " | ".join(str(summary[s]["original"]["n"]) for s in sizes) + " |"
    )
    lines += [
        "",
        f"**Real (simulated) against {scorer}-predicted error of the same windows (g)**",
        "",
        "| Policy | Size | n | first: predicted | first: real | selected: predicted | "
        "selected: real | real selected / first | selected better (tied) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for o in objs:
        for s in sizes:
            e = summary[s].get(o)
            if e is None:
                continue
            lines.append(
                f"| {LABELS[o]} | {s} cm | {e['n']} | {_fmt(e['first_pred_g'])} | "
                f"{_fmt(e['first_real_g'])} | {_fmt(e['selected_pred_g'])} | "
                f"{_fmt(e['selected_real_g'])} | {_fmt(e['ratio_selected_first'])} | "
                f"{_fmt(e['selected_beats_first'])} ({_fmt(e['tied'])}) |"
            )
    lines += [
        "",
        "Replay fidelity of the original chunk (recorded commands held for 20 ms): mean RMS "
        "deviation of the grip load from the recorded one "
        + ", ".join(f"{s} cm {_fmt(summary[s]['original']['dev_F_rms_N'])} N" for s in sizes)
        + "; mean largest deviation of M_L over the chunk "
        + ", ".join(f"{s} cm {_fmt(summary[s]['original']['dev_M_L_max_g'])} g" for s in sizes)
        + "; windows whose replay ends in another phase than the collected run "
        + ", ".join(
            f"{s} cm {summary[s]['original']['phase_differs']}/{summary[s]['original']['n']}"
            for s in sizes
        )
        + ".",
        "",
        f"Goal g: the collected M_L at t + {info['chunk_steps']}. Sweep `{info['sweep']}`, chunks "
        f"`{info['chunks']}`. Predicted values are `J_M` of `rmi rank` (biased toward {scorer}, "
        "which selected the chunk).",
    ]
    return "\n".join(lines) + "\n"


__all__ = [
    "LABELS",
    "ROW_SCHEMA",
    "TABLE_STEM",
    "WINDOWS_FILE",
    "markdown",
    "read_checkpoint",
    "summarise",
    "write_checkpoint",
]
