"""studies/wm_splits.py: the paper's relative claims over several grouped splits."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from study_scripts import load_study

KEYS = {
    "baseline": {"kind": "baseline", "state_groups": "ALL", "shuffled": False},
    "ac-gru": {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False},
    "state-gru": {"kind": "state-gru", "state_groups": "ALL", "shuffled": False},
    "ac-gru-shuffled": {"kind": "ac-gru", "state_groups": "ALL", "shuffled": True},
    "ac-gru-LS": {"kind": "ac-gru", "state_groups": "LS", "shuffled": False},
}


def _table(
    root: Path, name: str, seed: int | None, cells: dict[tuple[str, int], tuple[float, float, int]]
) -> Path:
    """An eval-wm-like results.json: ``cells[(row, size)] = (water g, force N, windows)`` at
    0.64 s (step 32); other steps carry a marker value that must not leak into step 32."""
    recs = []
    for (row, size), (water, force, windows) in cells.items():
        metrics: dict[str, float] = {"windows": float(windows)}
        for step in (8, 16, 32, 64):
            metrics[f"water_mae_g@{step}"] = water if step == 32 else 999.0
            metrics[f"force_mae_n@{step}"] = force if step == 32 else 999.0
        rec: dict[str, Any] = {"size_cm": size, "metrics": metrics, **KEYS[row]}
        if seed is not None:
            rec["split_seed"] = seed
        recs.append(rec)
    d = root / name
    d.mkdir()
    (d / "results.json").write_text(json.dumps(recs))
    return d


def test_reductions_pooling_and_claim_counts(tmp_path: Path) -> None:
    m = load_study("wm_splits")
    a = _table(
        tmp_path,
        "a",
        1,
        {
            ("baseline", 8): (20.0, 10.0, 100),
            ("ac-gru", 8): (8.0, 4.0, 100),
            ("state-gru", 8): (10.0, 9.0, 100),
            ("ac-gru-shuffled", 8): (7.0, 12.0, 100),
            # A state-group ablation is not the full-state AC-GRU-WM.
            ("ac-gru-LS", 8): (1.0, 1.0, 100),
            ("baseline", 10): (30.0, 5.0, 50),
            ("ac-gru", 10): (33.0, 4.0, 50),
        },
    )
    b = _table(
        tmp_path,
        "b",
        2,
        {
            ("baseline", 8): (10.0, 10.0, 300),
            ("ac-gru", 8): (12.0, 2.0, 300),
            ("state-gru", 8): (11.0, 3.0, 300),
        },
    )
    res = m.summarise(m.load_tables([str(a), str(b)]))
    s8 = res["sizes"][8]
    la, lb = f"split seed 1 ({a})", f"split seed 2 ({b})"
    assert s8["splits"][la]["ac_gru_water_reduction"] == pytest.approx(0.6)
    assert s8["splits"][lb]["ac_gru_water_reduction"] == pytest.approx(-0.2)
    assert s8["splits"][la]["cells"]["ac-gru"]["water"] == 8.0
    # Window-weighted: (8 * 100 + 12 * 300) / 400 against (20 * 100 + 10 * 300) / 400.
    assert s8["pooled"]["ac-gru"]["water"] == pytest.approx(11.0)
    assert s8["pooled"]["baseline"]["water"] == pytest.approx(12.5)
    assert s8["pooled_ac_gru_water_reduction"] == pytest.approx(1 - 11.0 / 12.5)
    assert s8["pooled"]["ac-gru-shuffled"] == {
        "water": 7.0,
        "force": 12.0,
        "windows": 100,
        "splits": 1,
    }
    c8 = s8["claims"]
    assert c8["AC-GRU-WM water < Baseline"] == {"holds": 1, "of": 2}
    assert c8["AC-GRU-WM water < State-GRU-WM"] == {"holds": 1, "of": 2}
    assert c8["AC-GRU-WM force < State-GRU-WM"] == {"holds": 2, "of": 2}
    assert c8["AC-GRU-WM water < shuffled chunks"] == {"holds": 0, "of": 1}
    assert c8["AC-GRU-WM force < shuffled chunks"] == {"holds": 1, "of": 1}
    s10 = res["sizes"][10]
    assert s10["splits"][la]["ac_gru_water_reduction"] == pytest.approx(-0.1)
    assert s10["splits"][lb]["ac_gru_water_reduction"] is None
    assert s10["claims"]["AC-GRU-WM water < State-GRU-WM"] == {"holds": 0, "of": 0}
    assert res["sizes"][12]["pooled"] == {}
    assert res["sizes"][12]["pooled_ac_gru_water_reduction"] is None


def test_refuses_one_split_twice_and_missing_tables(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    m = load_study("wm_splits")
    cells = {("baseline", 8): (20.0, 10.0, 100), ("ac-gru", 8): (8.0, 4.0, 100)}
    a = _table(tmp_path, "a", 3, cells)
    b = _table(tmp_path, "b", 3, cells)
    old = _table(tmp_path, "old", None, cells)
    with pytest.raises(ValueError, match="both evaluate split seed 3"):
        m.load_tables([str(a), str(b)])
    # Tables written before eval-wm recorded the split seed are labelled by directory.
    assert list(m.load_tables([str(a), str(old)])) == [f"split seed 3 ({a})", str(old)]
    assert m.main(["--tables", str(a), str(tmp_path / "none")]) == 2
    assert "no results.json" in capsys.readouterr().err
    assert m.main(["--tables", str(a), str(old)]) == 0
    out = capsys.readouterr().out
    assert "AC-GRU-WM water < Baseline: 2 of 2 splits" in out and "60 %" in out
