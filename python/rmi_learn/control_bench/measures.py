"""Summary measures of the goal-reaching benchmark: robust statistics with seeded bootstrap
intervals, paired comparisons with the policy's first sample, and the scorer diagnostics;
the Markdown table and the figure."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Two executed errors closer than this (g) count as a tie.
TIE_G = 0.1
#: Bootstrap resamples of every interval.
BOOTSTRAP = 1000


def rankdata(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of ``x`` with ties given their average rank."""
    x = np.asarray(x, dtype=np.float64)
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size, dtype=np.float64)
    xs = x[order]
    i = 0
    while i < x.size:
        j = i
        while j + 1 < x.size and xs[j + 1] == xs[i]:
            j += 1
        ranks[order[i : j + 1]] = 0.5 * (i + j) + 1.0
        i = j + 1
    return ranks


def spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman rank correlation of two samples (None when either is constant or n < 2)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.size < 2 or np.all(a == a[0]) or np.all(b == b[0]):
        return None
    ra, rb = rankdata(a), rankdata(b)
    return float(np.corrcoef(ra, rb)[0, 1])


def bootstrap_ci(
    x: Sequence[float] | np.ndarray, stat: str, rng: np.random.Generator, n: int = BOOTSTRAP
) -> tuple[float | None, float | None]:
    """Percentile 95 % interval of the ``stat`` (``median`` or ``mean``) of ``x``."""
    v = np.asarray(x, dtype=np.float64)
    if v.size == 0:
        return None, None
    idx = rng.integers(0, v.size, size=(n, v.size))
    f = np.median if stat == "median" else np.mean
    s = f(v[idx], axis=1)
    return float(np.quantile(s, 0.025)), float(np.quantile(s, 0.975))


def _centre(x: Sequence[float], rng: np.random.Generator) -> dict[str, Any]:
    v = np.asarray(x, dtype=np.float64)
    if v.size == 0:
        return {
            "n": 0,
            "median": None,
            "median_ci": [None, None],
            "mean": None,
            "mean_ci": [None, None],
        }
    return {
        "n": int(v.size),
        "median": float(np.median(v)),
        "median_ci": list(bootstrap_ci(v, "median", rng)),
        "mean": float(np.mean(v)),
        "mean_ci": list(bootstrap_ci(v, "mean", rng)),
    }


def _key(r: Mapping[str, Any]) -> tuple[Any, ...]:
    return (r["run_id"], r["t"], r["goal_index"])


def reference_objective(controller_objective: str | None, objectives: Sequence[str]) -> str | None:
    """The objective whose first sample and best-of-K a controller is compared with: its own,
    or the first objective for the controllers that use no policy."""
    return controller_objective or (objectives[0] if objectives else None)


def summarise(
    rows: Sequence[Mapping[str, Any]], objectives: Sequence[str], seed: int = 0
) -> dict[str, Any]:
    """Per goal kind (``drawn``, ``logged``, ``given``), size and controller: executed error
    (g) median and mean with 95 % bootstrap intervals; the paired ratio to the first sample
    (median, bootstrap interval; denominators below the tie tolerance are raised to it),
    wins/ties/losses against it; regret against best-of-K; peak force; failures by reason;
    and, per ranking scorer, the diagnostics (Spearman correlation of predicted and executed
    error over the K samples, how often the recorded chunk ranks first among K + 1 on the
    logged goal, its predicted error against persistence's)."""
    rng = np.random.default_rng([seed, 0xC0])
    ok = [r for r in rows if r.get("controller") and r["status"] == "ok"]
    by = {(r["goal_kind"], _key(r), r["controller"]): r for r in ok}
    out: dict[str, Any] = {}
    for kind in ("drawn", "logged", "given"):
        kind_rows = [r for r in ok if r["goal_kind"] == kind]
        if not kind_rows:
            continue
        sizes: dict[str, Any] = {}
        for size in sorted({int(r["size_cm"]) for r in kind_rows}):
            srows = [r for r in kind_rows if int(r["size_cm"]) == size]
            ctrls: dict[str, Any] = {}
            for ctrl in _ordered({r["controller"] for r in srows}):
                cr = [r for r in srows if r["controller"] == ctrl]
                ref_obj = reference_objective(cr[0]["objective"], objectives)
                err = [float(r["err_g"]) for r in cr]
                e: dict[str, Any] = {
                    "objective": cr[0]["objective"],
                    "scorer": cr[0]["scorer"],
                    **_centre(err, rng),
                    "peak_force_N_mean": float(np.mean([r["peak_force_N"] for r in cr])),
                    "failures": _count([r["failure"] for r in cr if r["failure"]]),
                }
                pairs, regrets = [], []
                for r in cr:
                    f = by.get((kind, _key(r), f"first-sample/{ref_obj}"))
                    b = by.get((kind, _key(r), f"best-of-k/{ref_obj}"))
                    if f is not None:
                        pairs.append((float(r["err_g"]), float(f["err_g"])))
                    if b is not None:
                        regrets.append(float(r["err_g"]) - float(b["err_g"]))
                if pairs and ref_obj is not None:
                    a = np.asarray(pairs)
                    ratio = a[:, 0] / np.maximum(a[:, 1], TIE_G)
                    d = a[:, 0] - a[:, 1]
                    e["vs_first"] = {
                        "reference": f"first-sample/{ref_obj}",
                        "n": int(a.shape[0]),
                        "ratio_median": float(np.median(ratio)),
                        "ratio_median_ci": list(bootstrap_ci(ratio, "median", rng)),
                        "wins": int(np.sum(d < -TIE_G)),
                        "ties": int(np.sum(np.abs(d) <= TIE_G)),
                        "losses": int(np.sum(d > TIE_G)),
                    }
                if regrets:
                    e["regret_vs_best_of_k"] = {
                        "reference": f"best-of-k/{ref_obj}",
                        **_centre(regrets, rng),
                    }
                if cr[0]["scorer"] and str(ctrl).startswith("ranked-"):
                    rho = [r["spearman"] for r in cr if r["spearman"] is not None]
                    e["spearman_mean"] = float(np.mean(rho)) if rho else None
                    e["spearman_n"] = len(rho)
                    if kind == "logged":
                        first = [r["recorded_rank"] == 1 for r in cr if r["recorded_rank"]]
                        pr = [r["pred_err_recorded_g"] for r in cr]
                        pp = [r["persistence_err_g"] for r in cr]
                        e["recorded_ranked_first"] = float(np.mean(first)) if first else None
                        e["recorded_pred_err_g_mean"] = float(np.mean(pr))
                        e["persistence_err_g_mean"] = float(np.mean(pp))
                        e["recorded_beats_persistence"] = float(
                            np.mean([a < b for a, b in zip(pr, pp, strict=True)])
                        )
                ctrls[ctrl] = e
            sizes[str(size)] = {
                "states": len({(r["run_id"], r["t"]) for r in srows}),
                "goals": len({_key(r) for r in srows}),
                "controllers": ctrls,
            }
        out[kind] = sizes
    return out


def scorer_diagnostics(
    samples: Sequence[Mapping[str, Any]], scorers: Sequence[str]
) -> dict[str, Any]:
    """Per size and scorer, how well the forecasts of executed chunks order and size their
    outcomes, from ``control_samples.parquet`` rows (goal-independent: predicted against
    executed terminal M_L).

    - ``sweep_spearman``: mean over states of the Spearman correlation between predicted and
      executed M_L over the constant-setpoint sweep (does the scorer know that a firmer grip
      keeps less water?);
    - ``samples_spearman``: the same over the K samples of each policy and goal;
    - ``level_mae_g``: mean |predicted - executed| M_L over every executed chunk, beside
      ``persistence_mae_g`` (predicting no change);
    - ``relative_mae_g``: mean over groups (one state's sweep; one policy's K samples for one
      goal) of |(pred_i - mean pred) - (exec_i - mean exec)|, the error in the differences
      between chunks that ranking depends on, beside ``executed_spread_g``, the mean absolute
      deviation of the executed outcomes in the same groups (what a scorer predicting no
      difference would score).
    """
    ok = [r for r in samples if r["status"] == "ok" and r["M_L_end_kg"] is not None]
    out: dict[str, Any] = {}
    for size in sorted({int(r["size_cm"]) for r in ok}):
        srows = [r for r in ok if int(r["size_cm"]) == size]
        groups: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
        for r in srows:
            if r["objective"] == "recorded":
                continue
            key = (r["run_id"], r["t"], r["objective"], r["goal_kind"], r["goal_index"])
            groups.setdefault(key, []).append(r)
        per: dict[str, Any] = {}
        ex = np.asarray([r["M_L_end_kg"] for r in srows])
        now = np.asarray([r["water_now_kg"] for r in srows])
        persistence_g = float(1000.0 * np.mean(np.abs(now - ex)))
        executed = {key: np.asarray([r["M_L_end_kg"] for r in g]) for key, g in groups.items()}
        for i, name in enumerate(scorers):
            pred = np.asarray([r["pred_M_L_kg"][i] for r in srows])
            rho: dict[str, list[float]] = {"constant": [], "policy": []}
            rel, spread = [], []
            for key, g in groups.items():
                p = np.asarray([r["pred_M_L_kg"][i] for r in g])
                e = executed[key]
                c = spearman(p, e)
                if c is not None:
                    rho["constant" if key[2] == "constant" else "policy"].append(c)
                rel.append(np.mean(np.abs((p - p.mean()) - (e - e.mean()))))
                spread.append(np.mean(np.abs(e - e.mean())))
            per[name] = {
                "sweep_spearman": float(np.mean(rho["constant"])) if rho["constant"] else None,
                "samples_spearman": float(np.mean(rho["policy"])) if rho["policy"] else None,
                "level_mae_g": float(1000.0 * np.mean(np.abs(pred - ex))),
                "persistence_mae_g": persistence_g,
                "relative_mae_g": float(1000.0 * np.mean(rel)) if rel else None,
                "executed_spread_g": float(1000.0 * np.mean(spread)) if spread else None,
                "chunks": int(len(srows)),
            }
        out[str(size)] = per
    return out


def diagnostics_markdown(diag: Mapping[str, Any]) -> list[str]:
    """The scorer diagnostics of :func:`scorer_diagnostics` as Markdown lines."""
    if not diag:
        return []
    lines = [
        "*Scorers against executed outcomes (every executed chunk; terminal M_L)*",
        "",
        "| Size | Scorer | Spearman, setpoint sweep | Spearman, policy samples | level MAE (g) "
        "| persistence MAE (g) | relative MAE (g) | executed spread (g) |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for size, per in diag.items():
        for name, d in per.items():
            lines.append(
                f"| {size} cm | {name} | {_f(d['sweep_spearman'])} | "
                f"{_f(d['samples_spearman'])} | {_f(d['level_mae_g'])} | "
                f"{_f(d['persistence_mae_g'])} | {_f(d['relative_mae_g'])} | "
                f"{_f(d['executed_spread_g'])} |"
            )
    return lines + [""]


def _count(xs: Sequence[str]) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in xs:
        out[x] = out.get(x, 0) + 1
    return out


_ORDER = (
    "recorded",
    "constant-best",
    "first-sample",
    "ranked-",
    "refined-",
    "best-of-k",
    "model-",
    "receding-",
)


def _ordered(names: set[str]) -> list[str]:
    def key(n: str) -> tuple[int, str]:
        for i, p in enumerate(_ORDER):
            if n.startswith(p):
                return i, n
        return len(_ORDER), n

    return sorted(names, key=key)


def _f(v: float | None, d: int = 2) -> str:
    return "n/a" if v is None else f"{v:.{d}f}"


def _ci(c: Sequence[float | None], d: int = 2) -> str:
    return f"[{_f(c[0], d)}, {_f(c[1], d)}]"


def markdown(
    summary: Mapping[str, Any],
    info: Mapping[str, Any],
    scorers: Mapping[str, Any] | None = None,
) -> str:
    """``table_control.md``: per goal kind and size, one row per controller; then the scorer
    diagnostics ``scorers`` (:func:`scorer_diagnostics`) when given."""
    titles = {
        "drawn": "Goals drawn inside the reachable interval",
        "logged": "Logged goal (M_L at t + H, reached by the recorded chunk)",
        "given": "Goals given with --goal-kg",
    }
    lines = [
        f"**Goal-reaching benchmark: executed terminal |M_L - g| (g), force setpoints held "
        f"{info['control_dt_s'] * 1000:.0f} ms, H = {info['horizon']}, K = {info['k']}**",
        "",
    ]
    for kind, sizes in summary.items():
        lines += [f"*{titles[kind]}*", ""]
        for size, s in sizes.items():
            lines += [
                f"{size} cm: {s['states']} start states, {s['goals']} (state, goal) pairs",
                "",
                "| Controller | n | median [95 % CI] | mean [95 % CI] | ratio to first "
                "(median [CI]) | win/tie/loss vs first | regret vs best-of-K (median) | "
                "peak F (N) | failures | Spearman (pred vs exec) |",
                "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|",
            ]
            for ctrl, e in s["controllers"].items():
                vf = e.get("vs_first")
                rg = e.get("regret_vs_best_of_k")
                fails = ", ".join(f"{k} {v}" for k, v in e["failures"].items()) or "-"
                lines.append(
                    f"| {ctrl} | {e['n']} | {_f(e['median'])} {_ci(e['median_ci'])} | "
                    f"{_f(e['mean'])} {_ci(e['mean_ci'])} | "
                    + (f"{_f(vf['ratio_median'])} {_ci(vf['ratio_median_ci'])}" if vf else "-")
                    + " | "
                    + (f"{vf['wins']}/{vf['ties']}/{vf['losses']}" if vf else "-")
                    + f" | {_f(rg['median']) if rg else '-'} | {_f(e['peak_force_N_mean'], 1)} | "
                    f"{fails} | {_f(e.get('spearman_mean')) if 'spearman_mean' in e else '-'} |"
                )
            if kind == "logged":
                diag = [(c, e) for c, e in s["controllers"].items() if "recorded_ranked_first" in e]
                if diag:
                    lines += [
                        "",
                        "| Scorer (logged goal) | recorded chunk ranked first of K + 1 | "
                        "predicted error of the recorded chunk (g) | persistence error (g) | "
                        "recorded beats persistence |",
                        "|---|---:|---:|---:|---:|",
                    ]
                    for c, e in diag:
                        lines.append(
                            f"| {c} | {_f(e['recorded_ranked_first'])} | "
                            f"{_f(e['recorded_pred_err_g_mean'])} | "
                            f"{_f(e['persistence_err_g_mean'])} | "
                            f"{_f(e['recorded_beats_persistence'])} |"
                        )
            lines.append("")
    lines += diagnostics_markdown(scorers or {})
    lines += [
        f"Start states: {info['split_used']} split"
        + (" (the test split is empty)" if info["split_used"] != info["split"] else "")
        + f", anchors in {', '.join(info['phases'])}; setpoints "
        f"{', '.join(f'{x:g}' for x in info['setpoint_fractions'])} of the span from "
        f"{info['setpoint_low_fraction']:g} x F_hold to {info['force_limit_N']:g} N. "
        f"Ratios and wins compare with the first sample of the same policy (the first policy "
        f"for controllers without one); ties within {TIE_G} g. Bootstrap: {BOOTSTRAP} "
        f"resamples, seed {info['seed']}.",
    ]
    return "\n".join(lines) + "\n"


def figure(rows: Sequence[Mapping[str, Any]], path: Path) -> None:
    """Executed error per controller (drawn goals; logged goals when there are none), one
    panel per sponge size, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r.get("controller") and r["status"] == "ok"]
    kind = "drawn" if any(r["goal_kind"] == "drawn" for r in ok) else "logged"
    ok = [r for r in ok if r["goal_kind"] == kind]
    sizes = sorted({int(r["size_cm"]) for r in ok}) or [0]
    ctrls = _ordered({r["controller"] for r in ok})
    fig, axes = plt.subplots(
        1, len(sizes), figsize=(max(6.0, 0.55 * len(ctrls) * len(sizes) + 2), 4.2), squeeze=False
    )
    for ax, size in zip(axes[0], sizes, strict=True):
        data = [
            [float(r["err_g"]) for r in ok if int(r["size_cm"]) == size and r["controller"] == c]
            for c in ctrls
        ]
        pos = np.arange(len(ctrls))
        for i, d in enumerate(data):
            if d:
                ax.scatter(np.full(len(d), i), d, s=10, alpha=0.6, color="C0")
                ax.hlines(np.median(d), i - 0.3, i + 0.3, color="C3")
        ax.set_xticks(pos, ctrls, rotation=60, ha="right", fontsize=7)
        ax.set_title(f"{size} cm ({kind} goals)")
        ax.set_ylabel("executed |M_L - g| (g)")
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def figure_scorers(
    samples: Sequence[Mapping[str, Any]], scorers: Sequence[str], path: Path
) -> None:
    """Predicted against executed change of the retained water over the chunk (g), one panel
    per scorer and sponge size, every executed chunk of ``control_samples.parquet`` (setpoint
    sweep, recorded chunk, policy samples), with the identity line; as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in samples if r["status"] == "ok" and r["M_L_end_kg"] is not None]
    sizes = sorted({int(r["size_cm"]) for r in ok}) or [0]
    names = list(scorers) or ["-"]
    fig, axes = plt.subplots(
        len(names), len(sizes), figsize=(3.2 * len(sizes), 3.0 * len(names)), squeeze=False
    )
    for i, name in enumerate(names):
        for j, size in enumerate(sizes):
            ax = axes[i][j]
            rows = [r for r in ok if int(r["size_cm"]) == size]
            if rows and name in scorers:
                now = np.asarray([r["water_now_kg"] for r in rows])
                ex = 1000.0 * (np.asarray([r["M_L_end_kg"] for r in rows]) - now)
                k = list(scorers).index(name)
                pr = 1000.0 * (np.asarray([r["pred_M_L_kg"][k] for r in rows]) - now)
                ax.scatter(ex, pr, s=6, alpha=0.5)
                lo, hi = float(min(ex.min(), pr.min())), float(max(ex.max(), pr.max()))
                ax.plot([lo, hi], [lo, hi], color="k", lw=0.8)
            ax.set_title(f"{name}, {size} cm", fontsize=9)
            ax.set_xlabel("executed change of M_L (g)", fontsize=8)
            ax.set_ylabel("predicted (g)", fontsize=8)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = [
    "BOOTSTRAP",
    "TIE_G",
    "bootstrap_ci",
    "diagnostics_markdown",
    "figure",
    "figure_scorers",
    "markdown",
    "rankdata",
    "scorer_diagnostics",
    "spearman",
    "summarise",
]
