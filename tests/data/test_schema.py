"""The seed range of ``rmi_learn.data.schema``: the engine's, stated in the engine's words,
and the check the library's entry points share."""

from __future__ import annotations

import numpy as np
import pytest

import rmi_sph
from rmi_learn.data.schema import SEED_MAX, SEED_RANGE, checked_seed


def test_the_seed_range_is_the_engines() -> None:
    assert SEED_MAX == rmi_sph.SEED_MAX == 2**63 - 1
    with pytest.raises(rmi_sph.ConfigError) as err:
        rmi_sph.validate_config({"seed": SEED_MAX + 1})
    assert err.value.expected == SEED_RANGE


@pytest.mark.parametrize("value", [0, SEED_MAX, np.int64(7), np.uint64(SEED_MAX)])
def test_seeds_in_the_range_are_taken_as_ints(value: object) -> None:
    seed = checked_seed(value)
    assert type(seed) is int and seed == int(value)  # type: ignore[call-overload]


@pytest.mark.parametrize("value", [-1, SEED_MAX + 1, np.uint64(2**64 - 1), True, 1.0, "3", None])
def test_other_values_are_one_line_naming_the_seed_and_the_range(value: object) -> None:
    with pytest.raises(ValueError) as err:
        checked_seed(value, "split seed")
    message = str(err.value)
    assert message.startswith("split seed must be " + SEED_RANGE) and "\n" not in message
