"""AC-GRU-WM and State-GRU-WM (paper Eq. 9-12).

A 2-layer GRU (width 128) encodes the history [y, m]; a 2-layer GRU decoder (GRU cells)
starts from its final hidden state and steps through the horizon. Decoder input at step tau:
[y_hat_{t+tau-1}, m_hat_{t+tau-1}, E_u(u_{t+tau-1})] (State-GRU-WM drops E_u). D_z predicts the
change of the standardised continuous state in units of each channel's step-to-step change
(``delta_scale``), accumulated from z_t; separate heads give the
contact and friction logits. The first step's input is the latest observation and its mask;
later inputs are the model's own predictions (contact probability, friction probabilities)
marked valid, or, with teacher forcing, the ground truth with its mask.

Without autograd (planning, evaluation) the same equations run in one native call on CPU
(``rmi_sph.GruForecaster``, the ``rmi-wm`` crate: the whole rollout without per-kernel
dispatch, its chunks split over ``torch.get_num_threads()`` threads with identical results for
any count), or elsewhere through ``_rollout``, which regroups the products for speed. The
differentiable loop in ``forward`` is the reference for both. Set ``RMI_WM_NATIVE=0`` (or the
model's ``native`` attribute to False) to keep inference in torch.
"""

from __future__ import annotations

import functools
import math
import os
from typing import Any, NamedTuple, cast

import torch
import torch.nn.functional as F
from torch import nn

from rmi_learn.data.schema import CONTINUOUS_INDEX
from rmi_learn.world_models.common import (
    ASSEMBLE_INDEX,
    N_FRIC,
    N_OBS,
    N_U,
    N_Z,
    WATER,
    WorldModel,
    assemble_obs,
    last_z,
)
from rmi_learn.world_models.weight_persistence import WEIGHT_READING, weight_water

#: Environment variable: "0" keeps GRU inference in torch instead of the native rollout.
NATIVE_ENV = "RMI_WM_NATIVE"


@functools.cache
def _native_class() -> Any:
    """``rmi_sph.GruForecaster``, or None where the extension lacks it or the CPU lacks the
    AVX2 + FMA its speed depends on (both fixed for the process)."""
    try:
        import rmi_sph
    except ImportError:
        return None
    cls = getattr(rmi_sph, "GruForecaster", None)
    return cls if cls is not None and cls.accelerated() else None


class _PackedDecoder(NamedTuple):
    """Decoder weights regrouped for the inference rollout (all transposed, K x N)."""

    w_q: torch.Tensor  # fed-back [z, contact, friction] -> layer-0 input gates
    b_ih: torch.Tensor
    b_rest: torch.Tensor  # b_ih plus the constant mask term of steps after the first
    w_first: torch.Tensor  # [y, m] of the last observation -> layer-0 input gates
    w_e: torch.Tensor  # E_u(u) -> layer-0 input gates
    w_out: list[torch.Tensor]  # new state of layer i -> [layer i+1 input (or head) | own gh]
    b_out: list[torch.Tensor]


class GRUWorldModel(WorldModel):
    """Recurrent world model; ``action_conditioned=False`` gives State-GRU-WM."""

    recurrent = True
    # Chunks scored for one history share its encoding: the encoder runs once per history.
    shares_history = True
    #: Free rollouts of float32 CPU tensors run natively (see the module docstring); the
    #: sensors mode's always in torch.
    native = True
    takes_sensors = True

    def __init__(
        self,
        action_conditioned: bool = True,
        hidden: int = 128,
        layers: int = 2,
        u_embed: int = 64,
        state_groups: str = "ALL",
        observation_mode: str = "privileged",
        weight_reading: list[float] | None = None,
    ) -> None:
        self.kind = "ac-gru" if action_conditioned else "state-gru"
        super().__init__(state_groups, observation_mode)
        self.weight_reading = _checked_reading(weight_reading, observation_mode)
        self.action_conditioned = action_conditioned
        self.hidden, self.layers, self.u_embed = hidden, layers, u_embed
        self.encoder = nn.GRU(2 * self.n_inputs, hidden, layers, batch_first=True)
        if observation_mode == "sensors":
            # No y_t to start from: the encoder's last state estimates it (the same three
            # outputs as the head, the state itself rather than its change).
            self.estimate = nn.Linear(hidden, N_Z + 1 + N_FRIC)
        d_in = 2 * N_OBS
        if action_conditioned:
            self.E_u = nn.Sequential(
                nn.Linear(N_U, u_embed), nn.ReLU(), nn.Linear(u_embed, u_embed)
            )
            d_in += u_embed
        # The decoder steps one command at a time: a stack of GRU cells (same equations as a
        # multi-layer nn.GRU, without its per-call sequence overhead).
        self.decoder = nn.ModuleList(
            [nn.GRUCell(d_in if i == 0 else hidden, hidden) for i in range(layers)]
        )
        # One matrix for the three heads: [D_z (18) | contact (1) | friction (4)].
        self.head = nn.Linear(hidden, N_Z + 1 + N_FRIC)
        # Start as the persistence forecast: small residuals.
        with torch.no_grad():
            self.head.weight[:N_Z].normal_(std=1e-3)
            self.head.bias[:N_Z].zero_()

    def config(self) -> dict[str, Any]:
        cfg = {
            **super().config(),
            "hidden": self.hidden,
            "layers": self.layers,
            "u_embed": self.u_embed,
        }
        if self.weight_reading is not None:
            cfg["weight_reading"] = list(self.weight_reading)
        return cfg

    def forward(
        self,
        hist: torch.Tensor,
        hist_mask: torch.Tensor,
        actions: torch.Tensor,
        teacher: dict[str, torch.Tensor] | None = None,
        tf_prob: float = 0.0,
    ) -> dict[str, torch.Tensor]:
        """See :mod:`rmi_learn.world_models.common`; ``teacher`` is a batch with ``target``,
        ``target_mask``, ``target_c``, ``target_r`` used with probability ``tf_prob``."""
        h_len = self.check_horizon(actions)
        hist, hist_mask = self.prepare(hist, hist_mask)
        n, b = actions.shape[0], hist.shape[0]
        if n % b:
            raise ValueError(f"{n} action chunks do not split evenly over {b} histories")
        rep = n // b
        if teacher is None and not torch.is_grad_enabled() and self._native_ok(hist, actions):
            return self._native_forecast(hist, hist_mask, actions)
        keep = self.obs_keep
        _, h_enc = self.encoder(torch.cat([hist, hist_mask], dim=-1))
        h = list(h_enc.repeat_interleave(rep, dim=1).unbind(0))
        y, m, z = self._start(hist, hist_mask, h_enc[-1])
        y, m, z = (x.repeat_interleave(rep, 0) for x in (y, m, z))
        if teacher is None and not torch.is_grad_enabled():
            return self._rollout(actions, h, y, m, z)
        e = self.E_u(actions) if self.action_conditioned else None
        ones = keep.expand(n, -1)
        use_tf = teacher is not None and tf_prob > 0.0 and self.training
        zs, cs, fs = [], [], []
        for tau in range(h_len):
            x = torch.cat([y, m] if e is None else [y, m, e[:, tau]], dim=-1)
            for i, cell in enumerate(self.decoder):
                h[i] = cell(x, h[i])
                x = h[i]
            dz, c_logit, f_logit = self.head(x).split((N_Z, 1, N_FRIC), dim=-1)
            c_logit = c_logit[:, 0]
            z = z + dz * self.delta_scale
            zs.append(z)
            cs.append(c_logit)
            fs.append(f_logit)
            if tau == h_len - 1:
                break
            y = assemble_obs(z, torch.sigmoid(c_logit), torch.softmax(f_logit, -1)) * keep
            m = ones
            if use_tf:
                assert teacher is not None
                pick = torch.rand(n, 1, device=z.device) < tf_prob
                tz = teacher["target"][:, tau]
                tm = teacher["target_mask"][:, tau]
                tc = teacher["target_c"][:, tau].to(z.dtype)
                tr = F.one_hot(teacher["target_r"][:, tau].long(), N_FRIC).to(z.dtype)
                y_true = assemble_obs(tz, tc, tr) * keep
                m_true = assemble_obs(tm, torch.ones_like(tc), torch.ones_like(tr)) * keep
                y = torch.where(pick, y_true, y)
                m = torch.where(pick, m_true, m)
                # Accumulate from the true state where it is defined.
                z = torch.where(pick & (tm > 0), tz, z)
        return {
            "z": torch.stack(zs, 1),
            "contact_logit": torch.stack(cs, 1),
            "friction_logit": torch.stack(fs, 1),
        }

    def _start(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, h_top: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The decoder's first input and the state its changes accumulate from, per history
        (B, 23), (B, 23), (B, 18): the latest observation, its mask and z_t; in the sensors
        mode the estimate of y_t from the encoder's top state ``h_top`` (B, hidden), marked
        valid."""
        if self.observation_mode == "privileged":
            return hist[:, -1], hist_mask[:, -1], last_z(hist)
        z0, c0, f0 = self.estimate(h_top).split((N_Z, 1, N_FRIC), dim=-1)
        if self.weight_reading is not None:
            # Start from what the wrist load weighs: the head learns the carried water and,
            # on the floor, where the load says nothing, the rest.
            z0 = z0.clone()
            z0[:, WATER] += weight_water(hist, self.weight_reading)
        y0 = assemble_obs(z0, torch.sigmoid(c0[:, 0]), torch.softmax(f0, -1)) * self.obs_keep
        return y0, self.obs_keep.expand_as(y0), z0

    def estimate_state(self, hist: torch.Tensor, hist_mask: torch.Tensor) -> torch.Tensor:
        """The standardised continuous state z_t (B, 18) the model starts its forecast from:
        the history's latest row, or in the sensors mode its estimate."""
        hist, hist_mask = self.prepare(hist, hist_mask)
        if self.observation_mode == "privileged":
            return last_z(hist)
        _, h_enc = self.encoder(torch.cat([hist, hist_mask], dim=-1))
        return self._start(hist, hist_mask, h_enc[-1])[2]

    def __getstate__(self) -> dict[str, Any]:
        # The native forecaster cannot be pickled or deep-copied; it is rebuilt on demand.
        state = self.__dict__.copy()
        state.pop("_native_cache", None)
        return state

    def _native_ok(self, *tensors: torch.Tensor) -> bool:
        return (
            self.native
            and self.observation_mode == "privileged"
            and os.environ.get(NATIVE_ENV, "1") != "0"
            and all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)
            and _native_class() is not None
        )

    def _native_forecast(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """The free rollout in one native call (weights copied once per weight change)."""
        key = tuple((p.data_ptr(), p._version) for p in (*self.parameters(), self.delta_scale))
        cached: tuple[Any, Any] | None = getattr(self, "_native_cache", None)
        if cached is None or cached[0] != key:
            tensors = dict(self.state_dict())
            tensors["head.weight"], tensors["head.bias"] = self._scaled_head()
            state = {
                k: v.detach().to(torch.float32).contiguous().numpy() for k, v in tensors.items()
            }
            fc = _native_class()(
                state,
                self.obs_keep.numpy(),
                ASSEMBLE_INDEX.tolist(),
                list(CONTINUOUS_INDEX),
            )
            cached = (key, fc)
            self._native_cache = cached
        z, c, f = cached[1].forecast(
            hist.detach().numpy(),
            hist_mask.detach().numpy(),
            actions.detach().numpy(),
            num_threads=max(1, torch.get_num_threads()),
        )
        return {
            "z": torch.from_numpy(z),
            "contact_logit": torch.from_numpy(c),
            "friction_logit": torch.from_numpy(f),
        }

    def _scaled_head(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The heads' weight and bias with :attr:`delta_scale` folded into the state-change
        rows, so that the inference rollouts apply the same unit as ``forward``."""
        row = torch.cat([self.delta_scale, self.delta_scale.new_ones(1 + N_FRIC)])
        return self.head.weight * row.unsqueeze(1), self.head.bias * row

    def _cells(self) -> list[nn.GRUCell]:
        return [cast(nn.GRUCell, c) for c in self.decoder]

    def _packed(self) -> _PackedDecoder:
        """The decoder's and head's weights regrouped for :meth:`_rollout`, rebuilt only when
        one of them changed (optimiser steps and ``load_state_dict`` bump ``_version``)."""
        key = tuple(
            (p.data_ptr(), p._version)
            for p in (*self.decoder.parameters(), *self.head.parameters(), self.delta_scale)
        )
        cached: tuple[Any, _PackedDecoder] | None = getattr(self, "_packed_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        keep = self.obs_keep
        cells = self._cells()
        c0 = cells[0]
        w_y = c0.weight_ih[:, :N_OBS]
        w_m = c0.weight_ih[:, N_OBS : 2 * N_OBS]
        w_q = torch.zeros_like(w_y)
        w_q[:, ASSEMBLE_INDEX.to(w_y.device)] = w_y * keep
        head_w, head_b = self._scaled_head()
        w_out, b_out = [], []
        for i, cell in enumerate(cells):
            above = cells[i + 1] if i + 1 < len(cells) else None
            above_w = above.weight_ih if above is not None else head_w
            above_b = above.bias_ih if above is not None else head_b
            w_out.append(torch.cat([above_w, cell.weight_hh], 0).t().contiguous())
            b_out.append(torch.cat([above_b, cell.bias_hh]))
        packed = _PackedDecoder(
            w_q=w_q.t().contiguous(),
            b_ih=c0.bias_ih,
            b_rest=torch.addmv(c0.bias_ih, w_m, keep),
            w_first=c0.weight_ih[:, : 2 * N_OBS].t().contiguous(),
            w_e=c0.weight_ih[:, 2 * N_OBS :].t().contiguous(),
            w_out=w_out,
            b_out=b_out,
        )
        self._packed_cache = (key, packed)
        return packed

    def _rollout(
        self,
        actions: torch.Tensor,
        h: list[torch.Tensor],
        y0: torch.Tensor,
        m0: torch.Tensor,
        z: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """Free rollout without autograd, the same equations as the loop in ``forward``
        regrouped so that each decoder step costs three matrix products instead of five
        (planning latency is dominated by per-call overhead at batch 8):

        - the commands' input gates E_u(u) W_e^T and the constant mask term enter once for
          the whole horizon (after the first step the mask is ``obs_keep``);
        - the fed-back observation enters through W_q, the input weights permuted to the
          head's [z, contact, friction] order and masked by ``obs_keep``;
        - each new hidden state is multiplied once by [next layer's input weights | its own
          recurrent weights] (the last layer: [head | recurrent]), so the recurrent gates of
          step tau+1 come out of step tau's product.

        ``h`` is the encoder state per layer and ``y0``, ``m0``, ``z`` the last observation,
        its mask and its continuous state, all already repeated per chunk by ``forward``.
        """
        hd = self.hidden
        n, h_len = actions.shape[:2]
        pk = self._packed()
        gi_first = torch.addmm(pk.b_ih, torch.cat([y0, m0], -1), pk.w_first)
        if self.action_conditioned:
            ge = self.E_u(actions) @ pk.w_e
            gi_first = gi_first + ge[:, 0]
            gi_rest = ge + pk.b_rest
        else:
            gi_rest = pk.b_rest.expand(n, h_len, -1)
        w_out, b_out, w_qt = pk.w_out, pk.b_out, pk.w_q
        cells = self._cells()
        # Every intermediate lives in a buffer allocated once, read through views made once:
        # the loop issues only arithmetic (about 20 small kernels per step).
        n_head = N_Z + 1 + N_FRIC

        def empty(*shape: int) -> torch.Tensor:
            return torch.empty(*shape, device=z.device, dtype=z.dtype)

        prod = [empty(n, w.shape[1]) for w in w_out]
        gh = [pr[:, pr.shape[1] - 3 * hd :] for pr in prod]
        for c, hi, g in zip(cells, h, gh, strict=True):
            torch.addmm(c.bias_hh, hi, c.weight_hh.t(), out=g)
        h = [hi.contiguous() for hi in h]
        gi0 = empty(n, 3 * hd)
        gates = empty(n, 2 * hd)
        cand, diff = empty(n, hd), empty(n, hd)
        r, u = gates[:, :hd], gates[:, hd:]
        heads = empty(h_len, n, n_head)
        zs = empty(h_len, n, N_Z)
        q = empty(n, N_OBS)
        q_c, q_f = q[:, N_Z : N_Z + 1], q[:, N_Z + 1 :]
        head = prod[-1][:, :n_head]
        dz, c_logit, f_logit = head[:, :N_Z], head[:, N_Z : N_Z + 1], head[:, N_Z + 1 :]
        # Input gates of each layer: [rz | n] views of their source buffers.
        below = [gi0] + [pr[:, : 3 * hd] for pr in prod[:-1]]
        gi_views = [(g[:, : 2 * hd], g[:, 2 * hd :]) for g in below]
        gh_views = [(g[:, : 2 * hd], g[:, 2 * hd :]) for g in gh]
        first_views = (gi_first[:, : 2 * hd], gi_first[:, 2 * hd :])
        for tau in range(h_len):
            if tau > 0:
                torch.addmm(gi_rest[:, tau], q, w_qt, out=gi0)
            for i in range(len(cells)):
                gi_rz, gi_n = first_views if i == 0 and tau == 0 else gi_views[i]
                gh_rz, gh_n = gh_views[i]
                torch.add(gi_rz, gh_rz, out=gates).sigmoid_()
                torch.addcmul(gi_n, r, gh_n, out=cand).tanh_()
                torch.sub(h[i], cand, out=diff)
                torch.addcmul(cand, u, diff, out=h[i])
                torch.addmm(b_out[i], h[i], w_out[i], out=prod[i])
            heads[tau].copy_(head)
            torch.add(z, dz, out=zs[tau])
            z = zs[tau]
            if tau + 1 < h_len:
                q[:, :N_Z].copy_(z)
                torch.sigmoid(c_logit, out=q_c)
                q_f.copy_(torch.softmax(f_logit, -1))
        heads_t = heads.transpose(0, 1)
        return {
            "z": zs.transpose(0, 1).contiguous(),
            "contact_logit": heads_t[..., N_Z].contiguous(),
            "friction_logit": heads_t[..., N_Z + 1 :].contiguous(),
        }


def _checked_reading(reading: Any, observation_mode: str) -> tuple[float, ...] | None:
    """``reading`` as six finite numbers with positive deviations (ValueError naming the
    argument otherwise); None stays None (the estimate head reads the water alone)."""
    if reading is None:
        return None
    if observation_mode != "sensors":
        raise ValueError("weight_reading applies to observation_mode 'sensors' only")
    try:
        values = tuple(float(v) for v in reading)
    except (TypeError, ValueError):
        values = ()
    ok = len(values) == len(WEIGHT_READING) and all(math.isfinite(v) for v in values)
    if not ok or min(values[1], values[3], values[5]) <= 0:
        raise ValueError(
            f"weight_reading must be six finite numbers ({', '.join(WEIGHT_READING)}) with "
            f"positive deviations, got {reading!r}"
        )
    return values


class ACGRUWM(GRUWorldModel):
    """AC-GRU-WM: one command per decoder step through E_u."""

    kind = "ac-gru"

    def __init__(self, **kw: Any) -> None:
        kw.pop("action_conditioned", None)
        super().__init__(action_conditioned=True, **kw)


class StateGRUWM(GRUWorldModel):
    """State-GRU-WM: the same network without E_u (ignores the actions)."""

    kind = "state-gru"

    def __init__(self, **kw: Any) -> None:
        kw.pop("action_conditioned", None)
        super().__init__(action_conditioned=False, **kw)
