"""A trained policy as one object: the run directory acts on its own (statistics and world
model inside), raw physical histories in, physical chunks out, the same chunks as the
project's sampling and ranking paths, and the example that drives the Gymnasium environment.

A tiny debug policy on the synthetic toy data (numbers mean nothing physically)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import rmi_learn.planning as planning
from rmi_learn.data.dataset import load_dataset
from rmi_learn.data.schema import FORCE_LIMIT_N, OBS
from rmi_learn.errors import InputError
from rmi_learn.planning.cost import clip_forces
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.policy import Policy, load_policy, observation_row
from rmi_learn.planning.scorers import world_model_scorer
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.policies import checkpoint
from rmi_learn.policies.policy import STORED, WORLD_MODEL_DIR, attach_world_model, parse_stats
from rmi_learn.trainer import save_weights
from rmi_learn.world_models import build
from rmi_learn.world_models import load as load_world_model
from script_module import load_script
from tiny_trial import tiny_config

torch.set_num_threads(1)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "policy_in_env.py"
GRU_SPEC = {"kind": "ac-gru", "hidden": 16, "u_embed": 8}


def _wm_run(path: Path, stats: dict[str, Any], spec: dict[str, Any] = GRU_SPEC) -> Path:
    """An (untrained) world-model run recording ``stats``."""
    torch.manual_seed(11)
    wm = build(spec)
    path.mkdir(parents=True)
    cfg = {"model": wm.config(), "extra": {"stats": stats}}
    (path / "config.json").write_text(json.dumps(cfg))
    save_weights(wm.state_dict(), path / "model.safetensors")
    return path


@pytest.fixture(scope="module")
def runs(synthetic_dataset_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A flow policy trained with a world model on a private copy of the dataset, then moved
    and the copy deleted: nothing outside the run directory is left to read."""
    from rmi_learn.policies.training import train_policy

    root = tmp_path_factory.mktemp("policy-object")
    data = root / "dataset"
    shutil.copytree(synthetic_dataset_dir, data)
    stats = load_dataset(data).stats.to_json()
    wm = _wm_run(root / "wm", stats)
    summary = train_policy("flow", data, root / "trained", channels=(8, 16, 32), debug=True,
                           progress=False, val_windows=16, wm=wm)  # fmt: skip
    assert Path(summary["world_model"]) == root / "trained" / WORLD_MODEL_DIR
    moved = root / "elsewhere" / "policy"
    moved.parent.mkdir()
    shutil.move(root / "trained", moved)
    shutil.rmtree(data)
    shutil.rmtree(wm)
    return {"run": moved, "root": root, "stats": stats}


@pytest.fixture(scope="module")
def window(synthetic_dataset_dir: Path) -> dict[str, Any]:
    """One validation window: its raw physical history, the dataset's standardised one,
    and the collected M_L at the end of its chunk (kg)."""
    ds = load_dataset(synthetic_dataset_dir)
    ws = ds.windows("val", history=16, horizon=32)
    i = len(ws) // 2
    anchor = int(ws.anchors[i])
    raw = ds.frames.select(OBS).to_numpy().astype(np.float64)
    b = ws.batch([i])
    goal = float(raw[anchor + 32, OBS.index("M_L")])
    return {"raw": raw[anchor - 15 : anchor + 1], "batch": b, "goal": goal, "stats": ds.stats}


def test_the_moved_run_acts_without_its_dataset(
    runs: dict[str, Any], window: dict[str, Any]
) -> None:
    run = runs["run"]
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["extra"]["stats"] == runs["stats"]  # the normaliser travels with the weights
    assert not Path(cfg["extra"]["data"]).exists()
    assert (run / WORLD_MODEL_DIR / "model.safetensors").is_file()

    policy = load_policy(run)
    assert isinstance(policy, Policy) and not policy.ranked
    assert policy.action_names == tuple(runs["stats"]["u_names"])
    assert policy.history_length == 16 and policy.horizon == 32
    raw = window["raw"]
    assert np.isnan(raw).any()  # v_res is undefined without contact
    chunk = policy.act(raw, window["goal"])
    assert chunk.shape == (32, len(policy.action_names)) and chunk.dtype == np.float32
    assert np.all(np.isfinite(chunk))
    force = chunk[:, policy.action_names.index("F_target")]
    assert np.all((0.0 <= force) & (force <= FORCE_LIMIT_N))
    # The raw history standardises exactly as the dataset's window.
    hist, mask = policy.standardise(raw)
    assert torch.equal(hist, window["batch"]["hist"]) and torch.equal(
        mask, window["batch"]["hist_mask"]
    )

    # Deterministic for a seed: a second load, and reset(), repeat the decisions.
    again = load_policy(run)
    assert np.array_equal(again.act(raw, window["goal"]), chunk)
    second = policy.act(raw, window["goal"])
    assert not np.array_equal(second, chunk)  # the noise moves on within an episode
    policy.reset()
    assert np.array_equal(policy.act(raw, window["goal"]), chunk)
    assert not np.array_equal(load_policy(run, seed=1).act(raw, window["goal"]), chunk)

    # The stored world model ranks K samples.
    planner = load_policy(run, scorer=STORED, k=4)
    assert planner.ranked and planner.k == 4
    picked = planner.act(raw, window["goal"])
    assert planner.last_plan is not None and planner.last_plan.samples.shape == (1, 4, *chunk.shape)
    assert torch.equal(torch.from_numpy(picked), planner.last_plan.selected[0])

    # The package-level name is this loader.
    assert planning.load_policy is load_policy and planning.Policy is Policy


def test_act_equals_the_sampler_and_planner_paths(
    runs: dict[str, Any], window: dict[str, Any]
) -> None:
    run, seed = runs["run"], 5
    net, objective, _ = checkpoint.load_policy(run)
    std = Standardiser.from_stats(window["stats"])
    b = window["batch"]
    goal_std = (torch.tensor([window["goal"]], dtype=torch.float32) - std.z_mean[0]) / std.z_std[0]
    water_now = b["water_now"]
    # The policy alone: one sample from the objective's sampler, same noise.
    with torch.no_grad():
        cond = net.encode_condition(b["hist"], b["hist_mask"], std.goal_vector(goal_std, water_now))
        noise = torch.randn((1, 32, len(std.u_mean)), generator=torch.Generator().manual_seed(seed))
        ref = clip_forces(std.u_to_phys(objective.sample_from_condition(net, cond, noise)))[0]
    got = load_policy(run, seed=seed).act(window["raw"], window["goal"])
    assert np.allclose(got, ref.numpy(), rtol=0.0, atol=1e-5)
    fast = load_policy(run, seed=seed, realtime=True).act(window["raw"], window["goal"])
    # Fast and reference samplers agree to float32 rounding, compared in standardised units.
    assert np.allclose(std.u_to_std(torch.from_numpy(fast)), std.u_to_std(ref), atol=1e-4)

    # Ranked: Planner.plan with the same world model, K and noise.
    wm = _wm_run(runs["root"] / "wm-ref", runs["stats"])
    scorer = world_model_scorer(load_world_model(wm)[0])
    ref_plan = Planner(net, objective, scorer, std, k=4).plan(
        b["hist"], b["hist_mask"], goal_std, water_now, None, torch.Generator().manual_seed(seed)
    )
    for realtime in (False, True):
        pol = load_policy(run, scorer=wm, k=4, seed=seed, realtime=realtime)
        picked = pol.act(window["raw"], window["goal"])
        assert pol.last_plan is not None
        assert torch.equal(pol.last_plan.index, ref_plan.index)
        assert np.allclose(std.u_to_std(torch.from_numpy(picked)),
                           std.u_to_std(ref_plan.selected[0]), atol=1e-4)  # fmt: skip


def test_histories_from_the_environment_and_bad_input(
    runs: dict[str, Any], window: dict[str, Any]
) -> None:
    obs = np.arange(23, dtype=np.float32)
    mask = np.ones(23, dtype=bool)
    mask[OBS.index("v_res")] = False
    row = observation_row(obs, {"mask": mask})
    assert np.isnan(row[OBS.index("v_res")]) and row[0] == 0.0 and np.isfinite(row).sum() == 22
    named = observation_row({n: (None if n == "v_res" else 1.0) for n in OBS})
    assert np.isnan(named[OBS.index("v_res")]) and np.nansum(named) == 22.0
    with pytest.raises(ValueError, match="23 values"):
        observation_row(np.zeros(5))

    policy = load_policy(runs["run"])
    raw = window["raw"]
    for r in raw[-3:]:
        hist = policy.observe(r, None)
    assert hist.shape == (3, 23)
    # A short history is preceded by copies of its first row.
    short, _ = policy.standardise(hist)
    full, _ = policy.standardise(np.concatenate([np.repeat(raw[-3:-2], 13, axis=0), raw[-3:]]))
    assert torch.equal(short, full)
    policy.reset()
    assert policy.observe(raw[-1]).shape == (1, 23)
    with pytest.raises(ValueError, match="history must be"):
        policy.act(np.zeros((4, 22)), 0.01)
    with pytest.raises(ValueError, match="goal_kg"):
        policy.act(raw, -1.0)
    nan_water = raw.copy()
    nan_water[-1, OBS.index("M_L")] = np.nan
    with pytest.raises(ValueError, match="M_L"):
        policy.act(nan_water, 0.01)


def test_clear_errors_for_runs_without_statistics_and_mismatched_world_models(
    runs: dict[str, Any],
    synthetic_dataset_dir: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    old = tmp_path / "old"
    shutil.copytree(runs["run"], old)
    shutil.rmtree(old / WORLD_MODEL_DIR)
    cfg = json.loads((old / "config.json").read_text())
    del cfg["extra"]["stats"]
    (old / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(InputError, match="does not store its standardisation statistics.*"
                       "retrain.*dataset=") as err:  # fmt: skip
        load_policy(old)
    assert "\n" not in str(err.value)
    # The dataset it was trained on supplies them.
    names = tuple(runs["stats"]["u_names"])
    assert load_policy(old, dataset=synthetic_dataset_dir).action_names == names
    with pytest.raises(InputError, match="stores no world model"):
        load_policy(old, scorer=STORED, dataset=synthetic_dataset_dir)

    shifted = {**runs["stats"], "z_mean": [v + 1.0 for v in runs["stats"]["z_mean"]]}
    other = _wm_run(tmp_path / "wm-shifted", shifted)
    with pytest.raises(InputError, match="other standardisation statistics"):
        load_policy(runs["run"], scorer=other)
    short = _wm_run(tmp_path / "wm-mlp", runs["stats"], {"kind": "ac-mlp", "horizon": 16})
    with pytest.raises(InputError, match="horizon"):
        load_policy(runs["run"], scorer=short)
    with pytest.raises(InputError, match="not a training run"):
        load_policy(runs["run"], scorer=tmp_path / "missing")
    with pytest.raises(InputError, match="not a training run"):
        load_policy(tmp_path / "missing")
    # rmi train-policy --wm checks the world model before it trains.
    from rmi_learn.cli import main

    argv = ["train-policy", "--objective", "flow", "--data", str(synthetic_dataset_dir),
            "--out", str(tmp_path / "new"), "--debug", "--no-progress"]  # fmt: skip
    assert main([*argv, "--wm", str(short)]) == 2
    assert "horizon" in capsys.readouterr().err and not (tmp_path / "new").exists()
    # Given its statistics back, the old run takes a world model that fits, and only one.
    cfg["extra"]["stats"] = runs["stats"]
    (old / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(InputError, match="other standardisation statistics"):
        attach_world_model(old, other)
    assert not (old / WORLD_MODEL_DIR).exists()
    fits = _wm_run(tmp_path / "wm-fits", runs["stats"])
    assert attach_world_model(old, fits) == old / WORLD_MODEL_DIR
    assert load_policy(old, scorer=STORED).ranked


@pytest.mark.parametrize("field", ["z_mean", "u_mean"])
def test_a_run_whose_mean_is_not_finite_is_refused_not_an_all_nan_chunk(
    runs: dict[str, Any], tmp_path: Path, field: str
) -> None:
    """A NaN mean would standardise every input (or destandardise every action) to NaN:
    the run is refused when loaded, naming its directory and the field."""
    run = tmp_path / "nan-mean"
    shutil.copytree(runs["run"], run)
    cfg = json.loads((run / "config.json").read_text())
    cfg["extra"]["stats"][field][0] = float("nan")
    (run / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(InputError, match=f"{re.escape(str(run))}: statistics field '{field}' "
                       "must be finite") as err:  # fmt: skip
        load_policy(run)
    assert "\n" not in str(err.value)


def _example() -> Any:
    return load_script(EXAMPLE, "policy_in_env")


def test_example_drives_the_environment(
    runs: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    example = _example()
    config = tmp_path / "trial.json"
    config.write_text(json.dumps(tiny_config()))
    argv = ["--policy", str(runs["run"]), "--config", str(config), "--max-steps", "5",
            "--execute", "2", "--k", "3"]  # fmt: skip
    assert example.main(argv) == 0
    out = capsys.readouterr().out
    lines = [x for x in out.splitlines() if "|M_L - goal|" in x]
    assert [x.split(":")[0] for x in lines] == [
        "policy alone",
        f"planner (K = 3, world model {runs['run'] / WORLD_MODEL_DIR})",
    ]
    for line in lines:
        m = re.search(r"\|M_L - goal\| = ([0-9.]+) g after (\d+) steps \((\d+) decisions", line)
        assert m is not None, line
        # The toy policy may lose the sponge before the step limit; the trial then ends.
        steps, decisions = int(m.group(2)), int(m.group(3))
        assert np.isfinite(float(m.group(1))) and 1 <= steps <= 5
        assert decisions == (steps + 1) // 2

    # Only F_target for a force-only (1-D) action space, both channels for a 2-D one.
    row = np.array([120.0, 0.01], dtype=np.float32)
    names = ("F_target", "v_cmd")
    assert example.env_action(row, names, 1).tolist() == [120.0]
    assert np.allclose(example.env_action(row, names, 2), [120.0, 0.01])
    assert example.env_action(np.array([90.0]), ("F_target",), 1).tolist() == [90.0]
    with pytest.raises(ValueError, match="action_mode='force'"):
        example.env_action(np.array([90.0]), ("F_target",), 2)


def test_statistics_give_the_action_channels(runs: dict[str, Any]) -> None:
    stats = runs["stats"]
    assert stats["u_names"] == ["F_target"]
    both = {**stats, "u_names": ["F_target", "v_cmd"], "u_mean": [150.0, 0.0],
            "u_std": [80.0, 0.01]}  # fmt: skip
    parsed, names = parse_stats(both, 2, "run")
    assert names == ("F_target", "v_cmd") and parsed.u_std.tolist() == [80.0, 0.01]
    with pytest.raises(InputError, match="1 action channels.*network outputs 2"):
        parse_stats(stats, 2, "run")
    with pytest.raises(InputError, match="observation channels"):
        parse_stats({**stats, "z_names": stats["z_names"][::-1]}, 1, "run")
    with pytest.raises(InputError, match="'u_std' must be finite and > 0"):
        parse_stats({**stats, "u_std": [0.0]}, 1, "run")
    with pytest.raises(InputError, match="'u_mean' must be finite"):
        parse_stats({**stats, "u_mean": [float("nan")]}, 1, "run")
    with pytest.raises(InputError, match="'z_mean' must be finite"):
        parse_stats({**stats, "z_mean": [float("inf"), *stats["z_mean"][1:]]}, 1, "run")
    with pytest.raises(InputError, match="'z_mean' missing"):
        parse_stats({k: v for k, v in stats.items() if k != "z_mean"}, 1, "run")
