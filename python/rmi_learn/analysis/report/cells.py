"""Table cells of the report: numbers formatted for a cell, and our row followed by the
paper's row for the same method, one cell per sponge size."""

from __future__ import annotations

from typing import Any

SIZES = (8, 10, 12)


def fmt(v: Any, digits: int = 2) -> str:
    """``v`` with ``digits`` decimals; a dash for a missing or non-finite number."""
    if v is None:
        return "–"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    if x != x or x in (float("inf"), float("-inf")):
        return "–"
    return f"{x:.{digits}f}"


def ours_then_paper(label: str, cells: list[str], paper: dict[str, Any]) -> list[list[str]]:
    """Our row, then the paper's row for the same method where the paper has one (its cells
    per size are a number or a list of numbers, in the table's column order)."""
    rows = [[label, *cells]]
    ref = paper.get(label)
    if ref is not None:
        vals = [ref[f"{s}cm"] for s in SIZES]
        rows.append(
            [f"paper: {label}"]
            + [fmt(x) for v in vals for x in (v if isinstance(v, list) else [v])]
        )
    return rows
