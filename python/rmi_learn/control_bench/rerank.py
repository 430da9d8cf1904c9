"""Rank a finished benchmark's executed samples again with other scorers, without the
simulator.

``rmi control-bench`` executes every one of the K policy samples of each start state, goal
and policy, and keeps each execution in ``control_samples.parquet``. Ranking picks one of
those samples, so the executed error of any scorer's choice is already known: scoring the
same chunks with another world model (or an ensemble with another disagreement weight) and
looking up the executed outcome of its choice measures that scorer's controller exactly, as
executed, at the cost of the model calls alone. This is how a scorer or a weight is chosen on
one split's states before it is reported on another's.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import torch

from rmi_learn.control_bench import measures
from rmi_learn.control_bench.checkpoint import SAMPLES_FILE
from rmi_learn.control_bench.inputs import ControlBenchError
from rmi_learn.data.dataset import load_dataset
from rmi_learn.planning.scorers import score_chunks
from rmi_learn.planning.standardiser import Standardiser


@dataclass(frozen=True)
class RankedGroup:
    """One (state, goal, policy) group re-ranked by one scorer: the chosen sample, its
    executed error and the first sample's and best sample's executed errors (g), and the
    Spearman correlation of predicted and executed error over the samples."""

    size_cm: int
    run_id: str
    t: int
    goal_kind: str
    goal_index: int
    objective: str
    index: int
    err_g: float
    first_err_g: float
    best_err_g: float
    spearman: float | None


#: What re-ranking needs to know of the benchmark that wrote the samples.
INFO_KEYS = ("data", "wm", "history", "horizon", "split_used")


def load_samples(control_dir: Path) -> tuple[pl.DataFrame, dict[str, Any]]:
    """The samples file of an ``rmi control-bench`` output (finished or still running) and
    the benchmark's settings :data:`INFO_KEYS`, from the file's metadata."""
    samples = control_dir / SAMPLES_FILE
    if not samples.exists():
        raise ControlBenchError(f"{control_dir} holds no executed samples ({SAMPLES_FILE})")
    meta = pl.read_parquet_metadata(samples).get("rmi.control.info")
    if meta is None:
        raise ControlBenchError(f"{samples} does not say which benchmark wrote it")
    info = json.loads(meta)
    return pl.read_parquet(samples), {k: info[k] for k in INFO_KEYS}


def rerank(
    control_dir: str | Path,
    scorers: Mapping[str, tuple[Any, Any]],
    *,
    data: str | Path | None = None,
) -> dict[str, list[RankedGroup]]:
    """Re-rank every policy group of ``control_dir`` with each of ``scorers`` (name ->
    (:data:`~rmi_learn.planning.scorers.Scorer`, :class:`~rmi_learn.planning.cost.CostWeights`
    or None)), by the combined cost J as the benchmark ranks. ``data``: the dataset (default
    the one the benchmark used). Returns, per scorer name, one :class:`RankedGroup` per
    (state, goal, policy)."""
    control_dir = Path(control_dir)
    frame, info = load_samples(control_dir)
    ds = load_dataset(data or info["data"])
    std = Standardiser.from_stats(ds.stats)
    hist_len, h, split = int(info["history"]), int(info["horizon"]), str(info["split_used"])
    ok = frame.filter(
        pl.col("objective").is_in(["constant", "recorded"]).not_() & (pl.col("status") == "ok")
    )
    windows: dict[int, Any] = {}
    where: dict[tuple[str, int], tuple[int, int]] = {}
    for size in sorted(set(ok["size_cm"].to_list())):
        ws = ds.windows(split, int(size), history=hist_len, horizon=h)
        windows[int(size)] = ws
        for i, a in enumerate(ws.anchors.tolist()):
            where[(ds.run_ids[int(ds.row_run[a])], int(ds.row_t[a]))] = (int(size), i)
    out: dict[str, list[RankedGroup]] = {name: [] for name in scorers}
    batches: dict[tuple[str, int], dict[str, Any]] = {}  # one window per state, many groups
    keys = ["size_cm", "run_id", "t", "goal_kind", "goal_index", "objective"]
    for key, g in ok.sort([*keys, "sample_index"]).group_by(keys, maintain_order=True):
        _size, run_id, t, kind, gi, obj = key
        state = (str(run_id), int(t))  # type: ignore[call-overload]
        if state not in where:
            raise ControlBenchError(
                f"state (run {run_id}, t={t}) is not a window of the {split} split of the dataset"
            )
        if int(g["sample_index"][0]) != 0:
            raise ControlBenchError(f"group {key} lacks its first sample")
        s, wi = where[state]
        if state not in batches:
            batches[state] = windows[s].batch([wi])
        b = batches[state]
        u = torch.as_tensor(np.stack(g["forces_N"].to_list()), dtype=torch.float32)
        u = u.view(1, -1, h, 1)
        goal = float(g["goal_kg"][0])
        executed = 1000.0 * np.abs(g["M_L_end_kg"].to_numpy() - goal)
        # The goal passes through the standardisation as in the benchmark (same rounding).
        goal_t = std.water_to_kg((torch.tensor([goal]) - std.z_mean[0]) / std.z_std[0])
        for name, (scorer, weights) in scorers.items():
            costs, _ = score_chunks(scorer, std, b["hist"], b["hist_mask"], u, goal_t, weights)
            j = costs["J"][0].double().numpy()
            idx = int(np.argmin(j))
            out[name].append(
                RankedGroup(
                    int(s),
                    state[0],
                    state[1],
                    str(kind),
                    int(gi),
                    str(obj),
                    idx,
                    float(executed[idx]),
                    float(executed[0]),
                    float(executed.min()),
                    measures.spearman(costs["J_M"][0].double().numpy(), executed),
                )
            )
    return out


def summary(groups: Sequence[RankedGroup], kind: str, seed: int = 0) -> dict[str, Any]:
    """Per size and policy, for goals of ``kind``: executed error (median, mean), median
    paired ratio to the first sample with its bootstrap interval, wins/ties/losses, median
    regret against best-of-K, the mean Spearman correlation, and the medians of the first
    sample and of best-of-K for reference."""
    rng = np.random.default_rng([seed, 0xE7])
    out: dict[str, Any] = {}
    for size in sorted({g.size_cm for g in groups}):
        for obj in sorted({g.objective for g in groups}):
            sel = [
                g
                for g in groups
                if g.size_cm == size and g.objective == obj and g.goal_kind == kind
            ]
            if not sel:
                continue
            err = np.asarray([g.err_g for g in sel])
            first = np.asarray([g.first_err_g for g in sel])
            ratio = err / np.maximum(first, measures.TIE_G)
            d = err - first
            rho = [g.spearman for g in sel if g.spearman is not None]
            out.setdefault(str(size), {})[obj] = {
                "n": len(sel),
                "median": float(np.median(err)),
                "mean": float(np.mean(err)),
                "ratio_median": float(np.median(ratio)),
                "ratio_median_ci": list(measures.bootstrap_ci(ratio, "median", rng)),
                "wins": int(np.sum(d < -measures.TIE_G)),
                "ties": int(np.sum(np.abs(d) <= measures.TIE_G)),
                "losses": int(np.sum(d > measures.TIE_G)),
                "regret_median": float(np.median(err - np.asarray([g.best_err_g for g in sel]))),
                "first_median": float(np.median(first)),
                "best_of_k_median": float(np.median([g.best_err_g for g in sel])),
                "spearman_mean": float(np.mean(rho)) if rho else None,
            }
    return out
