"""Model-based refinement of a force chunk (rmi_learn.planning.refine)."""

from __future__ import annotations

import pytest
import torch

from rmi_learn.planning.refine import METRICS, refine_chunk
from rmi_learn.planning.scorers import world_model_scorer
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.world_models.arx import LinearARX

H, L = 32, 4


def _std() -> Standardiser:
    z_mean, z_std = torch.zeros(18), torch.ones(18)
    z_mean[0], z_std[0] = 0.2, 0.05  # M_L around 0.2 kg
    return Standardiser(z_mean, z_std, torch.tensor([60.0]), torch.tensor([30.0]))


def _affine(weights: torch.Tensor, offset: float):
    """A scorer whose standardised M_L forecast after command ``s`` is
    ``offset + sum_{tau <= s} weights[tau] * u_std[tau]`` (a causal linear model)."""

    def score(hist: torch.Tensor, mask: torch.Tensor, actions: torch.Tensor):
        n, h, _ = actions.shape
        z = torch.zeros(n, h, 18)
        z = z + 0.0 * actions.sum()  # keeps the graph when the weights are zero
        water = offset + torch.cumsum(actions[..., 0] * weights[:h], dim=1)
        z = torch.cat([water[..., None], z[..., 1:]], dim=-1)
        return z, torch.zeros(n, h), torch.full((n, h, 4), 0.25)

    return score


def _inputs(n: int = 3) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    hist = torch.randn(n, L, 23, generator=g)
    return hist, torch.ones(n, L, 23), 60.0 + 10.0 * torch.randn(n, H, 1, generator=g)


@pytest.mark.parametrize("metric", METRICS)
def test_an_affine_scorer_is_met_in_one_step_when_no_bound_is_hit(metric: str) -> None:
    std = _std()
    w = -0.01 * torch.linspace(0.1, 1.0, H)  # a firmer grip keeps less water
    hist, mask, u = _inputs()
    before = refine_chunk(_affine(w, 0.0), std, hist, mask, u, torch.zeros(3), iterations=0)
    goal = before.pred_before_kg + torch.tensor([-0.003, 0.002, 0.003])
    r = refine_chunk(_affine(w, 0.0), std, hist, mask, u, goal, iterations=1, metric=metric)
    assert torch.allclose(r.pred_after_kg, goal, atol=1e-6)
    assert not torch.allclose(r.pred_before_kg, goal, atol=1e-4)
    assert r.u.shape == u.shape and bool((r.u >= 0).all())
    assert torch.allclose(r.change_N, (r.u - u).abs().amax(dim=(1, 2)))


def test_the_smooth_metric_varies_less_from_step_to_step_than_least_change() -> None:
    std = _std()
    w = torch.zeros(H)
    w[-4:] = -0.02  # the model attributes the water to the last setpoints only
    hist, mask, u = _inputs(1)
    goal = torch.tensor([0.195])
    out = {m: refine_chunk(_affine(w, 0.0), std, hist, mask, u, goal, metric=m) for m in METRICS}
    rough = {m: float(((r.u - u)[:, 1:] - (r.u - u)[:, :-1]).pow(2).sum()) for m, r in out.items()}
    assert rough["smooth"] < rough["l2"]
    for r in out.values():
        assert float(r.pred_after_kg[0]) == pytest.approx(0.195, abs=1e-6)


def test_bounds_hold_and_the_free_setpoints_take_up_the_correction() -> None:
    std = _std()
    w = -0.01 * torch.ones(H)
    hist, mask, _ = _inputs(1)
    u = torch.full((1, H, 1), 100.0)
    u[0, H // 2 :] = 10.0  # the second half sits at its lower bound
    lower = torch.clamp(u, max=10.0)
    # Less water than predicted needs a firmer grip: everything may rise.
    # More water needs a lighter one: only the first half may fall.
    before = float(_affine(w, 0.0)(hist, mask, std.u_to_std(u))[0][0, -1, 0])
    goal = std.water_to_kg(torch.tensor([before + 0.2]))
    r = refine_chunk(_affine(w, 0.0), std, hist, mask, u, goal, lower=lower, metric="l2")
    assert bool((r.u >= lower - 1e-5).all()) and bool((r.u <= 300.0 + 1e-5).all())
    assert torch.equal(r.u[0, H // 2 :], u[0, H // 2 :])
    assert float(r.pred_after_kg[0]) == pytest.approx(float(goal[0]), abs=1e-6)
    # A goal beyond every bound ends at the bound, not past it.
    far = std.water_to_kg(torch.tensor([before - 100.0]))
    r = refine_chunk(_affine(w, 0.0), std, hist, mask, u, far, upper=300.0)
    assert torch.allclose(r.u, torch.full_like(u, 300.0))


def test_a_scorer_blind_to_the_chunk_leaves_it_unchanged() -> None:
    hist, mask, u = _inputs(2)
    r = refine_chunk(_affine(torch.zeros(H), 0.0), _std(), hist, mask, u, torch.tensor([0.1, 0.3]))
    assert torch.equal(r.u, u)


def test_the_linear_arx_world_model_is_refined_through_autograd() -> None:
    torch.manual_seed(0)
    arx = LinearARX(history=L, horizon=H)
    arx.W.normal_(0.0, 1e-3)
    scorer = world_model_scorer(arx)
    std = _std()
    hist, mask, u = _inputs(2)
    start = refine_chunk(scorer, std, hist, mask, u, torch.zeros(2), step=H - 5, iterations=0)
    goal = start.pred_before_kg + torch.tensor([0.002, -0.002])
    with torch.no_grad():  # as inside the benchmark
        r = refine_chunk(scorer, std, hist, mask, u, goal, step=H - 5)
    assert torch.allclose(r.pred_after_kg, goal, atol=1e-5)
    assert arx.W.grad is None


@pytest.mark.parametrize("kw", [{"metric": "cubic"}, {"step": H}, {"iterations": -1}])
def test_bad_arguments_are_refused(kw: dict[str, object]) -> None:
    hist, mask, u = _inputs(1)
    with pytest.raises(ValueError):
        refine_chunk(_affine(torch.ones(H), 0.0), _std(), hist, mask, u, torch.tensor([0.2]), **kw)  # type: ignore[arg-type]
