"""The side view of rmi_learn.sim.render on the tiny trial."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import rmi_sph
from rmi_learn.sim.render import PAD, side_view, view_of
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def trial() -> rmi_sph.Trial:
    t = rmi_sph.Trial(tiny_config(), num_threads=1)
    t.step(100)
    return t


def _colour_columns(img: Any, colour: Any) -> Any:
    return np.nonzero(np.all(img == colour, axis=2).any(axis=0))[0]


def test_pads_either_side_of_the_sponge(trial: rmi_sph.Trial) -> None:
    view = view_of(trial, (120, 160))
    img = side_view(trial, view)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    cols = _colour_columns(img, PAD)
    assert cols.min() < 60 and cols.max() > 100  # a pad on each side of the centre column
    # The window is fixed: pads closing by a few millimetres move inward in it.
    later = rmi_sph.Trial.from_state(trial.get_state(), num_threads=1)
    later.set_action(0.0, velocity_command=0.05)
    later.step(100)
    moved = _colour_columns(side_view(later, view), PAD)
    assert moved.min() > cols.min() and moved.max() < cols.max()


def test_view_refuses_a_tiny_image(trial: rmi_sph.Trial) -> None:
    with pytest.raises(ValueError, match="render shape"):
        view_of(trial, (4, 100))
