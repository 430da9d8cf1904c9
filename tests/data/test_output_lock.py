"""A command's lock on its output directory: a second holder is refused with one message
naming the lock, the lock goes with its holder, and commands do not block one another."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from rmi_learn.data.output_lock import lock_file, output_lock
from rmi_learn.errors import StageFailure, exit_status

fcntl = pytest.importorskip("fcntl")


def test_a_held_lock_refuses_a_second_holder_naming_the_lock(tmp_path: Path) -> None:
    with output_lock(tmp_path, "control-bench"):
        with pytest.raises(StageFailure) as err, output_lock(tmp_path, "control-bench"):
            pass  # pragma: no cover - never entered
    lock = tmp_path / lock_file("control-bench")
    assert str(err.value) == f"another control-bench is writing {tmp_path} (lock {lock})"
    assert exit_status(err.value) == 1
    # Released with the block: the next run takes it.
    with output_lock(tmp_path, "control-bench"):
        pass


def test_the_lock_of_one_command_does_not_block_another(tmp_path: Path) -> None:
    with output_lock(tmp_path, "closed-loop"), output_lock(tmp_path, "control-bench"):
        assert sorted(p.name for p in tmp_path.iterdir()) == [
            ".closed-loop.lock",
            ".control-bench.lock",
        ]


def test_a_lock_held_by_another_process_refuses_and_goes_with_it(tmp_path: Path) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD, str(tmp_path / lock_file("closed-loop"))],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == b"held\n"
        with pytest.raises(StageFailure, match="another closed-loop"):
            with output_lock(tmp_path, "closed-loop"):
                pass  # pragma: no cover - never entered
    finally:
        holder.kill()
        holder.wait()
    with output_lock(tmp_path, "closed-loop"):
        pass


#: Takes the lock the way another run would, says so, and keeps it until killed.
_HOLD = """
import fcntl, sys
f = open(sys.argv[1], "a+b")
fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
print("held", flush=True)
sys.stdin.read()
"""
