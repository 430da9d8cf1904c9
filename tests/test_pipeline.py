"""The pipeline driver (stage order, markers, resumption, preset checks) and the report.

The driver is tested with the subcommands replaced by a recorder, so these tests take
milliseconds; the real chain runs on the ``tiny`` preset in CI (``make pipeline-tiny``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from rmi_learn import cli, pipeline
from rmi_learn.analysis.report import Doc, write_report
from rmi_learn.pipeline import PipelineError, load_preset, run_pipeline

STAGE_ORDER = [
    "sweep",
    "dataset",
    "analysis",
    "world-models",
    "ablations",
    "eval-wm",
    "policies",
    "rank",
    "closed-loop",
    "report",
]


class Recorder:
    """Stands in for ``cli.main``: records argv and fails on a chosen subcommand."""

    def __init__(self, fail_on: str | None = None) -> None:
        self.calls: list[list[str]] = []
        self.fail_on = fail_on

    def __call__(self, argv: list[str]) -> int:
        self.calls.append(argv)
        return 1 if argv[0] == self.fail_on else 0


def test_presets_load_and_name_every_stage(tmp_path: Path) -> None:
    for name in pipeline.PRESETS:
        cfg = load_preset(name)
        stages = pipeline.build_stages(cfg, tmp_path, threads=2)
        assert [s.name for s in stages] == STAGE_ORDER
        # Every stage's command lines parse with the real CLI (no typo in a preset option).
        parser = cli.build_parser()
        for stage in stages:
            for argv in stage.commands():
                parser.parse_args(argv)


def test_bad_presets_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown pipeline preset"):
        load_preset("huge")
    bad = tmp_path / "p.json"
    bad.write_text(json.dumps({"grid": "tiny", "polices": {}}))
    with pytest.raises(ValueError, match="unknown keys.*polices"):
        load_preset(path=bad)
    bad.write_text(json.dumps({"sweep": {}}))
    with pytest.raises(ValueError, match="missing key 'grid'"):
        load_preset(path=bad)
    bad.write_text(json.dumps({"grid": "tiny", "rank": 3}))
    with pytest.raises(ValueError, match="rank must be an object"):
        load_preset(path=bad)
    assert cli.main(["pipeline", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2


def test_flags_follow_cli_spelling() -> None:
    assert pipeline._flags({"max_windows": 4, "debug": True, "resume": False, "x": None}) == [
        "--max-windows",
        "4",
        "--debug",
    ]


def test_failed_stage_resumes_where_it_stopped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = load_preset("tiny")
    rec = Recorder(fail_on="rank")
    monkeypatch.setattr(cli, "main", rec)
    with pytest.raises(PipelineError, match="stage rank failed"):
        run_pipeline(cfg, tmp_path, log=lambda s: None)
    done = sorted(p.stem for p in (tmp_path / "stages").glob("*.json"))
    assert done == sorted(STAGE_ORDER[: STAGE_ORDER.index("rank")])
    marker = json.loads((tmp_path / "stages" / "sweep.json").read_text())
    assert marker["commands"][0].startswith("rmi sweep --preset tiny")

    # Second call: the finished stages are skipped, the failed one and the rest run.
    rec2 = Recorder()
    monkeypatch.setattr(cli, "main", rec2)
    run_pipeline(cfg, tmp_path, log=lambda s: None)
    assert [c[0] for c in rec2.calls] == ["rank", "closed-loop", "report"]
    # Third call: nothing left to do.
    rec3 = Recorder()
    monkeypatch.setattr(cli, "main", rec3)
    run_pipeline(cfg, tmp_path, log=lambda s: None)
    assert rec3.calls == []
    # --redo forgets a marker; --only restricts.
    run_pipeline(cfg, tmp_path, only=["report"], redo=["report"], log=lambda s: None)
    assert [c[0] for c in rec3.calls] == ["report"]


def test_interrupted_training_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_preset("tiny")
    (tmp_path / "wm" / "ac-gru").mkdir(parents=True)
    (tmp_path / "wm" / "ac-gru" / "config.json").write_text("{}")
    rec = Recorder()
    monkeypatch.setattr(cli, "main", rec)
    run_pipeline(cfg, tmp_path, only=["world-models"], log=lambda s: None)
    by_out = {c[c.index("--out") + 1]: c for c in rec.calls}
    assert "--resume" in by_out[str(tmp_path / "wm" / "ac-gru")]
    assert "--resume" not in by_out[str(tmp_path / "wm" / "transformer")]


def test_out_dir_is_tied_to_its_preset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cli, "main", Recorder())
    run_pipeline(load_preset("tiny"), tmp_path, only=["sweep"], log=lambda s: None)
    with pytest.raises(ValueError, match="another pipeline preset"):
        run_pipeline(load_preset("quick"), tmp_path, only=["sweep"], log=lambda s: None)
    with pytest.raises(ValueError, match="unknown stage"):
        run_pipeline(load_preset("tiny"), tmp_path, only=["train"], log=lambda s: None)


def test_report_of_an_empty_directory_says_what_is_missing(tmp_path: Path) -> None:
    md, page = write_report(tmp_path)
    text = md.read_text()
    for stage in ("sweep", "analysis", "eval-wm", "rank", "closed-loop"):
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
    from rmi_learn.analysis.report import _closed_loop_means

    cl = json.loads((tmp_path / "closed_loop" / "table_closed_loop.json").read_text())
    assert _closed_loop_means(cl) == {
        "Original controller action": {"8": 0.5},
        "Flow matching + W_T": {"8": 2.0},
    }
    assert (tmp_path / "report" / "figures" / "fig_ranking.png").stat().st_size > 1000
    assert 'class="paper"' in page.read_text()


def test_doc_escapes_html() -> None:
    d = Doc()
    d.h(1, "t")
    d.p("a <b> & `x<y`")
    d.table(["h"], [["<i>"]])
    page = d.html("t")
    assert "a &lt;b&gt; &amp; <code>x&lt;y</code>" in page and "<td>&lt;i&gt;</td>" in page
