"""Reading the run table of ``rmi analyze``."""

from __future__ import annotations

from pathlib import Path

import pytest

from rmi_learn.analysis.run_table import AnalysisError, load_runs


def test_load_runs_rejects_a_file(tmp_path: Path) -> None:
    f = tmp_path / "x.txt"
    f.write_text("not a directory")
    with pytest.raises(AnalysisError, match="not a directory"):
        load_runs(f)
