"""Where rmi_learn.sim.rerun_view writes a recording: missing folders are made, and a write
that fails leaves neither the file, its temporary nor the folders it made."""

from __future__ import annotations

from pathlib import Path

import pytest

from rmi_learn.sim.rerun_view import staged_output


def test_missing_folders_are_made_and_the_file_appears_when_complete(tmp_path: Path) -> None:
    out = tmp_path / "new" / "deeper" / "one.rrd"
    with staged_output(out) as tmp:
        assert tmp.parent == out.parent and tmp.parent.is_dir() and tmp != out
        tmp.write_bytes(b"recording")
        assert not out.exists()
    assert out.read_bytes() == b"recording"
    assert sorted(p.name for p in out.parent.iterdir()) == ["one.rrd"]


def test_a_failed_write_leaves_nothing_it_made(tmp_path: Path) -> None:
    (tmp_path / "kept").mkdir()
    out = tmp_path / "kept" / "new" / "deeper" / "one.rrd"
    with pytest.raises(OSError, match="disk full"), staged_output(out) as tmp:
        tmp.write_bytes(b"half a recor")
        raise OSError("disk full")
    assert list((tmp_path / "kept").iterdir()) == []
    # A folder that was there stays, with what it held; an old recording is kept.
    old = tmp_path / "kept" / "one.rrd"
    old.write_bytes(b"old")
    with pytest.raises(OSError), staged_output(old) as tmp:
        tmp.write_bytes(b"new")
        raise OSError("disk full")
    assert [p.name for p in (tmp_path / "kept").iterdir()] == ["one.rrd"]
    assert old.read_bytes() == b"old"


def test_a_file_where_a_folder_should_be_is_an_os_error(tmp_path: Path) -> None:
    (tmp_path / "plain").write_text("not a folder")
    with pytest.raises(FileExistsError), staged_output(tmp_path / "plain" / "one.rrd"):
        pass
