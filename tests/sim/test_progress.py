"""The progress line of a running trial (rmi_learn.sim.progress) and the callback of
:func:`rmi_learn.sim.trial.simulate` that feeds it."""

from __future__ import annotations

import io
from pathlib import Path

from rmi_learn.sim.progress import ProgressLine, TrialProgress, format_progress
from rmi_learn.sim.trial import _CHUNK, simulate
from tiny_trial import tiny_config


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def at(steps: int, phase: str = "hold") -> TrialProgress:
    return TrialProgress(phase, steps * 0.002, 12.0, steps, 1.5)


def test_format_names_phase_time_limit_steps_and_speed() -> None:
    line = format_progress(at(600, "squeeze"), 812.4)
    assert "phase squeeze" in line and "t   1.200 s of at most 12.00 s" in line
    assert "600 steps" in line and "812 steps/s" in line and "wall 2 s" in line


def test_a_log_gets_one_line_per_update_and_the_last_state_on_close() -> None:
    log = io.StringIO()
    line = ProgressLine(log, prefix="rmi simulate: ", every_s=0.0)
    line(at(100))
    line(at(200, "lift"))
    line.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 3 and all(ln.startswith("rmi simulate: phase ") for ln in lines)
    assert "200 steps" in lines[-1] and "\r" not in log.getvalue()


def test_a_terminal_line_is_rewritten_in_place_and_ended() -> None:
    tty = Terminal()
    line = ProgressLine(tty, every_s=0.0)
    line(at(100))
    line(at(200))
    line.close()
    text = tty.getvalue()
    assert text.count("\r") == 3 and text.endswith("\n") and text.count("\n") == 1


def test_nothing_is_written_before_the_first_interval() -> None:
    log = io.StringIO()
    line = ProgressLine(log, every_s=3600.0)
    line(at(100))
    line.close()
    assert log.getvalue() == ""


def test_simulate_reports_progress_after_each_chunk(tmp_path: Path) -> None:
    seen: list[TrialProgress] = []
    result = simulate(tiny_config(), tmp_path / "run", num_threads=1, progress=seen.append)
    assert seen, "no progress call"
    outcome = result["outcome"]
    # One call per chunk of steps, the last at the end of the trial.
    chunks = [min(_CHUNK * (i + 1), outcome["steps"]) for i in range(len(seen))]
    assert [p.steps for p in seen] == chunks
    assert seen[-1].time_s == outcome["sim_time"] and seen[-1].phase == "done"
    assert all(p.time_limit_s > p.time_s for p in seen)
    assert [p.wall_s for p in seen] == sorted(p.wall_s for p in seen)
