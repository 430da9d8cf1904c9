"""studies/drain_depth.py: where in the sponge the released water started."""

from __future__ import annotations

import numpy as np
import pytest
from study_scripts import load_study


def test_depths_from_the_grown_rest_box_and_release_per_band() -> None:
    m = load_study("drain_depth")
    # Skeleton centres span [0.01, 0.09] x [0.01, 0.09] x [0.01, 0.19]; faces at r = 0.01 beyond.
    rest = np.array([[0.01, 0.01, 0.01], [0.09, 0.09, 0.19]])
    x0 = np.array(
        [
            [0.005, 0.05, 0.1],  # 5 mm inside the x = 0 face
            [0.05, 0.085, 0.1],  # 15 mm below the y = 0.1 face
            [0.05, 0.05, 0.1],  # 50 mm: the centre
            [-0.01, 0.05, 0.1],  # outside the block
        ]
    )
    d = m.depths(x0, rest, 0.01)
    assert d == pytest.approx([0.005, 0.015, 0.05, -0.01])
    mass = np.array([0.004, 0.004, 0.004, 0.004])
    retained = np.array([False, True, False, False])
    bands = m.release_by_depth(d, mass, retained)
    assert [(b["water_g"], b["released_g"]) for b in bands] == [
        pytest.approx((4.0, 4.0)),
        pytest.approx((4.0, 0.0)),
        pytest.approx((4.0, 4.0)),
    ]


def test_bad_radius_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    m = load_study("drain_depth")
    assert m.main(["--radius", "0.5"]) == 2
    assert "particle_radius" in capsys.readouterr().err
