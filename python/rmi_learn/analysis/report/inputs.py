"""Reading what the pipeline's stages wrote: JSON files that may be absent, the note a section
leaves when its stage has not run, and the paragraphs and pipe tables of a command's Markdown
output."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rmi_learn.analysis.report.document import Doc


def read_json(path: Path) -> Any:
    """The JSON content of ``path``, or ``None`` when the file is absent."""
    return json.loads(path.read_text(encoding="utf-8")) if path.exists() else None


def note_missing(doc: Doc, what: str, stage: str) -> None:
    """Say in ``doc`` that ``what`` is absent because ``stage`` has not run."""
    doc.p(f"*Not available: {what} (stage `{stage}` has not run in this directory).*")


def md_blocks(text: str) -> list[tuple[str, Any]]:
    """Paragraphs and pipe tables of a Markdown text written by one of our commands."""
    blocks: list[tuple[str, Any]] = []
    lines = text.splitlines()
    i = 0

    def cells(ln: str) -> list[str]:
        return [c.strip() for c in ln.strip().strip("|").split("|")]

    while i < len(lines):
        ln = lines[i].strip()
        if ln.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(cells(lines[i]))
                i += 1
            blocks.append(("table", (rows[0], rows[2:])))
            continue
        if ln:
            blocks.append(("p", ln))
        i += 1
    return blocks
