"""The pipeline driver: typed presets, stage order, markers, resumption, the command lines it
records, and stages run through their library calls.

Most tests replace the execution of a stage's calls by a recorder, so they take
milliseconds (and run a parallel stage's calls in this process, where the recorder is); one
runs the dataset stage through its library function on synthetic runs, one a parallel stage
in a real pool. The real chain runs on the ``tiny`` preset in CI (``make pipeline-tiny``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from rmi_learn import cli, pipeline
from rmi_learn.pipeline import Call, PipelineError, load_preset, run_pipeline
from rmi_learn.pipeline import run as run_mod
from rmi_learn.pipeline.calls import flag_words

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


REAL_POOL = run_mod.parallel_map


@pytest.fixture(autouse=True)
def _calls_in_this_process(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(run_mod, "parallel_map", lambda fn, calls, workers: list(map(fn, calls)))


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
        if cfg.control is not None:  # the optional benchmarks run before the report
            order.insert(order.index("report"), "control")
        if cfg.control_protocol is not None:
            order.insert(order.index("report"), "control-protocol")
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


def test_every_seed_of_a_preset_takes_the_engine_range(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    top = 2**63 - 1
    for stage in ("world_models", "policies", "rank", "control"):
        path.write_text(json.dumps({"grid": "tiny", stage: {"seed": top}}))
        assert getattr(load_preset(path=path), stage).given() == {"seed": top}
        path.write_text(json.dumps({"grid": "tiny", stage: {"seed": top + 1}}))
        with pytest.raises(
            ValueError, match=rf"{stage}: seed: expected an integer in \[0, {top}\]"
        ):
            load_preset(path=path)


def test_flags_follow_cli_spelling() -> None:
    assert flag_words("max_windows", 4) == ("--max-windows", "4")
    assert flag_words("debug", True) == ("--debug",)
    assert flag_words("resume", False) == flag_words("x", None) == ()
    assert flag_words("channels", (32, 64)) == ("--channels", "32,64")


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
    # A training runs on one thread whatever --threads says (its weights depend on torch's).
    assert shuffled[-6:] == ["--debug", "--epochs", "1", "--threads", "1", "--no-progress"]
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
    monkeypatch.setattr(run_mod, "execute_call", rec)
    with pytest.raises(PipelineError, match="stage rank failed"):
        run_pipeline(cfg, tmp_path, log=lambda s: None)
    done = sorted(p.stem for p in (tmp_path / "stages").glob("*.json"))
    assert done == sorted(STAGE_ORDER[: STAGE_ORDER.index("rank")])
    marker = json.loads((tmp_path / "stages" / "sweep.json").read_text())
    assert marker["commands"][0].startswith("rmi sweep --preset tiny")

    # Second call: the finished stages are skipped, the failed one and the rest run.
    rec2 = Recorder()
    monkeypatch.setattr(run_mod, "execute_call", rec2)
    run_pipeline(cfg, tmp_path, log=lambda s: None)
    assert [c[0] for c in rec2.calls] == [
        "rank",
        "closed-loop",
        "control-bench",
        "control-bench",
        "report",
    ]
    # Third call: nothing left to do.
    rec3 = Recorder()
    monkeypatch.setattr(run_mod, "execute_call", rec3)
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
    monkeypatch.setattr(run_mod, "execute_call", rec)
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
    monkeypatch.setattr(run_mod, "execute_call", Recorder())
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


def test_every_stage_runs_its_library_call_with_the_arguments_it_records(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The calls that run, stage by stage, with every library function replaced by a
    recorder: each gets what its recorded command line says."""
    import torch

    import rmi_learn.control_bench as control
    import rmi_learn.control_bench.feedback as feedback
    from rmi_learn import closed_loop
    from rmi_learn.analysis import physical
    from rmi_learn.analysis import report as reporting
    from rmi_learn.data import dataset, sweep
    from rmi_learn.planning import ranking
    from rmi_learn.policies import training as policy_training
    from rmi_learn.world_models import evaluation
    from rmi_learn.world_models import training as wm_training

    seen: list[tuple[str, tuple[Any, ...], dict[str, Any]]] = []

    def recorder(name: str) -> Any:
        return lambda *args, **kw: seen.append((name, args, kw))

    for module, attr in (
        (sweep, "sweep"),
        (dataset, "build"),
        (physical, "analyze"),
        (wm_training, "train"),
        (evaluation, "eval_wm"),
        (policy_training, "train_policy"),
        (ranking, "rank"),
        (closed_loop, "run_closed_loop"),
        (control, "run_control_bench"),
        (feedback, "run_protocol_bench"),
        (reporting, "write_report"),
    ):
        monkeypatch.setattr(module, attr, recorder(attr))
    monkeypatch.setattr(torch, "set_num_threads", lambda n: seen.append(("threads", (n,), {})))
    (tmp_path / "policy" / "flow").mkdir(parents=True)
    (tmp_path / "policy" / "flow" / "config.json").write_text("{}")
    markers = run_pipeline(load_preset("tiny"), tmp_path, threads=3, log=lambda s: None)

    calls = [c for c in seen if c[0] != "threads"]
    assert [c[0] for c in calls] == (
        ["sweep", "build", "analyze"]
        + ["train"] * (len(pipeline.MAIN_MODELS) + len(pipeline.SCORER_MODELS))
        + ["train"] * len(pipeline.ABLATION_MODELS)
        + ["eval_wm", "train_policy", "train_policy", "rank", "run_closed_loop"]
        + ["run_control_bench", "run_protocol_bench", "write_report"]
    )
    # torch's threads are set before each call that runs torch: one for a training, --threads
    # for the evaluation, the ranking and the benchmark.
    before = {c[0]: [seen[i - 1] for i, s in enumerate(seen) if s[0] == c[0]] for c in calls}
    for name, n in (("train", 1), ("train_policy", 1), ("eval_wm", 3), ("rank", 3)):
        assert before[name] and all(b == ("threads", (n,), {}) for b in before[name]), name
    by_name = {c[0]: c for c in calls}
    t = tmp_path
    assert by_name["sweep"][1:] == (
        (t / "sweep",),
        {"preset": "tiny", "workers": 2, "threads_per_run": 1},
    )
    assert by_name["build"][1:] == ((t / "sweep" / "runs", t / "dataset"), {})
    assert by_name["analyze"][1:] == ((t / "sweep", t / "analysis"), {})
    _, runs, kw = by_name["eval_wm"]
    assert runs[1:] == (t / "dataset", t / "tables" / "wm")
    assert kw == {"latency": False, "max_windows": 64}
    assert len(runs[0]) == 11 and all(isinstance(r, str) for r in runs[0])
    policies = [c for c in calls if c[0] == "train_policy"]
    assert [p[1] for p in policies] == [
        ("diffusion", t / "dataset", t / "policy" / "diffusion"),
        ("flow", t / "dataset", t / "policy" / "flow"),
    ]
    assert [p[2] for p in policies] == [
        {"debug": True, "epochs": 1, "progress": False, "resume": resume}
        for resume in (False, True)
    ]
    assert by_name["rank"][1:] == (
        (t / "dataset", t / "wm" / "transformer", t / "tables" / "rank"),
        {"diffusion": t / "policy" / "diffusion", "flow": t / "policy" / "flow", "max_windows": 4},
    )
    _, args, kw = by_name["run_closed_loop"]
    assert args == (t / "sweep", t / "tables" / "rank", t / "closed_loop")
    assert kw.pop("log") is not None and kw == {"max_windows": 1, "threads": 3}
    _, args, kw = by_name["run_control_bench"]
    assert args == () and kw.pop("log") is not None
    assert kw == {
        "runs": t / "sweep",
        "data": t / "dataset",
        "wm": t / "wm",
        "policy": t / "policy",
        "out": t / "control",
        "states_per_size": 1,
        "goals_per_state": 1,
        "setpoints": 2,
        "k": 2,
        "receding": 16,
        "threads": 3,
        "progress": False,
    }
    _, args, kw = by_name["run_protocol_bench"]
    assert args == () and kw.pop("log") is not None
    assert kw == {
        "protocol": "tiny",
        "runs": t / "sweep",
        "out": t / "control_protocol",
        "workers": 2,
        "threads": 1,
        "replace_other": True,
    }
    assert by_name["write_report"][1:] == ((t,), {})
    # The markers record the command lines of those calls.
    assert markers["policies"]["commands"][1].endswith("--no-progress --resume")
    assert markers["control"]["commands"] == [
        f"rmi control-bench --runs {t / 'sweep'} --data {t / 'dataset'} --wm {t / 'wm'} "
        f"--policy {t / 'policy'} --out {t / 'control'} --states-per-size 1 "
        "--goals-per-state 1 --setpoints 2 --k 2 --receding 16 --threads 3 --no-progress"
    ]
    assert markers["control-protocol"]["commands"] == [
        f"rmi control-bench --protocol tiny --runs {t / 'sweep'} "
        f"--out {t / 'control_protocol'} --workers 2 --threads 1 --replace-other"
    ]


def test_list_options_of_the_benchmark_are_text_on_the_command_line_and_lists_in_the_call(
    tmp_path: Path,
) -> None:
    cfg = load_preset("control")
    (bench,) = {s.name: s for s in pipeline.build_stages(cfg, tmp_path, threads=2)}[
        "control"
    ].calls()
    assert bench.argv[bench.argv.index("--refine-scorers") + 1] == "arx-32,arx-32c"
    passed = {a.param: a.value for a in bench.args if a.kind == "keyword"}
    assert passed["refine_scorers"] == ["arx-32", "arx-32c"]
    assert passed["receding_scorers"] == ["wt", "arx-32"]


def test_seeds_replicate_the_learned_table_ii_models_with_their_own_seed(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"grid": "tiny", "seeds": 3, "world_models": {"seed": 5}}))
    stages = {s.name: s for s in pipeline.build_stages(load_preset(path=path), tmp_path, 1)}

    def runs(stage: str) -> dict[str, list[str]]:
        return {Path(c.argv[c.argv.index("--out") + 1]).name: c.argv for c in
                stages[stage].calls()}  # fmt: skip

    main, ablations = runs("world-models"), runs("ablations")
    for name in ("state-gru", "ac-gru"):
        replicates = {n for n in main if n.startswith(name + "-seed")}
        assert replicates == {f"{name}-seed6", f"{name}-seed7"}
    assert {"ac-gru-shuffled-seed6", "ac-gru-shuffled-seed7"} <= set(ablations)
    assert not any("seed" in n for n in ablations if not n.startswith("ac-gru-shuffled"))
    for name, argv in {**main, **ablations}.items():
        seed = name.rsplit("-seed", 1)[1] if "-seed" in name else "5"
        assert argv.count("--seed") == 1 and argv[argv.index("--seed") + 1] == seed, name
    assert "--shuffle-actions" in ablations["ac-gru-shuffled-seed7"]
    (ev,) = stages["eval-wm"].calls()
    listed = {Path(a).name for a in ev.argv if a.startswith(str(tmp_path / "wm"))}
    assert {"ac-gru-seed6", "state-gru-seed7", "ac-gru-shuffled-seed6"} <= listed
    assert "arx-32" not in listed  # the scorers are not table rows
    for bad in (0, 11, "3", True, 2.0):
        path.write_text(json.dumps({"grid": "tiny", "seeds": bad}))
        with pytest.raises(ValueError, match="seeds must be a whole number from 1 to 10"):
            load_preset(path=path)


def test_a_parallel_stage_runs_its_calls_in_a_pool_and_names_the_one_that_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import shutil

    from rmi_learn.pipeline.calls import call, positional
    from rmi_learn.pipeline.stages import Stage

    monkeypatch.setattr(run_mod, "parallel_map", REAL_POOL)
    src = tmp_path / "a.txt"
    src.write_text("x")

    def copy(dst: str, source: Path = src) -> Call:
        return call("copy", shutil.copyfile, positional("--src", source), positional("--to", dst))

    calls = [copy(str(tmp_path / f"{i}.txt")) for i in range(3)]
    run_mod._run_calls(Stage("s", "", lambda: calls, parallel=True), calls, 2, lambda s: None)
    assert [(tmp_path / f"{i}.txt").read_text() for i in range(3)] == ["x"] * 3
    bad = [copy(str(tmp_path / "b.txt")), copy(str(tmp_path / "c.txt"), tmp_path / "missing")]
    with pytest.raises(PipelineError, match="stage s failed .* running: rmi copy --src .*missing"):
        run_mod._run_calls(Stage("s", "", lambda: bad, parallel=True), bad, 2, lambda s: None)
    # The call that did not fail finished beside it.
    assert (tmp_path / "b.txt").read_text() == "x"
