"""The figures of the physical analysis (paper Figs. 4-6 and the squeeze association), drawn
on matplotlib's object interface (no pyplot state) and written as PNG atomically."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from rmi_learn.analysis.run_table import ANALYSIS_PHASES
from rmi_learn.analysis.statistics import G_PER_KG, GROUP_KEYS, groups_by
from rmi_learn.data.runs import atomic_write_bytes

#: Trailing-average window of the retained water in Fig. 4 (s), as in the paper's caption.
TRAILING_WINDOW_S = 2.0
_DPI = 130

_PHASE_COLOURS: dict[str, str] = {
    "settle": "#f2f2f2",
    "close": "#dbe9f6",
    "ramp": "#fde0c5",
    "hold": "#fbe3e8",
    "lift": "#d9f0d3",
    "waiting": "#ece2f0",
    "squeeze": "#fff3b0",
    "done": "#e0e0e0",
}
_SIZE_COLOURS: dict[int, str] = {8: "#1b9e77", 10: "#d95f02", 12: "#7570b3"}


def save_png(fig: Figure, path: Path) -> Path:
    """Render ``fig`` to PNG in memory and write it atomically (no half-written file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI)
    data = buf.getvalue()
    return atomic_write_bytes(path, lambda f: f.write(data))


def _message(fig: Figure, text: str) -> None:
    fig.text(0.5, 0.5, text, ha="center", va="center", wrap=True)


def no_run_figure(text: str) -> Figure:
    """The Fig. 4 canvas with ``text`` in place of a run."""
    fig = Figure(figsize=(9.0, 4.8), layout="constrained")
    _message(fig, text)
    return fig


def _trailing_mean(t: np.ndarray, y: np.ndarray, window: float) -> np.ndarray:
    """Mean of ``y`` over the samples in (t - window, t] at each time ``t`` (s)."""
    cs = np.concatenate([[0.0], np.cumsum(y)])
    start = np.searchsorted(t, t - window, side="right")
    stop = np.arange(1, t.size + 1)
    return np.asarray((cs[stop] - cs[start]) / (stop - start))


def _phase_segments(t: np.ndarray, phase: Sequence[str]) -> list[tuple[str, float, float]]:
    segs: list[tuple[str, float, float]] = []
    start = 0
    for i in range(1, len(phase) + 1):
        if i == len(phase) or phase[i] != phase[start]:
            end = float(t[i]) if i < len(phase) else float(t[-1])
            segs.append((phase[start], float(t[start]), end))
            start = i
    return segs


def plot_single_run(df: pl.DataFrame, title: str) -> Figure:
    """Fig. 4 analogue of one run's rows (see :func:`rmi_learn.data.runs.read_run`): F_target,
    F_meas and lightly F_L/F_R (N) on the left axis, retained water M_L and its trailing
    average (g) on the right, phases shaded and named."""
    fig = Figure(figsize=(9.0, 4.8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    t = df["time"].to_numpy()
    phase = [str(p) for p in df["phase"].to_list()]
    for name, t0, t1 in _phase_segments(t, phase):
        ax.axvspan(t0, t1, color=_PHASE_COLOURS.get(name, "#eeeeee"), lw=0, zorder=0)
        ax.text(
            0.5 * (t0 + t1),
            1.01,
            name,
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=7,
            rotation=45 if t1 - t0 < 0.08 * (t[-1] - t[0]) else 0,
        )
    ax.plot(t, df["F_L"].to_numpy(), color="tab:blue", lw=0.6, alpha=0.35, label="F_L")
    ax.plot(t, df["F_R"].to_numpy(), color="tab:cyan", lw=0.6, alpha=0.35, label="F_R")
    ax.plot(t, df["F_target"].to_numpy(), color="black", ls="--", lw=1.2, label="F_target")
    ax.plot(t, df["F_meas"].to_numpy(), color="tab:blue", lw=1.4, label="F_meas")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("gripper force (N)")
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax2 = ax.twinx()
    m = df["M_L"].to_numpy() * G_PER_KG
    ax2.plot(t, m, color="darkred", lw=1.5, label="M_L")
    ax2.plot(
        t,
        _trailing_mean(t, m, TRAILING_WINDOW_S),
        color="tab:red",
        lw=1.0,
        ls="--",
        alpha=0.7,
        label=f"M_L, {TRAILING_WINDOW_S:g} s trailing mean (as in the paper)",
    )
    ax2.set_ylabel("retained water M_L (g)")
    lines = ax.get_lines() + ax2.get_lines()
    fig.legend(
        lines, [str(x.get_label()) for x in lines], loc="outside lower center", ncol=3, fontsize=7
    )
    fig.suptitle(title, fontsize=9)
    return fig


def plot_water_per_phase(
    values_g: Mapping[str, np.ndarray], sizes: Mapping[str, np.ndarray], title: str
) -> Figure:
    """Fig. 5 analogue: one box per phase of the water removed (g), every run drawn as a
    point coloured by sponge size; the zero line shows where water was taken back up."""
    fig = Figure(figsize=(8.0, 4.6), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    phases = list(ANALYSIS_PHASES)
    present = [i for i, ph in enumerate(phases) if values_g[ph].size]
    if present:
        ax.boxplot(
            [values_g[phases[i]] for i in present],
            positions=[i + 1 for i in present],
            widths=0.55,
            showfliers=False,
            medianprops={"color": "black"},
        )
    rng = np.random.default_rng(0)
    seen: set[int] = set()
    for i, ph in enumerate(phases):
        v = values_g[ph]
        s = sizes[ph]
        for size in sorted({int(x) for x in s}):
            pick = s == size
            ax.scatter(
                i + 1 + rng.uniform(-0.18, 0.18, int(pick.sum())),
                v[pick],
                s=9,
                alpha=0.6,
                color=_SIZE_COLOURS.get(size, "grey"),
                label=f"{size} cm" if size not in seen else None,
                zorder=3,
            )
            seen.add(size)
        ax.text(
            i + 1,
            1.0,
            f"n={v.size}",
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=7,
        )
    ax.axhline(0.0, color="grey", lw=0.8, ls=":")
    ax.set_xticks(range(1, len(phases) + 1), phases)
    ax.set_xlim(0.4, len(phases) + 0.6)
    ax.set_ylabel("water removed in phase (g)")
    if seen:
        ax.legend(fontsize=7, title="sponge", title_fontsize=7)
    fig.suptitle(title, fontsize=9)
    return fig


def plot_lift_success(table: Mapping[str, Any], title: str) -> Figure:
    """Fig. 6 analogue: lift success rate per porosity (rows) x holding force (columns),
    one panel per sponge size; hatched cells had no run."""
    sizes: list[int] = list(table["sizes_cm"])
    pors: list[float] = list(table["porosities"])
    holds: list[float] = list(table["F_hold_values"])
    fig = Figure(figsize=(4.2 * max(1, len(sizes)) + 0.8, 3.8), layout="constrained")
    if not sizes:
        _message(fig, "no run with a lift outcome")
        return fig
    axes = [fig.add_subplot(1, len(sizes), i + 1) for i in range(len(sizes))]
    image = None
    for ax, size in zip(axes, sizes, strict=True):
        rate = np.full((len(pors), len(holds)), np.nan)
        label = [["" for _ in holds] for _ in pors]
        for c in table["cells"]:
            if c["size_cm"] != size:
                continue
            i, j = pors.index(c["porosity"]), holds.index(c["F_hold"])
            rate[i, j] = c["rate"]
            label[i][j] = f"{c['rate']:.0%}\n{c['n_success']}/{c['n']}"
        image = ax.imshow(
            np.ma.masked_invalid(rate),
            origin="lower",
            aspect="auto",
            cmap="RdYlGn",
            vmin=0.0,
            vmax=1.0,
            extent=(-0.5, len(holds) - 0.5, -0.5, len(pors) - 0.5),
        )
        for i in range(len(pors)):
            for j in range(len(holds)):
                if np.isnan(rate[i, j]):
                    ax.add_patch(_missing_cell(j, i))
                    ax.text(j, i, "no runs", ha="center", va="center", fontsize=6)
                else:
                    ax.text(
                        j,
                        i,
                        label[i][j],
                        ha="center",
                        va="center",
                        fontsize=7,
                        bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1.5},
                    )
        ax.set_xticks(range(len(holds)), [f"{h:g}" for h in holds])
        ax.set_yticks(range(len(pors)), [f"{p:g}" for p in pors])
        ax.set_xlabel("holding force F_hold (N)")
        ax.set_ylabel("porosity")
        ax.set_title(f"{size} cm sponge", fontsize=9)
    if image is not None:
        fig.colorbar(image, ax=axes, label="lift success rate", shrink=0.85)
    fig.suptitle(title, fontsize=9)
    return fig


def _missing_cell(x: int, y: int) -> Any:
    return Rectangle(
        (x - 0.5, y - 0.5), 1.0, 1.0, facecolor="#dddddd", hatch="//", edgecolor="grey", lw=0.0
    )


def plot_association(sel: pl.DataFrame, assoc: Mapping[str, Any], title: str) -> Figure:
    """Squeeze association figure: left, squeeze-phase removal (g) against squeeze force (N),
    one line per matched group coloured by size; right, both demeaned within group, with
    the fitted slope and its bootstrap interval."""
    fig = Figure(figsize=(10.0, 4.4), layout="constrained")
    ax1 = fig.add_subplot(1, 2, 1)
    ax2 = fig.add_subplot(1, 2, 2)
    labelled: set[int] = set()
    for key, g in groups_by(sel, GROUP_KEYS):
        size = int(key[0])
        g = g.sort("F_squeeze")
        x = g["F_squeeze"].to_numpy().astype(float)
        y = g["water_removed_squeeze"].to_numpy().astype(float) * G_PER_KG
        col = _SIZE_COLOURS.get(size, "grey")
        lab = f"{size} cm" if size not in labelled else None
        labelled.add(size)
        ax1.plot(x, y, marker="o", ms=3, lw=0.8, alpha=0.7, color=col, label=lab)
        if g["F_squeeze"].n_unique() >= 2:
            ax2.scatter(x - x.mean(), y - y.mean(), s=10, alpha=0.7, color=col)
    ax1.set_xlabel("squeeze force F_squeeze (N)")
    ax1.set_ylabel("water removed in squeeze phase (g)")
    ax1.set_title("matched groups (size, porosity, F_hold, seed)", fontsize=8)
    if labelled:
        ax1.legend(fontsize=7)
    ax2.axhline(0.0, color="grey", lw=0.6, ls=":")
    ax2.set_xlabel("squeeze force minus group mean (N)")
    ax2.set_ylabel("removal minus group mean (g)")
    if assoc.get("status") == "ok":
        xs = np.asarray(ax2.get_xlim())
        b = float(assoc["slope_g_per_N"])
        lo, hi = (v / 100.0 for v in assoc["ci95_g_per_100N"])
        ax2.plot(xs, b * xs, color="black", lw=1.4, label=f"{100 * b:.2f} g / 100 N")
        ax2.fill_between(xs, lo * xs, hi * xs, color="black", alpha=0.12, label="95% CI")
        ax2.set_xlim(*xs)
        ax2.legend(fontsize=7)
        ax2.set_title(
            f"within-group slope, {assoc['n_groups']} groups, cluster bootstrap CI", fontsize=8
        )
    else:
        ax2.text(
            0.5,
            0.5,
            f"no estimate: {assoc.get('reason')}",
            transform=ax2.transAxes,
            ha="center",
            va="center",
            fontsize=8,
            wrap=True,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )
    fig.suptitle(title, fontsize=9)
    return fig
