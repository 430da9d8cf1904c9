"""Loads a script of ``studies/`` as a module, for the tests of its pure functions
(``studies/`` is a folder of scripts, not a package)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

#: The repository's ``studies/`` folder.
STUDIES = Path(__file__).resolve().parents[2] / "studies"


def load_study(name: str) -> Any:
    """``load_study("seed_floor")``: ``studies/seed_floor.py``, freshly executed as a module."""
    spec = importlib.util.spec_from_file_location(name, STUDIES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
