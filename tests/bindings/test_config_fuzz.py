"""Property-based tests of the config converters: any JSON-like value (nested dicts and lists,
strings, huge integers, NaN and inf, nesting up to 50 levels) given as a trial config is
either accepted or refused with ``ConfigError``/``ValueError``/``TypeError`` by
``rmi_sph.validate_config`` and ``rmi_sph.trial_config(..., material=...)``, and with one line
and status 2 by ``rmi simulate --config``; the process never crashes.

Values nested 100,000 levels deep and values that contain themselves are checked in a child
process, so that a crash of the native converter fails those tests instead of ending pytest.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rmi_sph
from rmi_learn.cli import main

REFUSED = (rmi_sph.ConfigError, ValueError, TypeError)
DEFAULTS: dict[str, Any] = rmi_sph.validate_config({})
#: Field names of the config and its sections: random dicts use them often, so that values
#: reach the converters of real fields and not only the unknown-key check.
FIELDS: list[str] = sorted(
    set(DEFAULTS) | {k for v in DEFAULTS.values() if isinstance(v, dict) for k in v}
)

scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8)
)
keys = st.sampled_from(FIELDS) | st.text(max_size=6)


def _nest(value: Any, depth: int, as_dict: bool, key: str) -> Any:
    for _ in range(depth):
        value = {key: value} if as_dict else [value]
    return value


json_like = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=5),
    max_leaves=20,
)
#: Shallow random values, and the same wrapped in up to 50 levels of lists or dicts.
values = json_like | st.builds(
    _nest, json_like, st.integers(0, 50), st.booleans(), st.sampled_from(FIELDS)
)
configs = st.dictionaries(keys, values, max_size=6)
FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(values)
def test_validate_config_accepts_or_refuses_any_value(value: Any) -> None:
    # A string is a JSON text or a path to a JSON file: a missing or unreadable file is
    # refused with the OSError that names it.
    refused = (*REFUSED, OSError) if isinstance(value, str) else REFUSED
    with contextlib.suppress(*refused):
        rmi_sph.validate_config(value)


@FUZZ
@given(configs)
def test_validate_config_accepts_or_refuses_any_object(config: dict[str, Any]) -> None:
    with contextlib.suppress(*REFUSED):
        rmi_sph.validate_config(config)


@FUZZ
@given(values, st.sampled_from(["material", "gripper", "controller", "dt", "seed", "jitter"]))
def test_trial_config_accepts_or_refuses_any_override(value: Any, field: str) -> None:
    with contextlib.suppress(*REFUSED):
        rmi_sph.trial_config(8, 0.8, 20.0, 150.0, 0.01, **{field: value})


class Accepted(Exception):
    """Raised in place of building a trial the config of which the engine accepted."""


def _accept_only(config: Any, **kwargs: Any) -> None:
    rmi_sph.validate_config(config)
    raise Accepted


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(values | configs)
def test_simulate_config_file_is_accepted_or_one_line_and_status_2(value: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp, pytest.MonkeyPatch.context() as mp:
        # An accepted config would run a whole trial: stop at the engine's verdict.
        mp.setattr(rmi_sph, "Trial", _accept_only)
        path = Path(tmp) / "config.json"
        path.write_text(json.dumps(value), encoding="utf-8")
        out = Path(tmp) / "out"
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                status = main(["simulate", "--config", str(path), "--out", str(out)])
        except Accepted:
            return
        lines = err.getvalue().splitlines()
        assert status == 2 and len(lines) == 1 and lines[0].startswith("rmi simulate: ")
        assert not out.exists()


def _in_child(setup: str, call: str) -> subprocess.CompletedProcess[str]:
    """Run ``setup`` then ``call`` in a fresh interpreter; it prints ``refused`` when the
    call raises one of the expected errors, ``accepted`` when it returns."""
    code = textwrap.dedent(
        f"""
        import sys
        import rmi_sph
        {setup}
        try:
            {call}
        except (rmi_sph.ConfigError, ValueError, TypeError) as exc:
            print("refused", type(exc).__name__)
        else:
            print("accepted")
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )


DEEP_DICT = "value = {}\nfor _ in range(100_000):\n    value = {'material': value}"
DEEP_LIST = "value = []\nfor _ in range(100_000):\n    value = [value]"
CYCLIC_LIST = "value = []\nvalue.append(value)"
CYCLIC_DICT = "value = {}\nvalue['material'] = value"


@pytest.mark.parametrize(
    ("setup", "call"),
    [
        (DEEP_DICT, "rmi_sph.validate_config(value)"),
        (DEEP_LIST, "rmi_sph.validate_config({'material': value})"),
        (DEEP_DICT, "rmi_sph.trial_config(8, 0.8, 20.0, 150.0, 0.01, material=value)"),
        (CYCLIC_LIST, "rmi_sph.validate_config({'material': value})"),
        (CYCLIC_LIST, "rmi_sph.trial_config(8, 0.8, 20.0, 150.0, 0.01, material=value)"),
        (CYCLIC_DICT, "rmi_sph.validate_config(value)"),
    ],
    ids=[
        "deep-dict-validate",
        "deep-list-validate",
        "deep-dict-trial-config",
        "cyclic-list-validate",
        "cyclic-list-trial-config",
        "cyclic-dict-validate",
    ],
)
def test_deep_and_cyclic_values_are_refused_without_a_crash(setup: str, call: str) -> None:
    child = _in_child(textwrap.indent(setup, " " * 8).lstrip(), call)
    assert child.returncode == 0, f"status {child.returncode}: {child.stderr[-500:]}"
    assert child.stdout.startswith("refused"), child.stdout + child.stderr[-500:]
