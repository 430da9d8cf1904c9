"""The report's section on the protocol benchmark: the feedback rows, the sensor-mode ratios
and a finding per size and task, read from ``control_protocol/table_protocol.json``."""

from __future__ import annotations

import json
from pathlib import Path

from rmi_learn.analysis.report import write_report
from rmi_learn.control_bench.feedback.driver import summary
from rmi_learn.control_bench.feedback.protocol import load_protocol


def _rows(ctrl: str, errs: list[float]) -> list[dict]:
    return [
        {
            "controller": ctrl,
            "run_id": f"r{i % 2}",
            "tick": i,
            "abs_error_g": e,
            "role": "test",
            "size_cm": 8,
            "task": task,
        }
        for task in ("reach", "settle")
        for i, e in enumerate(errs)
    ]


def test_report_leads_the_goal_reaching_section_with_the_feedback_rows(tmp_path: Path) -> None:
    p = load_protocol("tiny")
    rows = _rows("pi-privileged", [0.1, 0.2, 0.1, 0.3]) + _rows("pi-weight", [8.0, 9.0, 7.0, 9.5])
    rows += _rows("pi-learned", [2.0, 1.0, 2.5, 1.5])
    result = {
        "protocol": p.raw,
        "protocol_digest": p.digest,
        "summary": summary(p, rows),
    }
    (tmp_path / "control_protocol").mkdir()
    (tmp_path / "control_protocol" / "table_protocol.json").write_text(json.dumps(result))
    md, _ = write_report(tmp_path)
    text = md.read_text()
    assert "Goal-reaching control: feedback on what the robot can sense" in text
    assert "| pi-privileged | privileged | 0.15" in text
    assert (
        "8 cm, reach: pi-privileged median 0.15 g; pi-weight median 8.50 g; pi-learned 1.75 g"
        in text
    )
