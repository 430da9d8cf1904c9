"""The pipeline driver: typed presets, stage order, markers, resumption, the command lines it
records, and stages run through their library calls.

Most tests replace the execution of a stage's calls by a recorder, so they take
milliseconds; one runs the dataset stage through its library function on synthetic runs.
The real chain runs on the ``tiny`` preset in CI (``make pipeline-tiny``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from rmi_learn import cli, pipeline
from rmi_learn.pipeline import Call, PipelineError, load_preset, run_pipeline
from rmi_learn.pipeline import stages as stages_mod

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
    """Stands in for the execution of a stage's calls: records each call's command line and
    fails (exit status 1) on a chosen command."""

    def __init__(self, fail_on: str | None = None) -> None:
        self.calls: list[list[str]] = []
        self.fail_on = fail_on

    def __call__(self, call: Call, threads: int) -> int:
        self.calls.append(call.argv)
        return 1 if call.argv[0] == self.fail_on else 0


def test_presets_load_and_name_every_stage(tmp_path: Path) -> None:
    for name in pipeline.PRESETS:
        cfg = load_preset(name)
        stages = pipeline.build_stages(cfg, tmp_path, threads=2)
        order = list(STAGE_ORDER)
        if cfg.control is not None:  # the optional benchmark runs before the report
            order.insert(order.index("report"), "control")
        if not cfg.ablations:
            order.remove("ablations")
        assert [s.name for s in stages] == order
        # Every stage's recorded command lines parse with the real CLI (a user can type them).
        parser = cli.build_parser()
        for stage in stages:
            for call in stage.calls():
                parser.parse_args(call.argv)


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


def test_stage_options_are_checked_like_the_commands_arguments(tmp_path: Path) -> None:
    bad = tmp_path / "p.json"
    for options, message in (
        ({"rank": {"max_windowz": 4}}, "rank: unknown options.*max_windowz"),
        ({"policies": {"epochs": 0}}, r"policies: epochs: expected an integer in \[1, \d+\]"),
        ({"world_models": {"epochs": "3"}}, "epochs must be of type int"),
        ({"world_models": {"debug": 1}}, "debug must be of type bool"),
        ({"eval": {"max_windows": True}}, "max_windows must be of type int"),
        ({"policies": {"ema_decay": 1.0}}, "ema_decay: expected a finite number in"),
    ):
        bad.write_text(json.dumps({"grid": "tiny", **options}))
        with pytest.raises(ValueError, match=message):
            load_preset(path=bad)
    assert cli.main(["pipeline", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    # A preset option keeps its command's spelling in the typed config.
    cfg = load_preset("tiny")
    assert cfg.rank.given() == {"max_windows": 4}
    assert cfg.eval.given() == {"max_windows": 64, "latency": False}
    assert cfg.raw == json.loads(
        (Path(pipeline.__file__).parent / "presets" / "tiny.json").read_text()
    )


def test_flags_follow_cli_spelling() -> None:
    assert stages_mod._flags({"max_windows": 4, "debug": True, "resume": False, "x": None}) == [
        "--max-windows",
        "4",
        "--debug",
    ]
    assert stages_mod._flags({"channels": (32, 64)}) == ["--channels", "32,64"]


def test_recorded_command_lines(tmp_path: Path) -> None:
    stages = {s.name: s for s in pipeline.build_stages(load_preset("tiny"), tmp_path, threads=3)}
    (sweep,) = stages["sweep"].calls()
    assert sweep.argv == [
        "sweep",
        "--preset",
        "tiny",
        "--out",
        str(tmp_path / "sweep"),
        "--workers",
        "2",
        "--threads-per-run",
        "1",
    ]
    wm = {c.argv[c.argv.index("--out") + 1]: c.argv for c in stages["ablations"].calls()}
    shuffled = wm[str(tmp_path / "wm" / "ac-gru-shuffled")]
    assert shuffled[:4] == ["train-wm", "--model", "ac-gru", "--shuffle-actions"]
    assert shuffled[-6:] == ["--debug", "--epochs", "1", "--threads", "3", "--no-progress"]
    groups = wm[str(tmp_path / "wm" / "ac-gru-LS+G")]
    assert groups[:5] == ["train-wm", "--model", "ac-gru", "--state-groups", "LS+G"]
    (ev,) = stages["eval-wm"].calls()
    assert ev.argv[-5:] == ["--max-windows", "64", "--threads", "3", "--no-latency"]
    assert len([a for a in ev.argv if a.startswith(str(tmp_path / "wm"))]) == 11
    (cl,) = stages["closed-loop"].calls()
    assert cl.argv[-4:] == ["--max-windows", "1", "--threads", "3"]
    assert [c.torch for s in ("world-models", "policies", "rank") for c in stages[s].calls()] == [
        True
    ] * 10
    main_wm = {c.argv[c.argv.index("--out") + 1]: c.argv for c in stages["world-models"].calls()}
    arx32 = main_wm[str(tmp_path / "wm" / "arx-32")]
    assert arx32[:5] == ["train-wm", "--model", "arx", "--model-arg", "horizon=32"]
    causal = main_wm[str(tmp_path / "wm" / "arx-32c")]
    assert causal[:7] == [*arx32[:5], "--model-arg", "causal=true"]


def test_a_grid_preset_without_a_pipeline_preset_is_named_not_read_as_a_file(
    tmp_path: Path,
) -> None:
    cfg = dataclasses.replace(load_preset("paper"), grid="paper-fine")
    (sweep,) = {s.name: s for s in pipeline.build_stages(cfg, tmp_path, threads=2)}["sweep"].calls()
    assert sweep.argv[:3] == ["sweep", "--preset", "paper-fine"]


def test_failed_stage_resumes_where_it_stopped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = load_preset("tiny")
    rec = Recorder(fail_on="rank")
    monkeypatch.setattr(stages_mod, "_execute", rec)
    with pytest.raises(PipelineError, match="stage rank failed"):
        run_pipeline(cfg, tmp_path, log=lambda s: None)
    done = sorted(p.stem for p in (tmp_path / "stages").glob("*.json"))
    assert done == sorted(STAGE_ORDER[: STAGE_ORDER.index("rank")])
    marker = json.loads((tmp_path / "stages" / "sweep.json").read_text())
    assert marker["commands"][0].startswith("rmi sweep --preset tiny")

    # Second call: the finished stages are skipped, the failed one and the rest run.
    rec2 = Recorder()
    monkeypatch.setattr(stages_mod, "_execute", rec2)
    run_pipeline(cfg, tmp_path, log=lambda s: None)
    assert [c[0] for c in rec2.calls] == ["rank", "closed-loop", "control-bench", "report"]
    # Third call: nothing left to do.
    rec3 = Recorder()
    monkeypatch.setattr(stages_mod, "_execute", rec3)
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
    monkeypatch.setattr(stages_mod, "_execute", rec)
    run_pipeline(cfg, tmp_path, only=["world-models"], log=lambda s: None)
    by_out = {c[c.index("--out") + 1]: c for c in rec.calls}
    assert "--resume" in by_out[str(tmp_path / "wm" / "ac-gru")]
    assert "--resume" not in by_out[str(tmp_path / "wm" / "transformer")]


def test_training_calls_resume_through_the_library(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from rmi_learn.world_models import training

    seen: dict[str, dict[str, Any]] = {}

    def fake_train(**kw: Any) -> dict[str, Any]:
        seen[Path(kw["out"]).name] = kw
        return {}

    monkeypatch.setattr(training, "train", fake_train)
    (tmp_path / "wm" / "ac-gru").mkdir(parents=True)
    (tmp_path / "wm" / "ac-gru" / "config.json").write_text("{}")
    run_pipeline(load_preset("tiny"), tmp_path, only=["world-models"], log=lambda s: None)
    assert sorted(seen) == sorted({**pipeline.MAIN_MODELS, **pipeline.SCORER_MODELS})
    assert seen["arx-32"]["model"] == "arx" and seen["arx-32"]["model_args"] == {"horizon": 32}
    assert seen["arx-32c"]["model_args"] == {"horizon": 32, "causal": True}
    assert seen["ac-gru"]["resume"] and not seen["transformer"]["resume"]
    assert seen["arx"] == {
        "model": "arx",
        "data": tmp_path / "dataset",
        "out": tmp_path / "wm" / "arx",
        "state_groups": "ALL",
        "shuffle_actions": False,
        "model_args": None,
        "resume": False,
        "progress": False,
        "debug": True,
        "epochs": 1,
    }
    # The preset's order of the options is kept in the recorded command lines.
    assert list(load_preset("tiny").world_models.given()) == ["debug", "epochs"]


def test_out_dir_is_tied_to_its_preset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(stages_mod, "_execute", Recorder())
    run_pipeline(load_preset("tiny"), tmp_path, only=["sweep"], log=lambda s: None)
    assert json.loads((tmp_path / "pipeline.json").read_text()) == load_preset("tiny").raw
    with pytest.raises(ValueError, match="another pipeline preset"):
        run_pipeline(load_preset("quick"), tmp_path, only=["sweep"], log=lambda s: None)
    with pytest.raises(ValueError, match="unknown stage"):
        run_pipeline(load_preset("tiny"), tmp_path, only=["train"], log=lambda s: None)


def test_a_stage_runs_through_its_library_call(
    tmp_path: Path,
    synthetic_runs_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The sweep stage calls ``rmi_learn.data.sweep.sweep`` with the preset's options (here
    replaced by a copy of synthetic runs), the dataset stage builds the real dataset through
    ``rmi_learn.data.dataset.build``, and each stage records the command line that does the
    same. An input error in a stage fails it like its command: one line, exit status 2."""
    import shutil

    from rmi_learn.data import sweep

    calls: list[tuple[Path, dict[str, Any]]] = []

    def fake_sweep(out: Path, **kw: Any) -> None:
        calls.append((out, kw))
        shutil.copytree(synthetic_runs_dir, out / "runs")

    monkeypatch.setattr(sweep, "sweep", fake_sweep)
    out = tmp_path / "out"
    markers = run_pipeline(load_preset("tiny"), out, only=["sweep", "dataset"], log=lambda s: None)
    assert calls == [(out / "sweep", {"preset": "tiny", "workers": 2, "threads_per_run": 1})]
    info = json.loads((out / "dataset" / "dataset.json").read_text())
    assert info["counts"]["kept"] > 0
    assert markers["dataset"]["commands"] == [
        f"rmi dataset build --runs {out / 'sweep' / 'runs'} --out {out / 'dataset'}"
    ]
    assert json.loads((out / "stages" / "dataset.json").read_text()) == markers["dataset"]

    # The dataset stage on a run tree without runs: `rmi dataset`'s input error.
    empty = tmp_path / "empty"
    monkeypatch.setattr(sweep, "sweep", lambda out, **kw: (out / "runs").mkdir(parents=True))
    capsys.readouterr()
    with pytest.raises(PipelineError, match="stage dataset failed \\(exit 2\\)"):
        run_pipeline(load_preset("tiny"), empty, only=["sweep", "dataset"], log=lambda s: None)
    err = capsys.readouterr().err
    assert err.startswith("rmi dataset: ") and len(err.strip().splitlines()) == 1
    assert cli.main(["pipeline", "--preset", "tiny", "--out", str(empty)]) == 1
    assert "run the same command again" in capsys.readouterr().err
