"""The report's training section: the training and validation loss per epoch of every world
model and policy the pipeline trained."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.ticker import MaxNLocator

from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.figure_files import FIG_SUBDIR, headless_pyplot, save_fig
from rmi_learn.analysis.report.inputs import note_missing
from rmi_learn.metrics_log import loss_curves


def training_runs(out: Path) -> list[tuple[str, Path]]:
    """(label, run directory) of every world model (``out/wm/*``) and policy
    (``out/policy/*``) the pipeline trained, in that order."""
    runs: list[tuple[str, Path]] = []
    for sub, label in (("wm", "world model"), ("policy", "policy")):
        root = out / sub
        if root.is_dir():
            runs += [(f"{label} {d.name}", d) for d in sorted(root.iterdir()) if d.is_dir()]
    return runs


def training_figure(runs: Sequence[tuple[str, Path]], path: Path) -> bool:
    """Draw the training and validation loss per epoch of each run in ``runs`` ((label, run
    directory) pairs; read from their ``metrics.jsonl``) into the PNG ``path``, one panel
    per run, the selected epoch dotted, the loss axis logarithmic where a run's losses span
    more than a factor of 10. Runs without a training loss (the closed-form world
    models) are left out; returns False, drawing nothing, when none is left."""
    curves = [(label, c) for label, d in runs if (c := loss_curves(d))]
    if not curves:
        return False
    plt = headless_pyplot()
    ncols = min(4, len(curves))
    nrows = math.ceil(len(curves) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.3 * ncols, 2.6 * nrows), squeeze=False, constrained_layout=True
    )
    for ax, (label, c) in zip(axes.flat, curves, strict=False):
        ax.plot(c["epoch"], c["train_loss"], marker=".", label="training")
        if "val_loss" in c:
            ax.plot(c["epoch"], c["val_loss"], marker=".", ls="--", label="validation")
        if "best_epoch" in c:
            ax.axvline(c["best_epoch"][0], color="0.5", ls=":", lw=1)
        values = [v for k in ("train_loss", "val_loss") for v in c.get(k, []) if math.isfinite(v)]
        if values and min(values) > 0 and max(values) > 10 * min(values):
            ax.set_yscale("log")  # losses that fall by decades
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("epoch", fontsize=8)
        ax.tick_params(which="both", labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(curves) :]:
        ax.set_visible(False)
    axes[0][0].set_ylabel("loss", fontsize=8)
    axes[0][0].legend(fontsize=7, frameon=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_fig(fig, path)
    plt.close(fig)
    return True


def section_training(doc: Doc, out: Path, figs: Path) -> None:
    """The loss curves of every trained run."""
    doc.h(2, "Training curves")
    if not training_figure(training_runs(out), figs / "fig_training.png"):
        note_missing(doc, "training curves", "world-models")
        return
    doc.img(
        f"{FIG_SUBDIR}/fig_training.png",
        "Training loss (solid) and validation loss (dashed) per epoch of every trained world "
        "model and policy; the dotted line marks the selected epoch",
    )
    doc.p(
        "A world model's validation loss is its training loss (same weights and scale) on "
        "free rollouts of the validation windows; the recurrent models' training loss is "
        "computed with teacher forcing while it decays. A policy's validation loss is its "
        "objective on the validation windows with fixed noise, and its checkpoint is selected "
        "by a metric of the EMA weights. Linear-ARX and the Baseline are not trained by "
        "gradient and have no curve. Every epoch's numbers: "
        "`wm/<name>/metrics.jsonl`, `policy/<objective>/metrics.jsonl`."
    )
