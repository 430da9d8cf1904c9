"""The seed-replicate floor of studies/seed_floor.py."""

from __future__ import annotations

import numpy as np
import pytest
from study_scripts import load_study


def _run(k0: int, m: np.ndarray, phases: list[str]) -> dict[str, np.ndarray]:
    n = len(m)
    r: dict[str, np.ndarray] = {"k": np.arange(k0, k0 + n), "M_L": m}
    for f in ("S", "V_pore", "F_meas", "w"):
        r[f] = np.zeros(n)
    r["keep"] = np.array([p != "settle" for p in phases])
    return r


def test_floors_of_known_replicates() -> None:
    sf = load_study("seed_floor")
    # Four seeds with the same mean outflow and seed offsets -2, -1, +1, +2 (g): the median
    # forecast is off by 2, 1, 1, 2 -> 1.5 g; leaving one seed out, the median of the others
    # is off by 3, 2, 2, 3 -> 2.5 g; the Baseline's error is the outflow, 10 g.
    d = np.array([[8.0], [9.0], [11.0], [12.0]])
    base, f_in, f_loo = sf.floors(d)
    assert (base, f_in, f_loo) == pytest.approx((10.0, 1.5, 2.5))
    # Identical replicates leave nothing to chance.
    assert sf.floors(np.full((4, 3), 5.0))[1:] == (0.0, 0.0)


def test_deltas_use_anchors_common_to_all_seeds() -> None:
    sf = load_study("seed_floor")
    h = 4
    phases = ["settle"] * 20 + ["hold"] * 20
    a = _run(0, np.linspace(1.0, 0.6, 40), phases)
    # The second seed starts one grid step later and drains faster.
    b = _run(1, np.linspace(1.0, 0.2, 40), phases[1:] + ["hold"])
    d, x = sf._deltas({0: a, 1: b}, h)
    lag = max(sf.LAGS)
    # Anchors: kept in both (k >= 20 for a, k - 1 >= 19 for b), enough history in both,
    # target inside both runs (k + 4 <= 39 for a, k - 1 + 4 <= 39 for b).
    ks = [k for k in range(40) if k >= 20 and k - 1 >= lag and k + h <= 39]
    assert d.shape == (2, len(ks)) and x.shape == (2, len(ks), 15)
    assert d[0] == pytest.approx(np.full(len(ks), -0.4 / 39 * h))
    assert d[1] == pytest.approx(np.full(len(ks), -0.8 / 39 * h))


def test_conditions_keep_force_variants_apart() -> None:
    sf = load_study("seed_floor")
    row = {"size_cm": 8, "porosity": 0.7, "F_hold": 140.0, "F_squeeze": 150.0, "seed": 1}
    other_squeeze = dict(row, F_squeeze=300.0)
    other_seed = dict(row, seed=2)
    # Seeds of one condition share a key; a run with another squeeze force is another
    # condition (pooling them would compare different command schedules as if chance).
    assert sf.condition(row) == sf.condition(other_seed) == (8, 0.7, 140.0, 150.0)
    assert sf.condition(row) != sf.condition(other_squeeze)
