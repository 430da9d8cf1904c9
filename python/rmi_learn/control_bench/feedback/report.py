"""The protocol benchmark's Markdown table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


def _f(v: float | None, d: int = 2) -> str:
    return "-" if v is None else f"{v:.{d}f}"


def _ci(c: Sequence[float | None] | None, d: int = 2) -> str:
    if not c or c[0] is None:
        return ""
    return f" [{_f(c[0], d)}, {_f(c[1], d)}]"


def _own(v: float | None, where: str = "") -> str:
    return "" if v is None else f" (the held-out group's own probes {where}{v * 1e3:.2f})"


def _spread(v: Sequence[float]) -> str:
    return f"{min(v):.2f}-{max(v):.2f}" if v else "-"


def _line(cell: Mapping[str, Any], name: str) -> Mapping[str, Any] | None:
    return next(
        (c for c in cell["controllers"] if c["controller"] == name and c.get("states")), None
    )


def findings(result: Mapping[str, Any]) -> list[str]:
    """One sentence per size and task: the privileged PI's median, the sensor-mode reference
    PI's, and each learned or calibrated sensor controller's ratio to it, with whether its
    interval lies below 1 (better), above (worse) or spans it."""
    refs = result["protocol"]["references"]
    out = []
    for cell in result["summary"]:
        parts = []
        priv = _line(cell, refs.get("privileged", ""))
        if priv:
            parts.append(f"{priv['controller']} median {_f(priv.get('median_g'))} g")
        ref = _line(cell, refs.get("sensors", ""))
        if ref:
            parts.append(f"{ref['controller']} median {_f(ref.get('median_g'))} g")
        for c in cell["controllers"]:
            ci = c.get("ratio_ci") or [None, None]
            if (
                c["mode"] != "sensors"
                or c["controller"] == (ref or {}).get("controller")
                or ci[0] is None
            ):
                continue
            verdict = "better" if ci[1] < 1 else "worse" if ci[0] > 1 else "not separated"
            parts.append(
                f"{c['controller']} {_f(c.get('median_g'))} g, "
                f"ratio {_f(c.get('ratio_to_reference'))}"
                f"{_ci(ci)} ({verdict})"
            )
        out.append(f"{cell['size_cm']} cm, {cell['task']}: " + "; ".join(parts) + ".")
    return out


def markdown(result: Mapping[str, Any]) -> str:
    """Per size and task: each controller's median and mean executed error (g) with 95 %
    cluster-bootstrap intervals, its ratio of mean errors to its mode's reference PI and the
    paired wins / ties / losses against it."""
    p = result["protocol"]
    lines = [
        f"# Goal-reaching benchmark, protocol `{p['name']}` "
        f"(digest `{result['protocol_digest'][:12]}`)",
        "",
        "Executed in the simulator from held-out conditions; errors |M_L - g| in grams; intervals",
        "are 95 % cluster bootstraps over runs; ratios are mean error over the reference PI's",
        "on the same states and goals (below 1: better than the reference).",
        "",
    ]
    for cell in result["summary"]:
        lines += [
            f"## {cell['size_cm']} cm, {cell['task']}",
            "",
            "| controller | mode | states (runs) | median g | mean g | ratio to ref "
            "| W/T/L vs ref |",
            "|---|---|---|---|---|---|---|",
        ]
        for c in cell["controllers"]:
            wtl = c.get("wins_ties_losses")
            lines.append(
                f"| {c['controller']} | {c['mode']} | {c['states']} ({c['runs']})"
                f"{' +' + str(c['failed']) + ' failed' if c['failed'] else ''} | "
                f"{_f(c.get('median_g'))}{_ci(c.get('median_ci'))} | "
                f"{_f(c.get('mean_g'))}{_ci(c.get('mean_ci'))} | "
                f"{_f(c.get('ratio_to_reference'))}{_ci(c.get('ratio_ci'))} | "
                f"{'/'.join(map(str, wtl)) if wtl else '-'} |"
            )
        lines.append("")
    lines += ["## Findings", "", *(f"- {x}" for x in findings(result)), ""]
    lines += [
        "## Estimators per fold (held-out group porosity/F_hold; RMS error on the training "
        "runs, g)",
        "",
    ]
    for size, per in result["estimators"].items():
        for fold, rep in per.items():
            cv = min(v for v in rep["learned_cv_rms_kg"].values())
            settle = ""
            if "settle_left_out_rms_kg" in rep:
                left = [v * 1e3 for v in rep["settle_left_out_rms_kg"].values()]
                spread = _spread(left)
                settle = (
                    f"; water outside the pores after the release {rep['settle_rms_kg'] * 1e3:.2f} "
                    f"(each training group left out {spread}; target spread "
                    f"{rep['settle_target_std_kg'] * 1e3:.2f}) over {rep['probes']} probes"
                    + _own(rep.get("settle_own_group_rms_kg"))
                )
            if "plan_left_out_rms_kg" in rep:
                left = [v * 1e3 for v in rep["plan_left_out_rms_kg"].values()]
                first = [v * 1e3 for v in rep["plan_left_out_start_rms_kg"].values()]
                settle += (
                    f"; settled-water model on {rep['plan_inputs']} {rep['plan_rms_kg'] * 1e3:.2f} "
                    f"(each training group "
                    f"left out {_spread(left)}, from a probe's start {_spread(first)}) over "
                    f"{rep['plan_rows']} path rows"
                    + _own(rep.get("plan_own_group_start_rms_kg"), "at a probe's start ")
                )
            lines.append(
                f"- {size} cm, fold {fold}: weight {rep['weight_rms_kg'] * 1e3:.2f}, "
                f"width {rep['width_rms_kg'] * 1e3:.2f}, learned {rep['learned_rms_kg'] * 1e3:.2f} "
                f"(left-out training group {cv * 1e3:.2f}) over {rep['rows']} rows{settle}"
            )
    lines += ["", "## Tuned PI gains per fold (ki N/(kg s), kp N/kg)", ""]
    for size, per in result["gains"].items():
        for fold, g in per.items():
            lines.append(
                f"- {size} cm, fold {fold}: "
                + ", ".join(f"{k} {v[0]:g}/{v[1]:g}" for k, v in g.items())
            )
    return "\n".join(lines) + "\n"


__all__ = ["findings", "markdown"]
