"""The paper's printed numbers, read from their one file."""

from __future__ import annotations

from rmi_learn.analysis.paper import paper_reference, physical_claims


def test_the_physical_claims_are_the_papers_numbers() -> None:
    claims = physical_claims()
    assert claims == paper_reference()["analysis"]
    assert claims["counts"]["runs_total"] == 594
    assert claims["counts"]["stable_squeeze"] == 410
    assert claims["counts"]["stable_squeeze_by_size"] == {"8": 110, "10": 157, "12": 143}
    assert claims["single_run"]["F_hold"] == 210.0 and claims["single_run"]["F_squeeze"] == 300.0
    assert claims["lift_success"]["rate_range_at_porosity_0.7"] == [0.20, 0.64]
    assoc = claims["squeeze_association"]
    assert assoc["slope_g_per_N"] == 0.669 and assoc["ci95_g_per_N"] == [0.610, 0.728]
    assert assoc["slope_g_per_100N"] == 66.9 and assoc["ci95_g_per_100N"] == [61.0, 72.8]


def test_every_table_the_report_compares_with_is_there() -> None:
    ref = paper_reference()
    for table in ("table2", "table3_diagnostic", "table4", "table3_ranking", "table5", "tableS1"):
        assert all(set(row) == {"8cm", "10cm", "12cm"} for row in ref[table].values()), table
    assert ref["report_wording"]["water_per_phase"]
