"""The paper's Table II findings checked on evaluation records."""

from __future__ import annotations

from typing import Any

from rmi_learn.world_models.findings import paper_findings


def record(kind: str, size: int, *water: float, shuffled: bool = False) -> dict[str, Any]:
    """An evaluation record whose training seeds had these water errors at 0.64 s."""
    rec: dict[str, Any] = {
        "kind": kind,
        "state_groups": "ALL",
        "shuffled": shuffled,
        "size_cm": size,
        "metrics": {"water_mae_g@32": sum(water) / len(water)},
    }
    if len(water) > 1:
        rec["metrics_per_seed"] = [{"water_mae_g@32": w} for w in water]
    return rec


def test_each_finding_compares_the_seed_means_and_keeps_every_seed() -> None:
    results = [
        record("baseline", 8, 10.0),
        record("ac-gru", 8, 4.0, 6.0, 11.0),
        record("state-gru", 8, 5.0),
        record("ac-gru", 8, 12.0, 14.0, 16.0, shuffled=True),
        record("baseline", 10, 9.0),
        record("ac-gru", 10, 12.0),
    ]
    found = {(f.finding.split(" (")[0].split(" below ")[1], f.size_cm): f for f in
             paper_findings(results)}  # fmt: skip
    base8 = found["the Baseline", 8]
    assert base8.ours == 7.0 and base8.other == 10.0 and base8.holds
    assert base8.ours_per_seed == (4.0, 6.0, 11.0) and not base8.seeds_agree
    assert not found["State-GRU-WM", 8].holds  # 7.0 against 5.0
    shuffled = found["itself with shuffled commands", 8]
    assert shuffled.holds and shuffled.seeds_agree
    assert not found["the Baseline", 10].holds
    # No State-GRU-WM or shuffled run for 10 cm: those comparisons are not made.
    assert set(found) == {
        ("the Baseline", 8),
        ("State-GRU-WM", 8),
        ("itself with shuffled commands", 8),
        ("the Baseline", 10),
    }
