"""Checks the binding tests share: bit-identical arrays, Ctrl-C during a call, a forked child."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-identical, NaN equal to NaN."""
    a, b = np.asarray(a), np.asarray(b)
    return bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))


def assert_interruptible(call: Callable[[], object]) -> None:
    """``call`` ends in KeyboardInterrupt within 5 s when a signal handler raises it 0.2 s in
    (as Ctrl-C does), i.e. the native code checks for signals while it runs."""

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, 0.2)
    try:
        t0 = time.perf_counter()
        with pytest.raises(KeyboardInterrupt):
            call()
        assert time.perf_counter() - t0 < 5.0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def in_forked_child(child: Callable[[], bytes]) -> bytes:
    """What ``child`` returns when run in a forked process (where the parent's worker threads
    do not exist)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        try:
            os.write(w, child())
        finally:
            os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    return data
