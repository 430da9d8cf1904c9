"""Real-time decision path: the fast sampler against the reference samplers, the real-time
planner against :class:`Planner`, few-step distillation and the loader's input errors.

Tiny networks on the synthetic toy data (numbers mean nothing physically)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import torch
from torch import Tensor

from rmi_learn.errors import InputError
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.realtime import RealtimePlanner, load_realtime_planner
from rmi_learn.planning.refine import refine_chunk
from rmi_learn.planning.scorers import world_model_scorer
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.policies.checkpoint import load_policy, make_objective, model_config
from rmi_learn.policies.diffusion import DiffusionObjective
from rmi_learn.policies.fast_sampler import FastSampler, mish, schedule
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import PolicyUNet, UNetConfig
from rmi_learn.trainer import save_weights
from rmi_learn.world_models import build

torch.set_num_threads(1)

TINY = UNetConfig(channels=(8, 16, 32), time_embed_dim=16, gru_hidden=8, goal_hidden=8)
STD = Standardiser(
    z_mean=torch.full((18,), 0.5),
    z_std=torch.full((18,), 0.2),
    u_mean=torch.tensor([150.0]),
    u_std=torch.tensor([100.0]),
)
OBJECTIVES = {"diffusion": DiffusionObjective, "flow": FlowObjective}
#: Agreement of the fast and reference samplers in standardised action units. DDIM's last
#: steps divide by sqrt(1 - abar_t) (0.006 at t = 0), which scales float32 rounding of the
#: network output (1e-7) up to about 2e-5; Euler steps do not amplify it.
TOL = {"diffusion": 1e-4, "flow": 1e-5}


def _net(seed: int = 0, config: UNetConfig = TINY) -> PolicyUNet:
    torch.manual_seed(seed)
    return PolicyUNet(config).eval()


def _inputs(b: int) -> tuple[Tensor, Tensor, Tensor]:
    g = torch.Generator().manual_seed(3)
    hist = torch.randn(b, 16, 23, generator=g)
    return hist, torch.ones(b, 16, 23), torch.randn(b, 2, generator=g)


def test_mish_matches_torch() -> None:
    x = torch.linspace(-30.0, 30.0, 2001)
    assert torch.allclose(mish(x.clone()), torch.nn.functional.mish(x), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", ["diffusion", "flow"])
@pytest.mark.parametrize("steps", [None, 1, 2, 5])
def test_fast_sampler_equals_the_reference_sampler(name: str, steps: int | None) -> None:
    net = _net()
    ref_obj = OBJECTIVES[name]() if steps is None else OBJECTIVES[name](n_sample_steps=steps)
    hist, mask, goal = _inputs(2)
    k = 3
    noise = torch.randn(2 * k, 32, 1, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        cond = net.encode_condition(hist, mask, goal)
        ref = ref_obj.sample_from_condition(net, cond.repeat_interleave(k, 0), noise)
    fast = FastSampler(net, OBJECTIVES[name](), steps).sample_from_condition(cond, noise)
    assert FastSampler(net, OBJECTIVES[name](), steps).schedule.steps == ref_obj.n_sample_steps
    assert torch.allclose(fast, ref, rtol=0.0, atol=TOL[name]), (fast - ref).abs().max()


def test_schedule_of_the_final_ddim_step_returns_the_prediction() -> None:
    sch = schedule(DiffusionObjective(), 16)
    assert sch.times[0] == 49.0 and sch.times[-1] == 0.0
    assert sch.keep[-1] == 0.0 and sch.gain[-1] == 1.0
    flow = schedule(FlowObjective(), 4)
    assert flow.times == (0.0, 250.0, 500.0, 750.0) and flow.gain == (0.25,) * 4


def _toy_scorer(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    n, h, _ = actions.shape
    z = torch.zeros(n, h, 18)
    z[:, -1, 0] = -actions[..., 0].mean(-1)
    return z, torch.ones(n, h), torch.full((n, h, 4), 0.25)


def _gru() -> Any:
    torch.manual_seed(11)
    return build({"kind": "ac-gru", "hidden": 16, "u_embed": 8}).eval()


@pytest.mark.parametrize("name", ["diffusion", "flow"])
@pytest.mark.parametrize("scorer", ["toy", "ac-gru"])
def test_realtime_planner_selects_what_the_planner_selects(name: str, scorer: str) -> None:
    net = _net(1)
    score = _toy_scorer if scorer == "toy" else world_model_scorer(_gru())
    ref = Planner(net, OBJECTIVES[name](), score, STD, k=8)
    fast = RealtimePlanner(net, OBJECTIVES[name](), score, STD, k=8)
    hist, mask, _ = _inputs(3)
    goal, water = torch.tensor([0.3, -0.2, 1.0]), torch.ones(3)
    original = torch.randn(3, 32, 1)
    a = ref.plan(hist, mask, goal, water, original, torch.Generator().manual_seed(7))
    b = fast.plan(hist, mask, goal, water, original, torch.Generator().manual_seed(7))
    # Compared in standardised units, where TOL is stated.
    assert torch.allclose(STD.u_to_std(a.samples), STD.u_to_std(b.samples), rtol=0.0,
                          atol=TOL[name])  # fmt: skip
    assert torch.allclose(a.costs["J"], b.costs["J"], rtol=1e-4, atol=1e-4)
    assert torch.equal(a.index, b.index)
    assert torch.allclose(a.original_costs["J"], b.original_costs["J"])
    # act: one window, goal in kg, the selected chunk in N and m/s.
    chunk = fast.act(hist[0], mask[0], float(STD.water_to_kg(goal[0])),
                     torch.Generator().manual_seed(9))  # fmt: skip
    from rmi_learn.world_models.common import last_z

    again = fast.plan(hist[:1], mask[:1], goal[:1], last_z(hist[:1])[:, 0], None,
                      torch.Generator().manual_seed(9))  # fmt: skip
    assert chunk.shape == (32, 1)
    assert torch.allclose(chunk, again.selected[0], atol=1e-5)
    assert 0.0 <= float(chunk[:, 0].min()) and float(chunk[:, 0].max()) <= 400.0


def test_act_refines_the_selected_chunk_toward_the_goal() -> None:
    from rmi_learn.world_models.arx import LinearARX

    torch.manual_seed(2)
    arx = LinearARX(history=16, horizon=32)
    arx.W.normal_(0.0, 1e-3)
    score = world_model_scorer(arx)
    net = _net(1)
    plain = RealtimePlanner(net, FlowObjective(), score, STD, k=8)
    refined = RealtimePlanner(net, FlowObjective(), score, STD, k=8, refine="smooth")
    hist, mask, _ = _inputs(1)
    chunk = plain.act(hist[0], mask[0], 0.5, torch.Generator().manual_seed(9))
    pred = refine_chunk(score, STD, hist, mask, chunk[None], torch.zeros(1), iterations=0)
    goal = float(pred.pred_before_kg[0]) + 0.002
    chunk = plain.act(hist[0], mask[0], goal, torch.Generator().manual_seed(9))
    moved = refined.act(hist[0], mask[0], goal, torch.Generator().manual_seed(9))
    direct = refine_chunk(score, STD, hist, mask, chunk[None], torch.tensor([goal]),
                          lower=torch.clamp(chunk[None], max=0.0))  # fmt: skip
    assert moved.shape == (32, 1) and not torch.allclose(moved, chunk)
    assert torch.allclose(moved, direct.u[0], atol=1e-5)
    assert float(direct.pred_after_kg[0]) == pytest.approx(goal, abs=1e-5)
    with pytest.raises(InputError, match="refine must be one of"):
        RealtimePlanner(net, FlowObjective(), score, STD, refine="cubic")


# ------------------------------------------------------------------ run directories


def _policy_run(path: Path, name: str, config: UNetConfig = TINY, seed: int = 0) -> Path:
    net = _net(seed, config)
    path.mkdir(parents=True)
    cfg = {"model": model_config(config, make_objective(name), 16), "extra": {"size_cm": None}}
    (path / "config.json").write_text(json.dumps(cfg))
    save_weights(net.state_dict(), path / "model.safetensors")
    save_weights(net.state_dict(), path / "model.ema.safetensors")
    return path


def _stats(dataset: Path) -> dict[str, list[float]]:
    from rmi_learn.data.dataset import load_dataset

    stats = load_dataset(dataset).stats.to_json()
    return {k: stats[k] for k in ("z_mean", "z_std", "u_mean", "u_std")}


def _wm_run(path: Path, spec: dict[str, Any], stats: dict[str, Any] | None) -> Path:
    wm = build(spec)
    path.mkdir(parents=True)
    extra = {} if stats is None else {"stats": stats}
    (path / "config.json").write_text(json.dumps({"model": wm.config(), "extra": extra}))
    save_weights(wm.state_dict(), path / "model.safetensors")
    return path


GRU_SPEC = {"kind": "ac-gru", "hidden": 16, "u_embed": 8}


@pytest.mark.parametrize("name", ["diffusion", "flow"])
def test_distilled_one_step_student_is_closer_to_the_teacher(
    name: str, synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    from rmi_learn.policies.distill import distill_policy

    teacher = _policy_run(tmp_path / "teacher", name)
    out = tmp_path / "student"
    summary = distill_policy(teacher, synthetic_dataset_dir, out, steps=1, epochs=12,
                             batch_size=32, lr=2e-3, max_windows=96, val_windows=32,
                             progress=False)  # fmt: skip
    hist = summary["history"]
    assert hist[-1]["train_loss"] < hist[1]["train_loss"]
    # The untrained 1-step sampler (the teacher's weights) is the epoch-0 distance.
    assert summary["val_distance"] < 0.7 * summary["val_distance_initial"]
    net, objective, cfg = load_policy(out)
    assert objective.n_sample_steps == 1 and cfg["model"]["objective"] == name
    assert cfg["distill"]["teacher"] == str(teacher.resolve())
    assert cfg["distill"]["teacher_steps"] == (16 if name == "diffusion" else 20)
    assert cfg["distill"]["steps"] == 1
    # The real-time loader reads the student and samples it with one network pass.
    wm = _wm_run(tmp_path / "wm", GRU_SPEC, _stats(synthetic_dataset_dir))
    planner = load_realtime_planner(out, wm)
    assert planner.steps == 1
    chunk = planner.act(torch.zeros(16, 23), torch.ones(16, 23), 0.01)
    assert chunk.shape == (32, 1) and torch.isfinite(chunk).all()


def test_distill_cli_writes_a_two_step_student_and_refuses_bad_input(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from rmi_learn.cli import main

    teacher = _policy_run(tmp_path / "teacher", "flow")
    args = ["distill-policy", "--policy", str(teacher), "--dataset", str(synthetic_dataset_dir),
            "--epochs", "1", "--max-windows", "16", "--val-windows", "8",
            "--no-progress"]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "s2"), "--steps", "2"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["steps"] == 2 and summary["teacher_steps"] == 20
    _, objective, _ = load_policy(tmp_path / "s2")
    assert objective.n_sample_steps == 2
    # An existing run is never overwritten; a directory that is not a policy run: status 2.
    assert main([*args, "--out", str(tmp_path / "s2")]) == 2
    bad = [*args, "--out", str(tmp_path / "s3")]
    bad[2] = str(tmp_path)
    assert main(bad) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "rmi distill-policy:" in err


def test_distill_refuses_a_dataset_the_teacher_was_not_trained_on(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The teacher's chunks are its own only for inputs standardised by its statistics: a
    dataset of other statistics is one line naming both, and no student is written; the
    dataset it was trained on is accepted."""
    from rmi_learn.cli import main
    from rmi_learn.data.dataset import load_dataset

    stats = load_dataset(synthetic_dataset_dir).stats.to_json()
    teacher = _policy_run(tmp_path / "teacher", "flow")
    cfg = json.loads((teacher / "config.json").read_text())
    args = ["distill-policy", "--policy", str(teacher), "--dataset", str(synthetic_dataset_dir),
            "--epochs", "1", "--max-windows", "8", "--val-windows", "4",
            "--no-progress"]  # fmt: skip
    cfg["extra"]["stats"] = {**stats, "z_mean": [v + 1.0 for v in stats["z_mean"]]}
    (teacher / "config.json").write_text(json.dumps(cfg))
    assert main([*args, "--out", str(tmp_path / "other")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0] == (
        f"rmi distill-policy: {teacher} was trained with other statistics than "
        f"{synthetic_dataset_dir}"
    )
    assert not (tmp_path / "other").exists()
    cfg["extra"]["stats"] = stats
    (teacher / "config.json").write_text(json.dumps(cfg))
    assert main([*args, "--out", str(tmp_path / "same")]) == 0
    assert (tmp_path / "same" / "config.json").exists()


def test_loader_reports_bad_inputs_as_input_errors(
    synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    stats = _stats(synthetic_dataset_dir)
    policy = _policy_run(tmp_path / "policy", "flow")
    wm = _wm_run(tmp_path / "wm", GRU_SPEC, stats)
    assert load_realtime_planner(policy, wm).steps == 20
    assert load_realtime_planner(policy, wm, steps=2).steps == 2

    def refused(policy_dir: Path, wm_dir: Path, match: str, **kw: Any) -> None:
        with pytest.raises(InputError, match=match):
            load_realtime_planner(policy_dir, wm_dir, **kw)

    refused(tmp_path / "missing", wm, "not a training run directory")
    broken = _policy_run(tmp_path / "broken", "flow")
    (broken / "model.ema.safetensors").write_bytes(b"not safetensors")
    refused(broken, wm, "damaged weights")
    other = _policy_run(tmp_path / "other", "flow",
                        UNetConfig(channels=(8, 16, 32), time_embed_dim=16, gru_hidden=8,
                                   goal_hidden=8, obs_dim=20))  # fmt: skip
    refused(other, wm, "observation")
    no_stats = _wm_run(tmp_path / "wm-no-stats", GRU_SPEC, None)
    refused(policy, no_stats, "no standardisation statistics")
    # With the dataset the statistics are there.
    assert load_realtime_planner(policy, no_stats, dataset=synthetic_dataset_dir).k == 8
    short = _wm_run(tmp_path / "wm-mlp", {"kind": "ac-mlp", "horizon": 16}, stats)
    refused(policy, short, "horizon")
    shifted = {**stats, "z_mean": [v + 1.0 for v in stats["z_mean"]]}
    refused(policy, _wm_run(tmp_path / "wm-shift", GRU_SPEC, shifted), "other statistics",
            dataset=synthetic_dataset_dir)  # fmt: skip
