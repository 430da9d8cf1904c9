"""The paper's printed numbers, read from ``paper_reference.json`` (the one place they are
written down): its tables, and under ``analysis`` what Secs. V and VI.A, Figs. 4-6 and
supplement Sec. S4 state about the physical analysis (``None`` where the paper gives no
number)."""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

REFERENCE_FILE = "paper_reference.json"


def paper_reference() -> dict[str, Any]:
    """Everything in ``paper_reference.json``: the tables by name, ``analysis`` and the
    report's ``report_wording``."""
    text = resources.files("rmi_learn.analysis").joinpath(REFERENCE_FILE).read_text()
    data: dict[str, Any] = json.loads(text)
    return data


def physical_claims() -> dict[str, Any]:
    """What the paper states about the physical analysis (run counts, the single run, water
    per phase, lift success, squeeze association), as :func:`analyze
    <rmi_learn.analysis.physical.analyze>` stores it beside our numbers."""
    claims: dict[str, Any] = paper_reference()["analysis"]
    return claims
