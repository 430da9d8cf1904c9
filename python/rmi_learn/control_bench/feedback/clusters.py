"""Summaries with intervals that respect how the states cluster: a start state's errors are
paired across controllers, and the states of one run share its trajectory, so every
interval comes from a bootstrap that resamples runs (all of a run's states together), with
the protocol's seed and number of resamples."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: Two executed errors closer than this (g) tie.
TIE_G = 0.01


def _by_run(runs: Sequence[str]) -> list[np.ndarray]:
    labels = sorted(set(runs))
    arr = np.asarray(runs)
    return [np.flatnonzero(arr == lab) for lab in labels]


def cluster_bootstrap(
    values: np.ndarray, runs: Sequence[str], stat: Any, rng: np.random.Generator, resamples: int
) -> tuple[float | None, float | None]:
    """Percentile 95 % interval of ``stat(values[idx])`` over resamples of whole runs;
    ``values`` is (n,) or (n, k) with one row per state."""
    clusters = _by_run(runs)
    if not clusters:
        return None, None
    out = []
    for _ in range(resamples):
        pick = rng.integers(0, len(clusters), size=len(clusters))
        idx = np.concatenate([clusters[i] for i in pick])
        out.append(stat(values[idx]))
    v = np.asarray(out, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None, None
    return float(np.quantile(v, 0.025)), float(np.quantile(v, 0.975))


def _ratio(pair: np.ndarray) -> float:
    den = float(np.mean(pair[:, 1]))
    return float(np.mean(pair[:, 0]) / den) if den > 0 else float("nan")


def summarise_cell(
    rows: Sequence[Mapping[str, Any]],
    controllers: Sequence[str],
    reference: Mapping[str, str],
    modes: Mapping[str, str],
    resamples: int,
    seed: int,
) -> list[dict[str, Any]]:
    """One line per controller of one (size, task) cell: states, runs, failures, the
    median and mean error (g) with cluster-bootstrap intervals, and against the reference
    PI of its observation mode (privileged for the oracle and the open-loop ones' own
    mode) the ratio of mean errors with its interval and the paired wins, ties, losses."""
    by: dict[str, dict[tuple[str, int], Mapping[str, Any]]] = {}
    for r in rows:
        by.setdefault(r["controller"], {})[(r["run_id"], int(r["tick"]))] = r
    out: list[dict[str, Any]] = []
    for ctrl in controllers:
        mine = by.get(ctrl, {})
        ok = {k: r for k, r in mine.items() if r["abs_error_g"] is not None}
        keys = sorted(ok)
        err = np.array([ok[k]["abs_error_g"] for k in keys])
        runs = [k[0] for k in keys]
        rng = np.random.default_rng([seed, len(out)])
        line: dict[str, Any] = {
            "controller": ctrl,
            "mode": modes[ctrl],
            "states": len(keys),
            "runs": len(set(runs)),
            "failed": len(mine) - len(ok),
        }
        if keys:
            line["median_g"] = float(np.median(err))
            line["median_ci"] = list(cluster_bootstrap(err, runs, np.median, rng, resamples))
            line["mean_g"] = float(np.mean(err))
            line["mean_ci"] = list(cluster_bootstrap(err, runs, np.mean, rng, resamples))
        ref = reference.get(modes[ctrl]) or reference.get("sensors")
        line["reference"] = ref
        ref_rows = by.get(ref or "", {})
        common = [k for k in keys if k in ref_rows and ref_rows[k]["abs_error_g"] is not None]
        if ref and ref != ctrl and common:
            pair = np.array([[ok[k]["abs_error_g"], ref_rows[k]["abs_error_g"]] for k in common])
            prun = [k[0] for k in common]
            line["ratio_to_reference"] = _ratio(pair)
            line["ratio_ci"] = list(cluster_bootstrap(pair, prun, _ratio, rng, resamples))
            d = pair[:, 0] - pair[:, 1]
            line["wins_ties_losses"] = [
                int(np.sum(d < -TIE_G)),
                int(np.sum(np.abs(d) <= TIE_G)),
                int(np.sum(d > TIE_G)),
            ]
        out.append(line)
    return out


__all__ = ["TIE_G", "cluster_bootstrap", "summarise_cell"]
