"""Decision latency against executed error, per sampler step count and scorer.

Joins two measurements of the same policies:

- executed error: an ``rmi control-bench`` output whose policies are the same networks at
  several step counts (copies of a policy run with ``model.objective_config.n_sample_steps``
  set to N in ``config.json``, named ``<objective>-<N>``; the run itself at its own count;
  a distilled student named ``<objective>-1step``), run with ``--controllers
  first-sample,ranked``;
- latency: ``benches/bench_planning.py --json`` lines of the fast path (``path`` ``fast``
  or ``student``) for the same objectives, step counts and scorers.

Prints a Markdown table (median executed error on drawn goals per size, for the first sample
and each scorer's ranked choice, beside the decision's p50 latency with that scorer) and
writes a figure of median executed error against p50 latency, one panel per size.

    .venv/bin/python studies/latency_error.py --control OUT/control-steps \\
        --latency latency.jsonl --figure docs/latency_error.png
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

#: Scorer names of the benchmark's ranked controllers -> bench_planning's.
SCORERS = {"arx-32": "arx", "ac-gru": "gru", "wt": "wt"}
#: The objectives' own step counts (the paper's samplers).
OWN_STEPS = {"diffusion": 16, "flow": 20}


def policy_steps(name: str) -> tuple[str, int, str] | None:
    """``diffusion-4`` -> (diffusion, 4, fast); ``flow-1step`` -> (flow, 1, student);
    ``flow`` -> (flow, 20, fast); None for other names."""
    if name in OWN_STEPS:
        return name, OWN_STEPS[name], "fast"
    m = re.fullmatch(r"(diffusion|flow)-(\d+)(step)?", name)
    if m is None:
        return None
    return m.group(1), int(m.group(2)), "student" if m.group(3) else "fast"


def load_latency(path: Path) -> dict[tuple[str, str, int, str], float]:
    """{(path, objective, steps, scorer): p50 ms} from bench_planning --json lines."""
    out = {}
    for line in path.read_text().splitlines():
        rec = json.loads(line)
        if "p50_ms" in rec:
            out[rec["path"], rec["objective"], int(rec["steps"]), rec["scorer"]] = rec["p50_ms"]
    return out


def load_errors(control: Path) -> dict[tuple[str, str, int], dict[str, dict[int, float]]]:
    """{(path, objective, steps): {controller kind: {size: median error g}}} on drawn goals."""
    summary = json.loads((control / "table_control.json").read_text())["summary"]["drawn"]
    out: dict[tuple[str, str, int], dict[str, dict[int, float]]] = {}
    for size, s in summary.items():
        for ctrl, e in s["controllers"].items():
            if "/" not in ctrl:
                continue
            kind, policy = ctrl.split("/", 1)
            parsed = policy_steps(policy)
            if parsed is None:
                continue
            obj, steps, path = parsed
            out.setdefault((path, obj, steps), {}).setdefault(kind, {})[int(size)] = e["median"]
    return out


def table(errors: dict[Any, Any], latency: dict[Any, float], sizes: list[int]) -> str:
    cols = ["first-sample"] + [f"ranked-{s}" for s in SCORERS]
    head = (
        "| sampler | steps | p50 (ms): ARX / AC-GRU / W_T | "
        + " | ".join(f"{c} ({' / '.join(f'{z} cm' for z in sizes)})" for c in cols)
        + " |"
    )
    lines = [head, "|---|---:|---|" + "---|" * len(cols)]
    for path, obj, steps in sorted(errors, key=lambda k: (k[1], k[2], k[0])):
        lat = " / ".join(
            f"{latency[path, obj, steps, b]:.1f}" if (path, obj, steps, b) in latency else "-"
            for b in SCORERS.values()
        )
        cells = []
        for c in cols:
            v = errors[path, obj, steps].get(c, {})
            cells.append(" / ".join(f"{v[z]:.2f}" if z in v else "-" for z in sizes))
        label = f"{obj} {'student' if path == 'student' else 'teacher'}"
        lines.append(f"| {label} | {steps} | {lat} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(errors: dict[Any, Any], latency: dict[Any, float], sizes: list[int], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(sizes), figsize=(5.0 * len(sizes), 4.0), squeeze=False)
    marks = {"diffusion": "o", "flow": "s"}
    for ax, size in zip(axes[0], sizes, strict=True):
        for ci, (sc, b) in enumerate(SCORERS.items()):
            for obj in OWN_STEPS:
                pts = sorted(
                    (latency[k[0], obj, k[2], b], v[f"ranked-{sc}"][size], k[0])
                    for k, v in errors.items()
                    if k[1] == obj
                    and (k[0], obj, k[2], b) in latency
                    and size in v.get(f"ranked-{sc}", {})
                )
                teach = [p for p in pts if p[2] == "fast"]
                ax.plot([p[0] for p in teach], [p[1] for p in teach], marker=marks[obj],
                        color=f"C{ci}", ls="-" if obj == "flow" else "--",
                        label=f"{obj}, ranked by {sc}")  # fmt: skip
                for p in pts:
                    if p[2] == "student":
                        ax.plot(p[0], p[1], marker="*", ms=12, color=f"C{ci}", ls="none")
        ax.axvline(20.0, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xlabel("decision p50 (ms, K = 8, 2 threads)")
        ax.set_ylabel("executed |M_L - g|, median (g)")
        ax.set_title(f"{size} cm (star: 1-step flow student; dotted: 20 ms tick)", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--control", type=Path, required=True, help="rmi control-bench output")
    p.add_argument("--latency", type=Path, required=True, help="bench_planning --json output")
    p.add_argument("--figure", type=Path, default=None, help="PNG to write")
    args = p.parse_args()
    errors = load_errors(args.control)
    latency = load_latency(args.latency)
    sizes = sorted({z for v in errors.values() for c in v.values() for z in c})
    print(table(errors, latency, sizes))
    if args.figure is not None:
        figure(errors, latency, sizes, args.figure)


if __name__ == "__main__":
    main()
