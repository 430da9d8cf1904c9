"""World-model ranking: cost terms, selection, physical chunks, and the CLIs end to end.

The end-to-end test trains both policies for seconds on the synthetic toy data (numbers
mean nothing physically) and checks the tables' structure and the invariants of ranking.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from torch import Tensor

from rmi_learn.planning.cost import CostWeights, clip_forces, cost_terms, jerk
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.scorers import EnsembleScorer
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.policies.diffusion import DiffusionObjective
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import PolicyUNet, UNetConfig

torch.set_num_threads(1)

STD = Standardiser(
    z_mean=torch.full((18,), 0.5),
    z_std=torch.full((18,), 0.2),
    u_mean=torch.tensor([150.0]),
    u_std=torch.tensor([100.0]),
)


def test_cost_terms_by_hand() -> None:
    f = torch.tensor([[100.0, 110.0, 130.0, 130.0]])  # second differences 10, -20
    u = f.unsqueeze(-1)
    p = torch.zeros(1, 4, 4)
    p[..., 1] = 0.5
    p[..., 2] = 0.3  # slip
    p[..., 3] = 0.2  # mixed
    c = cost_terms(torch.tensor([0.4021]), torch.tensor([0.4]), u, p)
    assert c["J_M"].item() == pytest.approx(2.1, rel=1e-4)  # grams
    assert c["J_F"].item() == 130.0
    assert c["J_S"].item() == pytest.approx(0.5)
    assert c["J_U"].item() == pytest.approx(15.0)  # N/step^2
    w = CostWeights()
    expect = 2.1 + w.force * 130 + w.slip * 0.5 + w.jerk * 15.0
    assert c["J"].item() == pytest.approx(expect, rel=1e-4)
    assert (w.water, w.force, w.slip, w.jerk) == (1.0, 1e-4, 0.05, 0.1)
    assert c["J_D"].item() == 0.0  # one scorer: no disagreement


def _constant_water(level_std: float) -> Any:
    def score(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        n, h, _ = actions.shape
        z = torch.zeros(n, h, 18)
        z[..., 0] = level_std - actions[..., 0]
        return z, torch.ones(n, h), torch.full((n, h, 4), 0.25)

    return score


def test_ensemble_scores_the_mean_and_penalises_the_spread() -> None:
    # Members a and b predict (standardised) M_L = 1 - u and 2 - u: means 1.5 - u, spread
    # 0.5 std = 0.5 * 0.2 kg = 100 g at every chunk.
    ens = EnsembleScorer({"a": _constant_water(1.0), "b": _constant_water(2.0)})
    net = PolicyUNet(UNetConfig(channels=(8, 16, 32), time_embed_dim=16, gru_hidden=8,
                                goal_hidden=8))  # fmt: skip
    planner = Planner(net, FlowObjective(), ens, STD, k=2, weights=CostWeights(disagreement=2.0))
    u = torch.tensor([150.0, 250.0]).view(1, 2, 1, 1).expand(1, 2, 32, 1)  # std 0 and 1
    goal = STD.water_to_kg(torch.tensor([1.5]))
    costs, water = planner.score(torch.zeros(1, 16, 23), torch.ones(1, 16, 23), u, goal)
    assert torch.allclose(water, STD.water_to_kg(torch.tensor([[1.5, 0.5]])))
    assert torch.allclose(costs["J_M"], torch.tensor([[0.0, 200.0]]), atol=1e-3)
    assert torch.allclose(costs["J_D"], torch.tensor([[100.0, 100.0]]), atol=1e-3)
    assert torch.allclose(
        costs["J"] - costs["J_M"] - 2.0 * costs["J_D"],
        1e-4 * u[..., 0].amax(-1) + 0.05 * 0.5,
        atol=1e-3,
    )
    # As a plain scorer it is the members' mean.
    z, _, _ = ens(torch.zeros(2, 16, 23), torch.ones(2, 16, 23), torch.zeros(2, 32, 1))
    assert torch.allclose(z[..., 0], torch.full((2, 32), 1.5))
    with pytest.raises(ValueError, match="at least two"):
        EnsembleScorer({"a": _constant_water(1.0)})


def test_jerk_and_force_clipping() -> None:
    ramp = torch.linspace(0, 300, 32).unsqueeze(-1)
    assert jerk(ramp).item() == pytest.approx(0.0, abs=1e-3)
    u = torch.tensor([[[-20.0], [350.0], [900.0]]])
    c = clip_forces(u)
    assert c[..., 0].tolist() == [[0.0, 350.0, 400.0]]


def test_standardiser_and_goal_vector() -> None:
    u = torch.tensor([[250.0]])
    assert torch.allclose(STD.u_to_std(u), torch.tensor([[1.0]]))
    assert torch.allclose(STD.u_to_phys(STD.u_to_std(u)), u)
    g = STD.goal_vector(torch.tensor([0.5]), torch.tensor([1.5]))
    assert g.tolist() == [[0.5, -1.0]]
    assert STD.water_to_kg(torch.tensor([1.0])).item() == pytest.approx(0.7)


def _water_scorer(
    hist: Tensor, hist_mask: Tensor, actions: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Toy scorer: the terminal water falls linearly with the mean standardised force."""
    n, h, _ = actions.shape
    z = torch.zeros(n, h, 18)
    z[:, -1, 0] = -actions[..., 0].mean(-1)
    p_f = torch.full((n, h, 4), 0.25)
    return z, torch.ones(n, h), p_f


@pytest.mark.parametrize("objective", [DiffusionObjective(), FlowObjective()])
def test_planner_selects_the_argmin_in_physical_units(
    objective: DiffusionObjective | FlowObjective,
) -> None:
    torch.manual_seed(0)
    net = PolicyUNet(UNetConfig(channels=(8, 16, 32), time_embed_dim=16, gru_hidden=8,
                                goal_hidden=8))  # fmt: skip
    planner = Planner(net, objective, _water_scorer, STD, k=8)
    b = 3
    hist, mask = torch.randn(b, 16, 23), torch.ones(b, 16, 23)
    original_std = torch.randn(b, 32, 1)
    res = planner.plan(hist, mask, torch.zeros(b), torch.ones(b), original_std,
                       torch.Generator().manual_seed(1))  # fmt: skip
    assert res.samples.shape == (b, 8, 32, 1)
    assert res.first.shape == res.selected.shape == (b, 32, 1)
    assert res.original is not None
    assert torch.allclose(res.original, STD.u_to_phys(original_std))
    f = res.samples[..., 0]
    assert f.min() >= 0.0 and f.max() <= 400.0
    j = res.costs["J"]
    assert torch.equal(res.index, j.argmin(1))
    sel = res.selected_costs()["J"]
    assert (sel <= res.first_costs()["J"]).all()
    assert torch.equal(res.selected, res.samples[torch.arange(b), res.index])
    # The scorer's water for a chunk is recomputed independently from its physical force.
    mean_f_std = STD.u_to_std(res.selected)[..., 0].mean(-1)
    water_g = 1000 * (STD.water_to_kg(-mean_f_std) - STD.water_to_kg(torch.zeros(b))).abs()
    assert torch.allclose(res.selected_costs()["J_M"], water_g, rtol=1e-4, atol=1e-3)
    # The original chunk is scored with the same cost.
    of = STD.u_to_std(res.original)[..., 0].mean(-1)
    assert torch.allclose(
        res.original_costs["J_M"],
        1000 * (STD.water_to_kg(-of) - STD.water_to_kg(torch.zeros(b))).abs(),
        rtol=1e-4,
        atol=1e-3,
    )


# ---------------------------------------------------------------- end to end


def test_train_and_rank_end_to_end(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from rmi_learn.cli import main

    wm_dir = tmp_path / "wm"
    wm_args = ["--debug", "--no-progress", "--val-windows", "16"]
    rc = main(["train-wm", "--model", "transformer", "--data", str(synthetic_dataset_dir),
               "--out", str(wm_dir), *wm_args])  # fmt: skip
    assert rc == 0
    small = ["--channels", "16,32,64", "--val-windows", "16", "--no-progress", "--debug"]
    for obj in ("diffusion", "flow"):
        rc = main(["train-policy", "--objective", obj, "--data", str(synthetic_dataset_dir),
                   "--out", str(tmp_path / obj), *small])  # fmt: skip
        assert rc == 0
        cfg = json.loads((tmp_path / obj / "config.json").read_text())
        assert cfg["model"]["objective"] == obj and cfg["model"]["horizon"] == 32
        assert cfg["train"]["optimizer"] == "adamw" and cfg["train"]["lr"] == 1e-4
        assert cfg["train"]["batch_size"] == 64 and cfg["train"]["patience"] == 12
        assert (tmp_path / obj / "model.ema.safetensors").exists()
        lines = (tmp_path / obj / "metrics.jsonl").read_text().splitlines()
        epochs = [json.loads(x) for x in lines if '"epoch"' in x and '"kind": "epoch"' in x]
        key = "val_action_mae" if obj == "diffusion" else "val_flow_mse"
        assert epochs and all(np.isfinite(e[key]) for e in epochs)
    # A finished run is never overwritten; --resume returns its summary.
    again = ["train-policy", "--objective", "flow", "--data", str(synthetic_dataset_dir),
             "--out", str(tmp_path / "flow"), *small]  # fmt: skip
    before = (tmp_path / "flow" / "model.ema.safetensors").read_bytes()
    assert main(again) == 2
    assert main([*again, "--resume"]) == 0
    assert (tmp_path / "flow" / "model.ema.safetensors").read_bytes() == before

    out = tmp_path / "tables"
    rc = main(["rank", "--data", str(synthetic_dataset_dir), "--wm", str(wm_dir),
               "--diffusion", str(tmp_path / "diffusion"), "--flow", str(tmp_path / "flow"),
               "--out", str(out), "--max-windows", "6", "--threads", "1"])  # fmt: skip
    assert rc == 0
    t3 = json.loads((out / "table3_ranking.json").read_text())
    assert t3["scorer_name"] == "W_T"
    assert [r["method"] for r in t3["rows"]] == [
        "Original controller action",
        "Diffusion policy, first sample",
        "Diffusion policy + W_T",
        "Flow matching, first sample",
        "Flow matching + W_T",
    ]
    sizes = [s for s, n in t3["n_windows"].items() if n > 0]
    assert sizes
    rows = {r["method"]: r for r in t3["rows"]}
    for s in sizes:
        for r in t3["rows"]:
            assert np.isfinite(r[s]) and r[s] >= 0.0
    t5 = json.loads((out / "table5_imitation.json").read_text())
    assert [r["method"] for r in t5["rows"]][:2] == ["Diffusion policy", "Flow matching"]
    ts1 = json.loads((out / "tableS1_cost.json").read_text())
    s1 = {r["method"]: r for r in ts1["rows"]}
    for o in ("Diffusion policy", "Flow matching"):
        for s in sizes:
            # argmin: the selected chunk's predicted cost never exceeds the first sample's
            assert s1[f"{o} + W_T"][s] <= s1[f"{o}, first sample"][s] + 1e-9
            assert 0.0 <= t5["rows"][0][s]["MAE_F"] < 400.0
        assert rows[f"{o} + W_T"] is not None
    for name in ("table3_ranking.md", "table5_imitation.md", "tableS1_cost.md"):
        text = (out / name).read_text()
        assert "| Method |" in text and "Flow matching" in text
    z = np.load(out / "chunks_flow.npz")
    n = int(sum(t3["n_windows"].values()))
    assert z["original"].shape == z["first"].shape == z["selected"].shape == (n, 32, 1)
    assert z["J_samples"].shape == (n, 8)
    assert np.all(z["selected"][..., 0] <= 400.0) and np.all(z["first"][..., 0] >= 0.0)
    best = z["J_samples"][np.arange(n), z["index"]]
    assert np.allclose(best, z["J_samples"].min(1))
    assert z["run_id"].shape == (n,)
    # Wrong inputs are found before anything is written: one line, status 2, no --out.
    arx = tmp_path / "arx"
    rc = main(["train-wm", "--model", "arx", "--data", str(synthetic_dataset_dir),
               "--out", str(arx), *wm_args])  # fmt: skip
    assert rc == 0
    base = ["rank", "--data", str(synthetic_dataset_dir), "--out", str(tmp_path / "bad")]
    for wm, flow, says in [
        (tmp_path / "flow", tmp_path / "flow", "unknown world model 'policy-unet'"),
        (wm_dir, wm_dir, "is not a policy run"),
        (arx, tmp_path / "flow", "scores chunks of exactly 64 steps, the --flow policy's have 32"),
    ]:
        assert main([*base, "--wm", str(wm), "--flow", str(flow)]) == 2
        assert says in capsys.readouterr().err
        assert not (tmp_path / "bad").exists()
    # Another scorer whose horizon fits names the selected rows and the title after itself.
    arx32 = tmp_path / "arx-32"
    rc = main(["train-wm", "--model", "arx", "--model-arg", "horizon=32", "--data",
               str(synthetic_dataset_dir), "--out", str(arx32), *wm_args])  # fmt: skip
    assert rc == 0
    by_arx = tmp_path / "tables-arx"
    assert main([*base[:-2], "--out", str(by_arx), "--wm", str(arx32),
                 "--flow", str(tmp_path / "flow"), "--max-windows", "2"]) == 0  # fmt: skip
    t3 = json.loads((by_arx / "table3_ranking.json").read_text())
    assert t3["scorer_name"] == "Linear-ARX"
    assert [r["method"] for r in t3["rows"]][1:] == [
        "Flow matching, first sample",
        "Flow matching + Linear-ARX",
    ]
    assert "Table III. Linear-ARX-predicted" in (by_arx / "table3_ranking.md").read_text()
    assert "W_T" not in (by_arx / "tableS1_cost.md").read_text()
