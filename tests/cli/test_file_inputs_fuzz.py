"""Property-based tests of the files the user names on the command line: whatever bytes a
``--config`` of options, a pipeline ``--config`` or a sweep ``--grid`` holds (binary noise,
text, JSON of any shape, objects with real and unknown keys and values of any kind), the
command either accepts it or ends with status 2 and one line on stderr naming the command,
and creates no ``--out``; never a traceback.

An accepted file would start real work (a sweep, a pipeline, a training run): the library
function the command calls is replaced by one that stops at the verdict.
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rmi_learn.cli import main


class Accepted(Exception):
    """Raised in place of the work an accepted file would start."""


def _stop(*args: Any, **kwargs: Any) -> None:
    raise Accepted


#: command -> (argv before the file's path, the functions an accepted file reaches, the keys
#: a file of that command may hold, so that random objects reach the checks of real fields).
COMMANDS: dict[str, tuple[list[str], list[tuple[str, str]], list[str]]] = {
    "train-wm": (
        ["train-wm", "--model", "arx", "--data", "d", "--config"],
        [("rmi_learn.world_models.training", "train")],
        ["epochs", "lr", "batch_size", "seed", "horizon", "model_arg", "device", "threads"],
    ),
    "sweep": (
        ["sweep", "--no-progress", "--grid"],
        [("rmi_learn.data.sweep", "sweep"), ("rmi_learn.data.sweep", "run_sweep")],
        ["sizes", "porosities", "holds", "squeezes", "seeds", "radius", "dt", "by_size"],
    ),
    "pipeline": (
        ["pipeline", "--config"],
        [("rmi_learn.cli.pipeline", "run_pipeline")],
        ["name", "grid", "dataset", "world_models", "policies", "rank", "closed_loop"],
    ),
}

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=12),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


def contents(command: str) -> st.SearchStrategy[bytes]:
    """File contents for ``command``: noise, text, any JSON, and objects of its keys."""
    keys = st.sampled_from(COMMANDS[command][2]) | st.text(max_size=8)
    objects = st.dictionaries(keys, json_values, max_size=5)
    as_json = (json_values | objects).map(lambda v: json.dumps(v).encode())
    text = st.text(max_size=200).map(str.encode)
    return st.binary(max_size=200) | text | as_json | as_json.map(lambda b: b[: len(b) // 2])


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_named_file_is_accepted_or_one_line_and_status_2(command: str) -> None:
    argv, stops, _ = COMMANDS[command]

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(contents(command))
    def check(content: bytes) -> None:
        with tempfile.TemporaryDirectory() as tmp, pytest.MonkeyPatch.context() as mp:
            for module, name in stops:
                mp.setattr(f"{module}.{name}", _stop)
            path = Path(tmp) / "file.json"
            path.write_bytes(content)
            out = Path(tmp) / "out"
            err = io.StringIO()
            usage = False
            try:
                with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                    status = main([*argv, str(path), "--out", str(out)])
            except Accepted:
                return
            except SystemExit as exc:  # argparse refusing a value: its usage line, then ours
                status, usage = exc.code, True
            lines = err.getvalue().splitlines()
            assert status == 2, (content, lines)
            assert len(lines) == (2 if usage else 1), lines
            assert lines[-1].startswith(f"rmi {command}: "), lines
            assert "Traceback" not in err.getvalue()
            assert not out.exists(), (content, lines)

    check()
