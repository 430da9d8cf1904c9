"""Policy network, diffusion/flow objectives and EMA: each trap of learning.md pinned."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from rmi_learn.policies.diffusion import (
    DiffusionObjective,
    cosine_alpha_bar,
    ddim_step_pairs,
    min_snr_weight,
)
from rmi_learn.policies.ema import EMA, ema_decay
from rmi_learn.policies.flow import FlowObjective, euler_integrate, interpolate
from rmi_learn.policies.unet import PolicyUNet, UNetConfig, count_parameters, sinusoidal_embedding

torch.set_num_threads(1)

H_PI = 32


class Oracle(nn.Module):
    """Stands in for PolicyUNet: ``denoise`` calls ``fn(x, t)`` and records every ``t``."""

    def __init__(self, fn: object) -> None:
        super().__init__()
        self.fn = fn
        self.times: list[Tensor] = []
        self.config = UNetConfig()

    def encode_condition(self, hist: Tensor, hist_mask: Tensor, goal: Tensor) -> Tensor:
        return torch.zeros(hist.shape[0], 1)

    def denoise(self, x: Tensor, t: Tensor, obs_cond: Tensor) -> Tensor:
        self.times.append(t.clone())
        out: Tensor = self.fn(x, t)  # type: ignore[operator]
        return out


# ---------------------------------------------------------------- UNet


def test_unet_parameter_count_and_shapes() -> None:
    torch.manual_seed(0)
    model = PolicyUNet(UNetConfig(horizon=H_PI))
    n = count_parameters(model)
    assert 4.7e6 < n < 5.1e6, n  # "about 4.9 M" with channels 64/128/256
    assert model.config.channels == (64, 128, 256) and model.config.kernel_size == 5
    films = [m for m in model.modules() if m.__class__.__name__ == "FiLMResidualBlock"]
    assert len(films) == 12  # FiLM in every residual block: 6 down, 2 mid, 4 up
    assert sum(isinstance(m, nn.GroupNorm) for m in model.modules()) == 25
    assert any(isinstance(m, nn.Mish) for m in model.modules())
    x = torch.randn(3, H_PI, 1)
    out = model(
        x,
        torch.tensor([0.0, 10.0, 49.0]),
        torch.randn(3, 16, 23),
        torch.ones(3, 16, 23),
        torch.randn(3, 2),
    )
    assert out.shape == (3, H_PI, 1)
    assert torch.isfinite(out).all()


def test_unet_uses_every_conditioning_input() -> None:
    torch.manual_seed(0)
    model = PolicyUNet(
        UNetConfig(channels=(16, 32, 64), time_embed_dim=32, gru_hidden=16, goal_hidden=16)
    )
    x = torch.randn(2, H_PI, 1)
    hist, mask, goal, t = (
        torch.randn(2, 16, 23),
        torch.ones(2, 16, 23),
        torch.randn(2, 2),
        torch.tensor([5.0, 5.0]),
    )
    base = model(x, t, hist, mask, goal)
    for changed in (
        model(x, t + 7, hist, mask, goal),
        model(x, t, hist + 1, mask, goal),
        model(x, t, hist, torch.zeros_like(mask), goal),
        model(x, t, hist, mask, goal + 1),
    ):
        assert (changed - base).abs().max() > 1e-4


def test_unet_rejects_bad_horizon() -> None:
    with pytest.raises(ValueError, match="divisible"):
        PolicyUNet(UNetConfig(horizon=30))


def test_time_embedding_resolves_flow_time_only_when_scaled() -> None:
    # Flow time in [0, 1] fed raw lands inside one slow period of every frequency.
    raw = (
        sinusoidal_embedding(torch.tensor([0.30]), 128)
        - sinusoidal_embedding(torch.tensor([0.31]), 128)
    ).norm()
    scaled = (
        sinusoidal_embedding(torch.tensor([300.0]), 128)
        - sinusoidal_embedding(torch.tensor([310.0]), 128)
    ).norm()
    assert raw < 0.1 and scaled > 2.0, (raw, scaled)


def test_config_round_trip() -> None:
    cfg = UNetConfig(channels=(8, 16, 32), horizon=16)
    assert UNetConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"channels": "abc"}, "field 'channels' must be a non-empty list of whole numbers >= 1"),
        ({"channels": 64}, "field 'channels' must be a non-empty list of whole numbers >= 1"),
        ({"channels": []}, "field 'channels' must be a non-empty list of whole numbers >= 1"),
        ({"channels": [8, -16]}, "field 'channels' must be a non-empty list"),
        ({"horizon": "32"}, "field 'horizon' must be a whole number >= 1, got '32'"),
        ({"n_groups": 0}, "field 'n_groups' must be a whole number >= 1, got 0"),
        ({"goal_dim": True}, "field 'goal_dim' must be a whole number >= 1, got True"),
        ({"width": 3}, "unknown field(s) ['width']"),
    ],
)
def test_a_config_from_a_file_names_the_field_it_cannot_use(
    change: dict[str, object], says: str
) -> None:
    """``config.json`` is the user's file: a field of the wrong kind is a ValueError naming
    it, not a TypeError from deep inside the network's constructor."""
    with pytest.raises(ValueError, match=re.escape(says)):
        UNetConfig.from_dict({**UNetConfig().to_dict(), **change})
    with pytest.raises(ValueError, match="unet must be an object"):
        UNetConfig.from_dict([64, 128])


# ---------------------------------------------------------------- diffusion


def test_cosine_schedule() -> None:
    ab = cosine_alpha_bar(50)
    assert ab.shape == (50,)
    assert (ab[1:] < ab[:-1]).all()
    f = [math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2 for s in (0.0, 0.5, 1.0 / 50)]
    # Below the beta cap the product telescopes to f(t/T) / f(0).
    assert ab[0].item() == pytest.approx(f[2] / f[0], rel=1e-9)
    assert ab[24].item() == pytest.approx(f[1] / f[0], rel=1e-9)
    assert 0.0 < ab[49].item() < 1e-5


def test_ddim_pairs_start_at_49_and_end_at_minus_one() -> None:
    pairs = ddim_step_pairs(50, 16)
    assert len(pairs) == 16
    assert pairs[0][0] == 49
    assert pairs[-1] == (0, -1)
    for (t, tp), (t_next, _) in zip(pairs, pairs[1:], strict=False):
        assert tp == t_next and tp < t
    assert [t for t, _ in pairs] == sorted({t for t, _ in pairs}, reverse=True)
    obj = DiffusionObjective()
    assert obj.pairs == pairs
    assert obj.abar(torch.tensor([-1])).item() == 1.0
    assert obj.abar(torch.tensor([49])).item() == pytest.approx(cosine_alpha_bar()[49].item())
    assert ddim_step_pairs(50, 50) == [(t, t - 1) for t in range(49, -1, -1)]


def test_min_snr_weight_for_x0_prediction() -> None:
    ab = cosine_alpha_bar(50)
    snr = ab / (1 - ab)
    w = min_snr_weight(ab, gamma=5.0)
    assert torch.allclose(w, torch.minimum(snr, torch.tensor(5.0, dtype=torch.float64)))
    assert w[0].item() == 5.0
    assert w[49].item() < 1e-5  # the x0 trap: almost no weight at the noisiest step
    eps_w = min_snr_weight(ab, gamma=5.0, prediction="epsilon")
    assert eps_w[49].item() == pytest.approx(1.0)  # the epsilon form differs
    assert min_snr_weight(ab, 5.0, floor=0.01)[49].item() == 0.01
    obj = DiffusionObjective()
    assert torch.allclose(obj.weights.double(), w.float().double())


def test_ddim_recovers_a_point_mass_with_an_x0_oracle() -> None:
    target = torch.linspace(-1, 1, H_PI).view(1, H_PI, 1)
    oracle = Oracle(lambda x, t: target.expand_as(x))
    obj = DiffusionObjective()
    noise = torch.randn(4, H_PI, 1, generator=torch.Generator().manual_seed(1))
    out = obj.sample_from_condition(oracle, torch.zeros(4, 1), noise)  # type: ignore[arg-type]
    assert torch.allclose(out, target.expand(4, -1, -1), atol=1e-5)
    seen = [int(t[0]) for t in oracle.times]
    assert seen == [t for t, _ in ddim_step_pairs(50, 16)]  # integer steps, 16 evaluations


def test_ddim_follows_the_exact_x0_of_a_gaussian_data_distribution() -> None:
    # Data A ~ N(mu, s^2): E[A | x_t] is linear. DDIM with this oracle discretises the
    # probability-flow ODE, so the sample mean is mu and the std approaches s as steps grow
    # (16 steps shrink it by ~12 %, 50 by ~4 %); a wrong eps/abar pairing breaks both.
    mu, s = 2.0, 0.3
    stds = []
    for steps in (16, 50):
        obj = DiffusionObjective(n_sample_steps=steps)

        def x0_oracle(x: Tensor, t: Tensor, obj: DiffusionObjective = obj) -> Tensor:
            ab = obj.abar(t.long()).view(-1, 1, 1)
            var = ab * s**2 + (1 - ab)
            return mu + ab.sqrt() * s**2 / var * (x - ab.sqrt() * mu)

        noise = torch.randn(4000, 2, 1, generator=torch.Generator().manual_seed(0))
        out = obj.sample_from_condition(
            Oracle(x0_oracle),  # type: ignore[arg-type]
            torch.zeros(4000, 1),
            noise,
        )
        assert out.mean().item() == pytest.approx(mu, abs=0.03)
        stds.append(out.std().item())
    assert 0.85 * s < stds[0] < stds[1] < 1.02 * s, stds


def test_diffusion_loss_is_min_snr_weighted() -> None:
    torch.manual_seed(0)
    obj = DiffusionObjective()
    actions = torch.randn(64, H_PI, 1)
    zero = Oracle(lambda x, t: torch.zeros_like(x))

    class Wrapper(nn.Module):
        config = UNetConfig()

        def forward(self, x: Tensor, t: Tensor, *_: Tensor) -> Tensor:
            return zero.denoise(x, t, x)

    loss, info = obj.loss(
        Wrapper(),  # type: ignore[arg-type]
        actions,
        torch.zeros(64, 16, 23),
        torch.ones(64, 16, 23),
        torch.zeros(64, 2),
        torch.Generator().manual_seed(3),
    )
    per = actions.pow(2).flatten(1).mean(1)
    assert torch.allclose(info["mse"], per)
    assert loss.item() == pytest.approx((obj.weights[info["t"]] * per).mean().item(), rel=1e-5)
    assert info["t"].min() >= 0 and info["t"].max() <= 49


# ---------------------------------------------------------------- flow


def test_flow_direction_moves_noise_to_data() -> None:
    # Point-mass data at a: x_t = (1-t) eps + t a, so the exact velocity is (a - x)/(1 - t).
    a = torch.full((5, H_PI, 1), 3.0)
    noise = torch.randn(5, H_PI, 1, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(interpolate(a, noise, torch.zeros(5)), noise)
    assert torch.allclose(interpolate(a, noise, torch.ones(5)), a)
    out = euler_integrate(lambda x, t: (a - x) / (1 - t).view(-1, 1, 1), noise, 20)
    assert torch.allclose(out, a, atol=1e-5)
    # The opposite convention (t = 0 data) applied to this sampler goes the wrong way.
    wrong = euler_integrate(lambda x, t: -(a - x) / (1 - t).view(-1, 1, 1), noise, 20)
    assert (wrong - a).abs().mean() > 1.0


def test_flow_sampler_feeds_t_times_1000_and_the_target_is_a_minus_eps() -> None:
    a = torch.full((1, H_PI, 1), -1.5)
    oracle = Oracle(lambda x, t: (a - x) / (1 - t / 1000.0).view(-1, 1, 1))
    obj = FlowObjective()
    noise = torch.randn(2, H_PI, 1, generator=torch.Generator().manual_seed(0))
    out = obj.sample_from_condition(oracle, torch.zeros(2, 1), noise)  # type: ignore[arg-type]
    assert torch.allclose(out, a.expand(2, -1, -1), atol=1e-4)
    assert [round(float(t[0])) for t in oracle.times] == [50 * i for i in range(20)]

    gen = torch.Generator().manual_seed(7)
    actions = torch.randn(16, H_PI, 1)
    t = torch.rand((16,), generator=gen)
    eps = torch.randn(actions.shape, generator=gen)

    class Zero(nn.Module):
        config = UNetConfig()

        def forward(self, x: Tensor, *_: Tensor) -> Tensor:
            return torch.zeros_like(x)

    loss, info = obj.loss(
        Zero(),  # type: ignore[arg-type]
        actions,
        torch.zeros(16, 16, 23),
        torch.ones(16, 16, 23),
        torch.zeros(16, 2),
        torch.Generator().manual_seed(7),
    )
    assert torch.allclose(info["t"], t)
    assert loss.item() == pytest.approx((actions - eps).pow(2).mean().item(), rel=1e-5)


# ---------------------------------------------------------------- EMA


def test_ema_warmup_formula() -> None:
    assert ema_decay(0) == 0.0
    assert ema_decay(1) == pytest.approx(1 - 2**-0.75)
    assert ema_decay(9) == pytest.approx(1 - 10**-0.75)
    assert ema_decay(10**6) == 0.999
    assert all(ema_decay(n) <= ema_decay(n + 1) for n in range(0, 20000, 97))


def test_ema_hook_forgets_the_initialisation() -> None:
    torch.manual_seed(0)
    live = nn.Linear(3, 3)
    ema = EMA()
    for n in (0, 1, 9, 500, 10**6):
        ema.updates = n
        assert ema.decay() == pytest.approx(ema_decay(n))
    ema.updates = 0
    with torch.no_grad():
        live.weight.fill_(1.0)
    ema.update(live)  # decay 0: a copy
    assert torch.allclose(ema.shadow["weight"], torch.ones(3, 3))
    with torch.no_grad():
        live.weight.fill_(2.0)
    for _ in range(1000):
        ema.update(live)
    # A constant 0.999 would still hold 0.999^1000 = 37 % of the old value.
    assert (ema.shadow["weight"] - 2.0).abs().max() < 0.05
    with torch.no_grad():
        live.weight.fill_(7.0)
    with ema.applied(live):
        assert (live.weight - 2.0).abs().max() < 0.05
    assert torch.equal(live.weight, torch.full((3, 3), 7.0))


# ---------------------------------------------------------------- learning on toy data


@pytest.mark.parametrize("name", ["diffusion", "flow"])
def test_briefly_trained_policy_samples_beat_noise(
    synthetic_dataset_dir: object, name: str
) -> None:
    """A small UNet trained for a few seconds on the synthetic windows must sample chunks
    much closer to the held-out validation chunks than the noise it starts from."""
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.checkpoint import goal_from_batch, make_objective

    torch.manual_seed(0)
    ds = load_dataset(synthetic_dataset_dir)  # type: ignore[arg-type]
    train = ds.windows("train", history=16, horizon=H_PI)
    val = ds.windows("val", history=16, horizon=H_PI).batch(np.arange(0, 400, 5))
    obj = make_objective(name)
    net = PolicyUNet(UNetConfig(channels=(16, 32, 64), time_embed_dim=32, gru_hidden=16,
                                goal_hidden=16))  # fmt: skip
    opt = torch.optim.AdamW(net.parameters(), lr=2e-3)
    rng = np.random.default_rng(0)
    for _ in range(60):
        b = train.batch(rng.choice(len(train), 64, replace=False))
        loss, _ = obj.loss(net, b["actions"], b["hist"], b["hist_mask"], goal_from_batch(b)[1])
        opt.zero_grad()
        loss.backward()  # type: ignore[no-untyped-call]
        opt.step()
    net.eval()
    gen = torch.Generator().manual_seed(5)
    sample = obj.sample(net, val["hist"], val["hist_mask"], goal_from_batch(val)[1], gen)
    noise = torch.randn(sample.shape, generator=gen)
    mae = (sample - val["actions"]).abs().mean().item()
    noise_mae = (noise - val["actions"]).abs().mean().item()
    assert mae < 0.5 * noise_mae, (mae, noise_mae)


def test_a_seed_gives_the_same_policy_in_another_process(
    synthetic_dataset_dir: object, tmp_path: Path
) -> None:
    """torch seeds its global generator at random in each process: the UNet's initial
    weights must come from the training seed, so two processes train the same policy."""
    outs = [tmp_path / f"run{i}" for i in range(2)]
    for out in outs:
        cmd = [sys.executable, "-m", "rmi_learn.cli", "train-policy", "--objective", "flow",
               "--data", str(synthetic_dataset_dir), "--out", str(out), "--debug",
               "--epochs", "1", "--threads", "1", "--no-progress"]  # fmt: skip
        subprocess.run(cmd, check=True, capture_output=True)
    a, b = ((o / "model.safetensors").read_bytes() for o in outs)
    assert a == b
