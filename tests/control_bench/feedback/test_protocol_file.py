"""The benchmark's protocol file (control_bench.feedback.protocol): the shipped protocols are
valid, every field is checked with one line naming it, its digest follows its content, and a
run that differs from the protocol an output was written under is refused, or moved aside when
asked."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from rmi_learn.cli import main
from rmi_learn.control_bench.feedback.driver import (
    DIGEST_KEY,
    ROWS_FILE,
    SCHEMA,
    _load_done,
    run_protocol_bench,
    set_aside,
)
from rmi_learn.control_bench.feedback.protocol import PROTOCOL_DIR, load_protocol, validate
from rmi_learn.data.checkpoint_rows import write_rows
from rmi_learn.errors import InputError


@pytest.fixture
def raw() -> dict[str, Any]:
    return json.loads((PROTOCOL_DIR / "control.json").read_text())


@pytest.mark.parametrize("name", ["control", "quick", "tiny"])
def test_the_shipped_protocols_are_valid(name: str) -> None:
    p = load_protocol(name)
    assert p["name"].startswith(name) and len(p.digest) == 64


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("split",), "random", "protocol split must be"),
        (("states", "max_per_run"), 5, r"states.max_per_run must be an integer in \[1, 4\]"),
        (("states", "phases"), ["hold"], "states.phases must be a non-empty subset"),
        (("tasks",), ["reach", "sprint"], "tasks must be a non-empty subset of reach, settle"),
        (("controllers",), ["pi-privileged", "mpc"], "controllers must be a non-empty list"),
        (("references", "sensors"), "pi-privileged", "references.sensors must name a listed"),
        (("sensors", "wrist_N"), -1.0, "sensors.wrist_N must be in"),
        (("sensors", "latency_ticks"), 99, "sensors.latency_ticks must be an integer"),
        (("pi", "ki"), [], "pi.ki must be a non-empty list"),
        (("sizes_cm",), [9], "sizes_cm must be a non-empty list of 8, 10, 12"),
    ],
)
def test_a_bad_field_is_one_line_naming_it(
    raw: dict, path: tuple, value: Any, message: str
) -> None:
    bad = copy.deepcopy(raw)
    node = bad
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(InputError, match=message):
        validate(bad)


def test_the_digest_follows_the_content_not_the_key_order(raw: dict) -> None:
    same = dict(reversed(list(raw.items())))
    assert validate(same).digest == validate(raw).digest
    other = copy.deepcopy(raw)
    other["goal_seed"] += 1
    assert validate(other).digest != validate(raw).digest


def test_an_output_of_another_protocol_is_refused(tmp_path: Path, raw: dict) -> None:
    rows = tmp_path / "rows.parquet"
    write_rows(rows, [], SCHEMA, {DIGEST_KEY: "0" * 64})
    with pytest.raises(InputError, match="written under another protocol"):
        _load_done(rows, validate(raw).digest)
    assert _load_done(rows, "0" * 64) == []


def test_an_output_of_another_protocol_is_moved_aside_when_asked(tmp_path: Path, raw: dict) -> None:
    out = tmp_path / "out"
    meta = {DIGEST_KEY: "ab" * 32, "rmi.protocol.name": "tiny-v0"}
    write_rows(out / ROWS_FILE, [], SCHEMA, meta)
    (out / "table_protocol.md").write_text("old")
    said: list[str] = []
    dest = tmp_path / f"out.tiny-v0-{'ab' * 6}"
    assert set_aside(out, validate(raw).digest, said.append) == dest
    assert dest.is_dir() and (dest / "table_protocol.md").read_text() == "old"
    assert (dest / ROWS_FILE).exists() and not (out / ROWS_FILE).exists()
    assert said == [f"{out} held the output of protocol tiny-v0-{'ab' * 6}: moved to {dest}"]
    # An output of this protocol stays where it is.
    write_rows(out / ROWS_FILE, [], SCHEMA, {DIGEST_KEY: validate(raw).digest})
    assert set_aside(out, validate(raw).digest, said.append) is None
    assert (out / ROWS_FILE).exists() and len(said) == 1


def test_a_sweep_of_another_grid_is_refused(tmp_path: Path) -> None:
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "grid.json").write_text(json.dumps({"name": "quick"}))
    with pytest.raises(InputError, match="is for the 'tiny' grid"):
        run_protocol_bench("tiny", tmp_path / "sweep", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_the_command_refuses_options_the_protocol_fixes(tmp_path: Path, capsys: Any) -> None:
    code = main(
        [
            "control-bench",
            "--protocol",
            "tiny",
            "--runs",
            str(tmp_path),
            "--out",
            str(tmp_path / "o"),
            "--k",
            "3",
        ]
    )
    assert code == 2
    assert "--k does not apply with --protocol" in capsys.readouterr().err
    code = main(["control-bench", "--runs", str(tmp_path), "--out", str(tmp_path / "o")])
    assert code == 2 and "--data is required (or give --protocol)" in capsys.readouterr().err
    code = main(["control-bench", "--runs", str(tmp_path), "--out", "o", "--replace-other"])
    assert code == 2 and "--replace-other applies with --protocol only" in capsys.readouterr().err
    code = main(
        [
            "control-bench",
            "--protocol",
            "nope",
            "--runs",
            str(tmp_path),
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert code == 2 and "no such file or shipped protocol" in capsys.readouterr().err
