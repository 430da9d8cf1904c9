"""Any input to the step and reset of rmi_learn.sim.env.SpongeSqueezeEnv is taken or refused
with one line: random actions (shapes, dtypes, NaN, inf, complex, huge values) and random
reset options (known and unknown keys, values of any kind)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import rmi_sph
from rmi_learn.sim.env import SpongeSqueezeEnv
from tiny_trial import tiny_config

pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: Stand-ins for the saved hand-over state and its file, replaced in the test body.
STATE, STATE_FILE = "<the saved state>", "<the saved state's file>"

scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.booleans(),
    st.complex_numbers(allow_nan=True, allow_infinity=True),
    st.none(),
    st.text(max_size=4),
)
actions = st.one_of(
    scalars,
    st.lists(scalars, max_size=4),
    st.lists(st.lists(st.floats(), max_size=3), max_size=3),  # ragged as well as nested
    hnp.arrays(
        dtype=hnp.scalar_dtypes(),
        shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=3),
    ),
    hnp.arrays(dtype=np.float32, shape=st.just((2,))),  # the right shape, any values
)
option_values = st.one_of(
    scalars,
    st.floats(min_value=0.0, max_value=2.0),
    st.sampled_from([STATE, STATE_FILE]),
    st.lists(scalars, max_size=2),
    st.dictionaries(st.text(max_size=3), scalars, max_size=2),
)
option_keys = st.one_of(
    st.sampled_from(["goal", "goal_fraction", "state", "state_path", "goal_kg", "seed"]),
    st.text(max_size=6),
)
options = st.one_of(
    st.none(),
    st.dictionaries(option_keys, option_values, max_size=3),
    st.lists(st.tuples(option_keys, option_values), max_size=2),
    scalars,
)


@pytest.fixture(scope="module")
def env_and_state(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[SpongeSqueezeEnv, bytes, Path]:
    """One environment (built once: resets are costly), its hand-over state and that
    state's file, from which every example starts cheaply."""
    env = SpongeSqueezeEnv(tiny_config(), goal=0.5, action_mode="force_velocity")
    env.reset(seed=0)
    state = env.get_state()
    path = tmp_path_factory.mktemp("env") / "handover.state"
    rmi_sph.Trial.from_state(state).save(path)
    return env, state, path


def assert_one_line(exc: BaseException, *names: str) -> None:
    message = str(exc)
    assert message and "\n" not in message, message
    assert any(name in message for name in names), message


@FUZZ
@given(action=actions)
def test_any_action_is_taken_or_refused_in_one_line(
    env_and_state: tuple[SpongeSqueezeEnv, bytes, Path], action: Any
) -> None:
    env, state, _ = env_and_state
    env.reset(options={"state": state})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing may be dropped or cast with a warning
        try:
            obs, reward, terminated, truncated, info = env.step(action)
        except (ValueError, TypeError) as exc:
            assert_one_line(exc, "action")
            return
    assert not np.iscomplexobj(action)
    assert obs.shape == (23,) and not np.isnan(obs).any()
    assert math.isfinite(reward) and not truncated


@FUZZ
@given(options=options)
def test_any_reset_options_are_taken_or_refused_in_one_line(
    env_and_state: tuple[SpongeSqueezeEnv, bytes, Path], options: Any
) -> None:
    env, state, path = env_and_state
    stand_in = {STATE: state, STATE_FILE: str(path)}
    if isinstance(options, dict):
        options = {k: stand_in.get(v, v) if isinstance(v, str) else v for k, v in options.items()}
        if not {"state", "state_path"} & options.keys():
            options = {"state": state, **options}  # a cheap reset, not the scripted approach
    elif options is None:
        options = {"state": state}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            obs, info = env.reset(options=options)
        except (ValueError, TypeError) as exc:
            assert_one_line(exc, "options")
            return
        except OSError as exc:  # a file that is not there, named by the binding
            assert isinstance(options["state_path"], str) and "state" not in options
            assert_one_line(exc, "")
            return
    assert obs.shape == (23,) and not np.isnan(obs).any()
    assert math.isfinite(info["goal"]) and info["goal"] >= 0.0
    env.step(np.array([100.0, 0.0], np.float32))
