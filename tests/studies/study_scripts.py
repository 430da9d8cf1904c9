"""Imports a script of ``studies/`` as a module, for the tests of its pure functions
(``studies/`` is a folder of scripts, not a package)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any

#: The repository's ``studies/`` folder.
STUDIES = Path(__file__).resolve().parents[2] / "studies"


def load_study(name: str) -> Any:
    """``load_study("seed_floor")``: ``studies/seed_floor.py``, imported afresh (a module of
    that name imported before is replaced, so each test sees the script's initial state)."""
    sys.modules.pop(name, None)
    sys.path.insert(0, str(STUDIES))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(STUDIES))
