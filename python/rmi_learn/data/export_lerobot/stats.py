"""Statistics of exported features, as LeRobot's ``stats.json`` and per-episode statistics
hold them: population mean and standard deviation, minimum, maximum, frame count and, for
the v3.0 layout, the 1, 10, 50, 90 and 99 % quantiles."""

from __future__ import annotations

import numpy as np
import polars as pl

#: Quantiles of the v3.0 layout: (key, fraction).
QUANTILES: tuple[tuple[str, float], ...] = (
    ("q01", 0.01),
    ("q10", 0.10),
    ("q50", 0.50),
    ("q90", 0.90),
    ("q99", 0.99),
)


def feature_stats(values: np.ndarray, quantiles: bool = False) -> dict[str, list[float]]:
    """Population statistics of one feature over its frames: ``values`` is (frames,) or
    (frames, channels); returns ``mean``, ``std``, ``min``, ``max`` (one entry per channel,
    in the feature's unit), ``count`` ([frames]) and with ``quantiles`` the entries of
    :data:`QUANTILES` (linear interpolation between frames)."""
    x = values.astype(np.float64)
    if x.ndim == 1:
        x = x[:, None]
    out: dict[str, list[float]] = {
        "mean": x.mean(axis=0).tolist(),
        "std": x.std(axis=0).tolist(),
        "min": x.min(axis=0).tolist(),
        "max": x.max(axis=0).tolist(),
        "count": [int(x.shape[0])],
    }
    if quantiles:
        for key, q in QUANTILES:
            out[key] = np.quantile(x, q, axis=0).tolist()
    return out


def table_stats(table: pl.DataFrame, quantiles: bool = False) -> dict[str, dict[str, list[float]]]:
    """:func:`feature_stats` of every column of an episode table (or of several stacked)."""
    return {
        name: feature_stats(np.asarray(table[name].to_numpy()), quantiles) for name in table.columns
    }
