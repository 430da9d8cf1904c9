"""Output written whole or not at all (``rmi_learn.data.staging``): which temporary
directories count as abandoned, the directories a command made and undoes, and errors that
name the output rather than its temporary."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from rmi_learn.data import staging


def abandoned_temporary(parent: Path, name: str) -> Path:
    """A temporary directory made by a process that has exited since."""
    code = "import sys; from pathlib import Path; from rmi_learn.data import staging; "
    code += "print(staging.temporary_dir(Path(sys.argv[1]), sys.argv[2]))"
    package_root = Path(staging.__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(package_root), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", code, str(parent), name],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return Path(done.stdout.strip())


def test_only_abandoned_temporaries_of_this_host_are_removed(tmp_path: Path) -> None:
    dead = abandoned_temporary(tmp_path, "export")
    (dead / "data").mkdir()
    live = staging.temporary_dir(tmp_path, "export")
    pid_host = dead.name.split(".")[2]
    elsewhere = tmp_path / dead.name.replace(pid_host, pid_host.split("@")[0] + "@far-away")
    elsewhere.mkdir()
    a_file = tmp_path / dead.name.replace("export", "file")  # the pattern, but not a directory
    a_file.write_text("")
    link = tmp_path / dead.name.replace("export", "link")
    link.symlink_to(live, target_is_directory=True)
    other = tmp_path / ".export.notes.tmp"
    other.mkdir()
    assert staging.remove_stale_temporaries(tmp_path) == 1
    assert not dead.exists()
    assert live.is_dir() and elsewhere.is_dir() and other.is_dir() and link.is_symlink()
    assert a_file.is_file()


def test_a_missing_parent_has_no_temporaries(tmp_path: Path) -> None:
    assert staging.remove_stale_temporaries(tmp_path / "none") == 0


def test_make_dirs_reports_and_undoes_only_what_it_made(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    made = staging.make_dirs(tmp_path / "a" / "b" / "c")
    assert made == [tmp_path / "a" / "b" / "c", tmp_path / "a" / "b"]
    (tmp_path / "a" / "b" / "c" / "part.parquet").write_text("")
    (tmp_path / "a" / "mine.txt").write_text("kept")
    staging.remove_made_dirs(made)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["mine.txt"]
    assert staging.make_dirs(tmp_path / "a") == []


def test_make_dirs_refuses_a_file_in_the_way(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("")
    with pytest.raises(FileExistsError):
        staging.make_dirs(tmp_path / "f")
    broken = tmp_path / "broken"
    broken.symlink_to(tmp_path / "nowhere")
    with pytest.raises(FileExistsError):
        staging.make_dirs(broken)


def test_an_error_in_the_temporary_names_the_output(tmp_path: Path) -> None:
    tmp, dest = tmp_path / ".out.1@h.abc.tmp", tmp_path / "out"
    cases = [
        (
            OSError(errno.ENOSPC, "No space left on device", str(tmp / "meta" / "x.json")),
            dest / "meta" / "x.json",
        ),
        (OSError(errno.ENOSPC, "No space left on device"), dest),
    ]
    for exc, named in cases:
        with pytest.raises(OSError) as info:
            staging.raise_named_for(exc, tmp, dest)
        assert info.value.errno == errno.ENOSPC and info.value.filename == str(named)
        assert info.value.__cause__ is exc
    elsewhere = OSError(errno.EACCES, "Permission denied", str(tmp_path / "other"))
    without_number = OSError("disk full")
    for exc in (elsewhere, without_number):
        with pytest.raises(OSError) as info:
            staging.raise_named_for(exc, tmp, dest)
        assert info.value is exc


def test_parquet_bytes_are_what_polars_writes_to_a_file(tmp_path: Path) -> None:
    table = pl.DataFrame({"a": [1.5, float("nan"), 3.0], "b": ["x", "y", "z"]})
    table.write_parquet(tmp_path / "t.parquet")
    assert staging.parquet_bytes(table) == (tmp_path / "t.parquet").read_bytes()
    # With key-value metadata, as the checkpoints of closed-loop and control-bench carry it.
    meta = {"rmi.fingerprint": "abc"}
    table.write_parquet(tmp_path / "m.parquet", metadata=meta)
    data = staging.parquet_bytes(table, meta)
    assert data == (tmp_path / "m.parquet").read_bytes()
    assert pl.read_parquet_metadata(tmp_path / "m.parquet")["rmi.fingerprint"] == "abc"
