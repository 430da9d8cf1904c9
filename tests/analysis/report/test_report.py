"""The report of a pipeline directory (``rmi report``): sections of stages that have not
run, our numbers beside the paper's, the training curves, the embedded figures."""

from __future__ import annotations

import base64
import json
import math
import struct
from pathlib import Path
from typing import Any

from rmi_learn import cli
from rmi_learn.analysis.report import training_figure, training_runs, write_report
from rmi_learn.analysis.report.policies import closed_loop_means
from rmi_learn.metrics_log import loss_curves


def test_report_of_an_empty_directory_says_what_is_missing(tmp_path: Path) -> None:
    md, page = write_report(tmp_path)
    text = md.read_text()
    for stage in ("sweep", "analysis", "eval-wm", "rank", "world-models", "closed-loop"):
        assert f"stage `{stage}` has not run" in text
    html = page.read_text()
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    assert "<nav>" in html
    assert cli.main(["report", "--out", str(tmp_path / "nope")]) == 2


def _write(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def test_report_puts_our_numbers_beside_the_papers(tmp_path: Path) -> None:
    rows = [
        {"method": "Original controller action", "8": 1.5, "10": None, "12": 3.25},
        {"method": "Flow matching + W_T", "8": 0.75, "10": None, "12": None},
    ]
    _write(tmp_path / "tables" / "rank" / "table3_ranking.json", {"rows": rows, "k": 8})
    _write(
        tmp_path / "closed_loop" / "table_closed_loop.json",
        {"sizes": {"8": {"original": {"real_g": 0.5}, "flow": {"selected_real_g": 2.0}}}},
    )
    (tmp_path / "closed_loop" / "table_closed_loop.md").write_text(
        "**Closed loop**\n\n| size | first (g) | selected (g) |\n|---|---|---|\n"
        "| 8 cm | 4.00 | 2.00 |\n\nReplay fidelity: fine.\n"
    )
    md, page = write_report(tmp_path)
    text = md.read_text()
    assert "| Original controller action | 1.50 | – | 3.25 |" in text
    assert "| paper: Original controller action | 2.56 | 4.23 | 4.68 |" in text
    assert "| paper: Flow matching + W_T | 1.11 | 2.24 | 2.45 |" in text
    assert "| 8 cm | 4.00 | 2.00 |" in text and "Replay fidelity: fine." in text
    cl = json.loads((tmp_path / "closed_loop" / "table_closed_loop.json").read_text())
    assert closed_loop_means(cl) == {
        "Original controller action": {"8": 0.5},
        "Flow matching + W_T": {"8": 2.0},
    }
    assert (tmp_path / "report" / "figures" / "fig_ranking.png").stat().st_size > 1000
    assert 'class="paper"' in page.read_text()


def test_a_ranking_by_another_scorer_is_named_and_its_claim_checked(tmp_path: Path) -> None:
    rows = [
        {"method": "Flow matching, first sample", "8": 2.0, "10": None, "12": None},
        {"method": "Flow matching + AC-GRU-WM", "8": 0.75, "10": None, "12": None},
    ]
    t3 = {"rows": rows, "k": 8, "scorer_name": "AC-GRU-WM"}
    _write(tmp_path / "tables" / "rank" / "table3_ranking.json", t3)
    flow = {"first_real_g": 4.0, "selected_real_g": 2.0}
    _write(tmp_path / "closed_loop" / "table_closed_loop.json", {"sizes": {"8": {"flow": flow}}})
    md, _ = write_report(tmp_path)
    text = md.read_text()
    assert "### Table III: AC-GRU-WM-predicted terminal water error (g)" in text
    assert "| Flow matching | holds: 0.38; executed 2.0 vs 4.0 g | – | – |" in text
    assert "AC-GRU-WM-selected chunk" in text


def test_report_shows_the_goal_reaching_benchmark_when_it_ran(tmp_path: Path) -> None:
    md, _ = write_report(tmp_path)
    assert "Goal-reaching control" not in md.read_text()  # a preset without the stage
    ctrl = tmp_path / "control"
    ctrl.mkdir()
    (ctrl / "table_control.md").write_text(
        "**Goal-reaching benchmark**\n\n| Controller | n | median |\n|---|---:|---:|\n"
        "| refined-arx-32/flow | 4 | 1.25 |\n"
    )
    (ctrl / "fig_control.png").write_bytes(b"\x89PNG fake")
    md, _ = write_report(tmp_path)
    text = md.read_text()
    assert "Goal-reaching control" in text and "| refined-arx-32/flow | 4 | 1.25 |" in text
    assert "figures/fig_control.png" in text and "fig_control_scorers" not in text
    assert (tmp_path / "report" / "figures" / "fig_control.png").exists()


def png_size(path: Path) -> tuple[int, int]:
    """Width and height (pixels) from a PNG's header."""
    width, height = struct.unpack(">II", path.read_bytes()[16:24])
    return int(width), int(height)


def test_report_draws_the_training_curves_of_tiny_runs(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    data = str(synthetic_dataset_dir)
    quiet = ["--debug", "--no-progress", "--threads", "1"]
    for model, extra in (("ac-mlp", ["--model-arg", "hidden=16"]), ("arx", [])):
        out = tmp_path / "wm" / model
        assert (
            cli.main(
                ["train-wm", "--model", model, "--data", data, "--out", str(out)] + quiet + extra
            )
            == 0
        )
    policy = tmp_path / "policy" / "flow"
    argv = ["train-policy", "--objective", "flow", "--data", data, "--out", str(policy)]
    assert cli.main(argv + quiet + ["--channels", "8,16"]) == 0

    for run in (tmp_path / "wm" / "ac-mlp", policy):
        curves = loss_curves(run)
        assert curves["epoch"] == [1.0, 2.0]  # debug mode: two epochs
        assert all(math.isfinite(v) and v > 0 for v in curves["train_loss"] + curves["val_loss"])
    assert loss_curves(tmp_path / "wm" / "arx") == {}  # fitted in closed form: no curve
    assert [label for label, _ in training_runs(tmp_path)] == [
        "world model ac-mlp",
        "world model arx",
        "policy flow",
    ]

    md, page = write_report(tmp_path)
    fig = tmp_path / "report" / "figures" / "fig_training.png"
    assert "](figures/fig_training.png)" in md.read_text()
    assert base64.b64encode(fig.read_bytes()).decode() in page.read_text()  # embedded
    # Two panels side by side (3.3 in each at 120 dpi): ARX has none.
    assert png_size(fig) == (792, 312)
    only_arx = tmp_path / "arx.png"
    assert not training_figure([("arx", tmp_path / "wm" / "arx")], only_arx)
    assert not only_arx.exists()


def test_report_html_embeds_its_figures(tmp_path: Path) -> None:
    """report.html is one file: every figure is a data URI holding the PNG written beside
    report.md, and no image is linked by a relative path."""
    import base64
    import re

    rows = [{"method": "Original controller action", "8": 1.5, "10": 2.0, "12": 3.25}]
    _write(tmp_path / "tables" / "rank" / "table3_ranking.json", {"rows": rows, "k": 8})
    md, page = write_report(tmp_path)
    sources = re.findall(r'<img src="([^"]*)"', page.read_text())
    assert sources, "the report should hold the ranking figure"
    assert all(src.startswith("data:image/png;base64,") for src in sources), sources
    png = (tmp_path / "report" / "figures" / "fig_ranking.png").read_bytes()
    embedded = [base64.b64decode(src.split(",", 1)[1]) for src in sources]
    assert png in embedded
    # The Markdown report keeps linking the figure files beside it.
    assert "](figures/fig_ranking.png)" in md.read_text()


def test_report_says_which_table_ii_findings_hold_with_the_range_over_seeds(
    tmp_path: Path,
) -> None:
    def rec(kind: str, size: int, *water: float, shuffled: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": kind, "state_groups": "ALL", "shuffled": shuffled,
                               "size_cm": size, "method": kind, "params": 0,
                               "metrics": {"water_mae_g@32": sum(water) / len(water)}}  # fmt: skip
        if len(water) > 1:
            out["metrics_per_seed"] = [{"water_mae_g@32": w} for w in water]
        return out

    results = [
        rec("baseline", 8, 10.0),
        rec("ac-gru", 8, 4.0, 5.0, 6.0),
        rec("baseline", 12, 9.0),
        rec("ac-gru", 12, 8.0, 9.5, 11.0),
    ]
    _write(tmp_path / "tables" / "wm" / "results.json", results)
    md, _ = write_report(tmp_path)
    text = md.read_text()
    assert "| AC-GRU-WM below the Baseline (persistence) | holds: 5.0 [4.0, 6.0] vs 10.0 | – " \
        "| does not hold: 9.5 [8.0, 11.0] vs 9.0 |" in text  # fmt: skip
    assert "Not on these data: AC-GRU-WM below the Baseline (persistence) on the 12 cm " \
        "sponge (9.5 g against 9.0 g)." in text  # fmt: skip


def test_report_checks_the_ranking_claim_and_puts_the_executed_errors_beside_it(
    tmp_path: Path,
) -> None:
    rows = [
        {"method": "Flow matching, first sample", "8": 4.0, "10": 4.0, "12": None},
        {"method": "Flow matching + W_T", "8": 1.5, "10": 3.0, "12": 1.0},
    ]
    _write(tmp_path / "tables" / "rank" / "table3_ranking.json", {"rows": rows, "k": 8})
    _write(
        tmp_path / "closed_loop" / "table_closed_loop.json",
        {"sizes": {"8": {"flow": {"first_real_g": 3.0, "selected_real_g": 5.5}}}},
    )
    text = write_report(tmp_path)[0].read_text()
    row = "| Flow matching | holds: 0.38; executed 5.5 vs 3.0 g | does not hold: 0.75 | – |"
    assert row in text
