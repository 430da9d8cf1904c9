"""The report's section on the engine's physical validation: one row per validation record
(``make validation``)."""

from __future__ import annotations

import json
from pathlib import Path

from rmi_learn.analysis.report.document import Doc


def section_validation(doc: Doc, out: Path, validation: Path | None) -> None:
    """One row per validation record of ``validation`` (default ``out/validation``)."""
    doc.h(2, "Physical validation of the engine")
    src = validation if validation is not None else out / "validation"
    recs = sorted(src.glob("*.json")) if src.is_dir() else []
    if not recs:
        doc.p(
            "*No validation records here. Run `make validation` (it runs "
            "`cargo test --release -p rmi-sph --test validation` with "
            "`RMI_VALIDATION_OUT=OUT/validation`) and re-run `rmi report`. The figures "
            "recorded for the release are in docs/engine.md (Validation).*"
        )
        return
    rows = []
    for path in recs:
        r = json.loads(path.read_text(encoding="utf-8"))
        rows.append(
            [
                str(r.get("case", path.stem)),
                str(r.get("setup", "")),
                str(r.get("measured", "")),
                str(r.get("analytic", "")),
                str(r.get("error", "")),
                "pass" if r.get("pass") else "FAIL",
            ]
        )
    doc.table(["case", "set-up", "measured", "analytic", "error", "test"], rows, text=True)
