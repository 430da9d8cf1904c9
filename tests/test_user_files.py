"""Bounded reading of the files a user names (``rmi_learn.user_files``); the commands'
refusals are checked in ``tests/cli/test_bad_input.py``."""

from __future__ import annotations

from pathlib import Path

import pytest

from rmi_learn.errors import InputError
from rmi_learn.user_files import read_user_text


@pytest.mark.parametrize(
    "content",
    [b'{"a": 1}\r\n', b"\xef\xbb\xbf{}\r", b"{\n}\n", b""],
    ids=["crlf", "bom-cr", "lf", "empty"],
)
def test_the_text_is_what_read_text_gives(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "c.json"
    path.write_bytes(content)
    assert read_user_text(path, "config file") == path.read_text(encoding="utf-8")


def test_bytes_that_are_not_utf8_fail_as_read_text_does(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(UnicodeDecodeError) as got:
        read_user_text(path, "config file")
    with pytest.raises(UnicodeDecodeError) as want:
        path.read_text(encoding="utf-8")
    assert (got.value.start, got.value.reason) == (want.value.start, want.value.reason)


def test_a_missing_file_keeps_the_system_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_user_text(tmp_path / "none.json", "config file")


def test_the_limit_holds_for_a_file_longer_than_its_size_says(tmp_path: Path) -> None:
    """A file of the proc file system reports size 0: the limit is checked on what is read."""
    path = Path("/proc/self/status")
    if not path.is_file():
        path = tmp_path / "c.json"
        path.write_text("x" * 100)
    with pytest.raises(InputError, match=r"status|c\.json"):
        read_user_text(path, "config file", limit=10)


def test_the_label_and_the_limit_are_in_the_message(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_bytes(b"[]" * 600_000)
    with pytest.raises(InputError) as info:
        read_user_text(path, "grid file", label="--grid c.json", limit=1 << 20)
    assert str(info.value) == (
        "--grid c.json: 1200000 bytes or more exceed the limit of 1 MiB for a grid file"
    )
