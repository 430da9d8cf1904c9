"""Progress of one trial while it runs: what ``rmi simulate`` prints to stderr.

:func:`rmi_learn.sim.trial.simulate` calls its ``progress`` callback with a
:class:`TrialProgress` after every chunk of steps; :class:`ProgressLine` turns those calls
into one status line every few seconds (rewritten in place on a terminal, a new line per
update in a log file), so that a trial of several minutes shows that it advances.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TextIO


@dataclass(frozen=True)
class TrialProgress:
    """Where a running trial stands."""

    #: Controller phase name (settle, close, ramp, hold, lift, wait, squeeze, done, ...).
    phase: str
    #: Simulated time (s).
    time_s: float
    #: Simulated time after which the trial gives up (s).
    time_limit_s: float
    #: Simulator steps completed.
    steps: int
    #: Wall-clock time since the trial started (s).
    wall_s: float


def format_progress(p: TrialProgress, steps_per_s: float) -> str:
    """One status line: phase, simulated time against its limit, steps, speed, wall time."""
    return (
        f"phase {p.phase:<8s} t {p.time_s:7.3f} s of at most {p.time_limit_s:.2f} s  "
        f"{p.steps} steps  {steps_per_s:,.0f} steps/s  wall {p.wall_s:.0f} s"
    )


class ProgressLine:
    """A ``progress`` callback that writes :func:`format_progress` lines to ``stream``, at
    most one per ``every_s`` seconds of wall time, prefixed with ``prefix``. On a terminal
    the line is rewritten in place; :meth:`close` ends it with a newline after a last
    update."""

    def __init__(self, stream: TextIO, *, prefix: str = "", every_s: float = 2.0) -> None:
        self.stream = stream
        self.prefix = prefix
        self.every_s = every_s
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self._last_wall = time.perf_counter()
        self._last_steps = 0
        self._last: TrialProgress | None = None
        self._shown = False

    def __call__(self, p: TrialProgress) -> None:
        self._last = p
        if time.perf_counter() - self._last_wall >= self.every_s:
            self._show(p)

    def _show(self, p: TrialProgress) -> None:
        now = time.perf_counter()
        elapsed = now - self._last_wall
        rate = (p.steps - self._last_steps) / elapsed if elapsed > 0 else 0.0
        self._last_wall, self._last_steps = now, p.steps
        line = self.prefix + format_progress(p, rate)
        # "\x1b[K" clears what a longer previous line left to the right.
        self.stream.write(f"\r{line}\x1b[K" if self.tty else line + "\n")
        self.stream.flush()
        self._shown = True

    def close(self) -> None:
        """Show the last state (if any line was shown) and end the line on a terminal."""
        if self._shown and self._last is not None:
            self._show(self._last)
        if self._shown and self.tty:
            self.stream.write("\n")
            self.stream.flush()
