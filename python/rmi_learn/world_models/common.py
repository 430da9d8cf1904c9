"""Shared interface, channel bookkeeping and losses of the world models (paper Sec. IV).

Every world model maps a standardised history, its validity mask and a standardised action
chunk to a forecast::

    out = model(hist, hist_mask, actions)   # (N, L, 23), (N, L, 23), (N, H, 2)
    out["z"]               # (N, H, 18) standardised continuous states z_{t+1..t+H}
    out["contact_logit"]   # (N, H)     logit of c_{t+tau}
    out["friction_logit"]  # (N, H, 4)  logits over FRICTION_CLASSES

A GRU model built with ``observation_mode="sensors"`` reads instead a history of what the
gripper's sensors report, (N, L, 17) (``SENSOR_INPUTS``, mask all ones), estimates y_t from
it and forecasts the same outputs.

Recurrent decoders also accept ``teacher=batch`` and ``tf_prob`` (teacher forcing: at each step
and per sample, with probability ``tf_prob``, the next decoder input is the ground truth
instead of the model's own prediction). Use :meth:`WorldModel.predict` for inference
(eval mode, no gradients, probabilities instead of logits).

State-group ablation (paper Eq. 7): a model built with ``state_groups="LS"`` etc. zeroes the
excluded observation channels *and* their mask entries on input (zero is also the standardised
training mean, and mask 0 says "not available", exactly like a missing value), and the same
channels are zeroed in the recurrent decoder's fed-back predictions. :func:`wm_loss` then
scores only the continuous channels of the kept groups, and the contact/friction losses only
when group C is kept: the ablated model is a world model *of that state*.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS
from rmi_learn.data.schema import (
    CONTACT_INDEX,
    CONTINUOUS,
    CONTINUOUS_INDEX,
    CONTROL_ACTIONS,
    FRICTION_CLASSES,
    FRICTION_SLICE,
    OBS,
)
from rmi_learn.sensing import OBSERVATION_MODES

N_OBS = len(OBS)  # 23
N_Z = len(CONTINUOUS)  # 18
N_U = len(CONTROL_ACTIONS)  # 1: the force setpoint
N_FRIC = len(FRICTION_CLASSES)  # 4
#: Index of retained water M_L and measured force F_meas within z (the 18 continuous entries).
WATER = CONTINUOUS.index("M_L")
FORCE = CONTINUOUS.index("F_meas")

#: The four state groups of paper Eq. 7, by observation name.
STATE_GROUPS: dict[str, tuple[str, ...]] = {
    "LS": ("M_L", "S", "V_pore", "V_sponge"),
    "G": ("w", "F_meas", "F_L", "F_R", "alpha_F"),
    "C": (
        "A_L",
        "A_R",
        "c",
        "v_tan_x",
        "v_tan_y",
        "v_tan_z",
        "F_fric_x",
        "F_fric_y",
        "F_fric_z",
        "r_none",
        "r_stick",
        "r_slip",
        "r_mixed",
    ),
    "R": ("v_res",),
}
#: The ablation settings of Table IV.
GROUP_SETS: dict[str, tuple[str, ...]] = {
    "LS": ("LS",),
    "LS+G": ("LS", "G"),
    "LS+G+C": ("LS", "G", "C"),
    "ALL": ("LS", "G", "C", "R"),
}

# Position of each OBS entry in cat([z (18), c (1), r (4)]).
ASSEMBLE_INDEX = torch.tensor(
    [
        CONTINUOUS_INDEX.index(j)
        if j in CONTINUOUS_INDEX
        else (N_Z if j == CONTACT_INDEX else N_Z + 1 + (j - FRICTION_SLICE.start))
        for j in range(N_OBS)
    ]
)


def obs_keep(state_groups: str = "ALL") -> torch.Tensor:
    """(23,) float mask: 1 for observation channels in the groups of ``state_groups``."""
    if state_groups not in GROUP_SETS:
        raise ValueError(f"state_groups must be one of {list(GROUP_SETS)}, got {state_groups!r}")
    names = {n for g in GROUP_SETS[state_groups] for n in STATE_GROUPS[g]}
    return torch.tensor([1.0 if n in names else 0.0 for n in OBS])


def assemble_obs(z: torch.Tensor, c: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Build (..., 23) observations in OBS order from z (..., 18), contact (...,) and friction
    probabilities or one-hot (..., 4)."""
    cat = torch.cat([z, c.unsqueeze(-1), r], dim=-1)
    return cat.index_select(-1, ASSEMBLE_INDEX.to(cat.device))


def last_z(hist: torch.Tensor) -> torch.Tensor:
    """Latest standardised continuous state z_t (N, 18) from a history (N, L, 23)."""
    return hist[:, -1, list(CONTINUOUS_INDEX)]


def constructor_defaults(cls: type) -> dict[str, Any]:
    """The default values of the constructor arguments of ``cls``: those of the nearest
    ``__init__`` in its class hierarchy that names its arguments (one that only passes
    ``**kw`` on to its base is skipped)."""
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters.values()
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
            continue
        return {p.name: p.default for p in params if p.default is not inspect.Parameter.empty}
    return {}


def _argument_kind(default: Any, value: Any) -> str | None:
    """What ``value`` must be to stand for an argument of default ``default``; None if it is
    that (or the default is of no kind checked here)."""
    if isinstance(default, bool):
        return None if isinstance(value, bool) else "true or false"
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, int):
        return None if number and isinstance(value, int) and value >= 1 else "a whole number >= 1"
    if isinstance(default, float):
        return None if number and math.isfinite(value) else "a finite number"
    if isinstance(default, str):
        return None if isinstance(value, str) else "a name (text)"
    return None


class WorldModel(nn.Module):
    """Base class: input masking for the state-group ablation, config, predict()."""

    obs_keep: torch.Tensor
    z_keep: torch.Tensor

    kind: str = "base"
    #: False for closed-form or parameter-free models (Baseline, Linear-ARX).
    trainable: bool = True
    #: True for recurrent decoders that accept teacher forcing.
    recurrent: bool = False
    #: The only horizon a lookahead model accepts (None: any horizon up to ``max_horizon``).
    fixed_horizon: int | None = None
    max_horizon: int | None = None

    #: Whether the model can read the ``sensors`` observation mode instead of y_t.
    takes_sensors: bool = False

    def __init__(self, state_groups: str = "ALL", observation_mode: str = "privileged") -> None:
        super().__init__()
        if observation_mode not in OBSERVATION_MODES:
            raise ValueError(
                f"observation_mode must be one of {', '.join(OBSERVATION_MODES)}, "
                f"got {observation_mode!r}"
            )
        if observation_mode == "sensors" and not self.takes_sensors:
            raise ValueError(f"{self.kind} reads y_t only, not observation_mode 'sensors'")
        if observation_mode == "sensors" and state_groups != "ALL":
            raise ValueError(
                "state_groups must be ALL with observation_mode 'sensors' (the groups are "
                f"y_t's), got {state_groups!r}"
            )
        self.observation_mode = observation_mode
        #: Channels of a history row: y_t's 23 or the sensor mode's inputs.
        self.n_inputs = N_OBS if observation_mode == "privileged" else len(SENSOR_INPUTS)
        self.state_groups = state_groups
        keep = obs_keep(state_groups)
        self.register_buffer("obs_keep", keep, persistent=False)
        self.register_buffer("z_keep", keep[list(CONTINUOUS_INDEX)].clone(), persistent=False)
        self.register_buffer("delta_scale", torch.ones(N_Z), persistent=False)
        self.classify = bool(keep[CONTACT_INDEX] > 0)

    def set_delta_scale(self, scale: Any) -> None:
        """Set the unit of each continuous channel's predicted change per step, (18,) in
        standardised units (see :func:`step_scale`): the network's state-change outputs are
        multiplied by it. With unit outputs for every channel, one optimiser step moves a slow
        channel's forecast (retained water changes by a few hundredths of its spread in a
        horizon) by as little as a fast one's, relative to how far each moves. Models that
        accumulate no predicted change ignore it."""
        values = torch.as_tensor(scale, dtype=torch.float32).reshape(-1)
        if values.shape != (N_Z,) or not bool(torch.all(torch.isfinite(values) & (values > 0))):
            raise ValueError(f"delta_scale must be {N_Z} positive finite numbers, got {scale!r}")
        self.delta_scale.copy_(values)

    def config(self) -> dict[str, Any]:
        """JSON that rebuilds this model with :func:`rmi_learn.world_models.build`."""
        cfg: dict[str, Any] = {"kind": self.kind, "state_groups": self.state_groups}
        if self.observation_mode != "privileged":
            cfg["observation_mode"] = self.observation_mode
        if not bool(torch.all(self.delta_scale == 1.0)):
            cfg["delta_scale"] = [float(v) for v in self.delta_scale]
        return cfg

    @classmethod
    def check_arguments(cls, args: Mapping[str, Any]) -> None:
        """Raise ValueError naming the argument unless each of the constructor arguments
        ``args`` is of its default's kind: a whole number >= 1 for a size or count, a
        finite number for a real one, true or false for a switch, text for a name. Names
        the constructor does not take are left to it (TypeError). A model with further
        rules adds them in its override."""
        defaults = constructor_defaults(cls)
        for name, value in args.items():
            if name not in defaults:
                continue
            want = _argument_kind(defaults[name], value)
            if want is not None:
                raise ValueError(f"{cls.kind}: {name} must be {want}, got {value!r}")

    def prepare(
        self, hist: torch.Tensor, hist_mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Zero channels outside the model's state groups (value and mask); a history of
        the sensors passes as it is."""
        if self.observation_mode == "sensors":
            return hist, hist_mask
        return hist * self.obs_keep, hist_mask * self.obs_keep

    def check_horizon(self, actions: torch.Tensor) -> int:
        return self.check_horizon_length(actions.shape[1])

    def check_horizon_length(self, h: int) -> int:
        """``h`` if the model can forecast chunks of ``h`` steps, else ValueError."""
        if self.fixed_horizon is not None and h != self.fixed_horizon:
            raise ValueError(
                f"{self.kind} sees the whole chunk: horizon must be {self.fixed_horizon}, got {h}"
            )
        if self.max_horizon is not None and h > self.max_horizon:
            raise ValueError(f"{self.kind}: horizon {h} exceeds max_horizon {self.max_horizon}")
        return h

    @torch.no_grad()
    def predict(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """Free rollout in eval mode: ``z`` (N, H, 18) standardised, ``p_contact`` (N, H),
        ``p_friction`` (N, H, 4) probabilities. Inputs are standardised as in the dataset."""
        return self.forecast(hist, hist_mask, actions)

    def forecast(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """:meth:`predict` under the caller's gradient mode: differentiable in ``actions``
        when gradients are enabled (model-based refinement of a chunk)."""
        was = self.training
        self.eval()
        try:
            out = self(hist, hist_mask, actions)
        finally:
            self.train(was)
        return {
            "z": out["z"],
            "p_contact": torch.sigmoid(out["contact_logit"]),
            "p_friction": torch.softmax(out["friction_logit"], dim=-1),
        }


def wm_loss(
    out: dict[str, torch.Tensor],
    batch: dict[str, torch.Tensor],
    *,
    gamma: float = 0.98,
    lambda_c: float = 0.2,
    lambda_f: float = 0.2,
    channel_weight: torch.Tensor | None = None,
    z_keep: torch.Tensor | None = None,
    classify: bool = True,
    huber_delta: float = 1.0,
    channel_scale: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """World-model loss (paper Eq. 12, supplement S3), all terms dimensionless.

    L = L_cont + lambda_c L_BCE + lambda_f L_CE. L_cont is the Huber error per channel and
    step weighted by gamma^(tau-1) * channel_weight[d] * target_mask * z_keep[d], summed and
    divided by the sum of those weights (the number of valid weighted elements, never a
    plain mean over invalid entries). With ``channel_scale`` (18,), prediction and target of
    channel d are divided by ``channel_scale[d]`` before the Huber error, so that each error
    is measured against how far that channel moves (see :func:`change_scale`). The
    classification losses are discounted the same way and divided by N * sum_tau
    gamma^(tau-1).
    """
    z = out["z"]
    n, h, d = z.shape
    target = batch["target"][:, :h]
    w = batch["target_mask"][:, :h].to(z.dtype)
    disc = gamma ** torch.arange(h, dtype=z.dtype, device=z.device)
    w = w * disc.view(1, h, 1)
    if channel_weight is not None:
        w = w * channel_weight.to(z).view(1, 1, d)
    if z_keep is not None:
        w = w * z_keep.to(z).view(1, 1, d)
    if channel_scale is not None:
        inv = 1.0 / channel_scale.to(z).view(1, 1, d)
        z, target = z * inv, target * inv
    hub = F.huber_loss(z, target, reduction="none", delta=huber_delta)
    l_cont = (w * hub).sum() / w.sum().clamp_min(1e-8)
    logs = {"l_cont": float(l_cont.detach())}
    loss = l_cont
    if classify:
        norm = n * disc.sum()
        bce = F.binary_cross_entropy_with_logits(
            out["contact_logit"], batch["target_c"][:, :h].to(z.dtype), reduction="none"
        )
        l_c = (bce * disc).sum() / norm
        ce = F.cross_entropy(
            out["friction_logit"].reshape(n * h, -1),
            batch["target_r"][:, :h].reshape(-1).long(),
            reduction="none",
        ).view(n, h)
        l_f = (ce * disc).sum() / norm
        loss = loss + lambda_c * l_c + lambda_f * l_f
        logs.update(l_contact=float(l_c.detach()), l_friction=float(l_f.detach()))
    return loss, logs


def _masked_rms(
    ws: Any,
    changes: Callable[[dict[str, torch.Tensor]], tuple[torch.Tensor, torch.Tensor]],
    batch_size: int,
    floor: float,
) -> torch.Tensor:
    """Per-channel RMS, (18,), of the changes ``changes(batch)`` returns with their weights
    (both float64, channels last) over the windows of ``ws``, floored at ``floor``."""
    total = torch.zeros(N_Z, dtype=torch.float64)
    count = torch.zeros(N_Z, dtype=torch.float64)
    for s in range(0, len(ws), batch_size):
        d, w = changes(ws.batch(np.arange(s, min(s + batch_size, len(ws)))))
        total += (w * d * d).sum(dim=(0, 1))
        count += w.sum(dim=(0, 1))
    rms = (total / count.clamp_min(1.0)).sqrt()
    return rms.clamp_min(floor).to(torch.float32)


def _now(b: dict[str, torch.Tensor]) -> torch.Tensor:
    """Each window's true continuous state z_t, (N, 18): its ``z_now`` (a sensor-mode
    history does not hold it), else the history's latest row."""
    return b["z_now"] if "z_now" in b else last_z(b["hist"])


def _latest_mask(b: dict[str, torch.Tensor]) -> torch.Tensor:
    """Validity of each window's latest continuous state, (N, 1, 18)."""
    if "z_now_mask" in b:
        return b["z_now_mask"].unsqueeze(1)
    return b["hist_mask"][:, -1, list(CONTINUOUS_INDEX)].unsqueeze(1)


def change_scale(ws: Any, batch_size: int = 1024, floor: float = 1e-3) -> torch.Tensor:
    """Root-mean-square forecast change of each continuous channel, (18,), standardised units.

    The RMS over the windows of ``ws`` and every horizon step of ``target - z_t`` (z_t the
    window's latest state), where both are valid, floored at ``floor``. Standardised levels
    make channels comparable in size but not in how much they move within a horizon: at the
    study resolution retained water changes by about 1/80 of its level's spread in 0.64 s,
    the grip force by half of it. This is the scale that ``--loss-scale change`` divides by.
    """

    def changes(b: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        d = (b["target"] - _now(b).unsqueeze(1)).to(torch.float64)
        return d, (b["target_mask"] * _latest_mask(b)).to(torch.float64)

    return _masked_rms(ws, changes, batch_size, floor)


def step_scale(ws: Any, batch_size: int = 1024, floor: float = 1e-4) -> torch.Tensor:
    """Root-mean-square change of each continuous channel from one control step to the next,
    (18,), standardised units: over the windows of ``ws``, the steps ``z_t -> z_{t+1}`` and
    ``z_{t+k} -> z_{t+k+1}`` of every forecast where both ends are valid, floored at
    ``floor``. The unit of the learned models' predicted change
    (:meth:`WorldModel.set_delta_scale`)."""

    def changes(b: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        z = torch.cat([_now(b).unsqueeze(1), b["target"]], dim=1).to(torch.float64)
        m = torch.cat([_latest_mask(b), b["target_mask"]], dim=1).to(torch.float64)
        return z[:, 1:] - z[:, :-1], m[:, 1:] * m[:, :-1]

    return _masked_rms(ws, changes, batch_size, floor)


def shuffled_pairing(run: np.ndarray, seed: int = 0) -> np.ndarray:
    """Permutation p of window indices with run[p[i]] != run[i] wherever possible.

    Giving window i the action chunk of window p[i] pairs each history with a chunk from
    another trajectory while keeping the marginal distribution of chunks exactly (p is a
    permutation). Deterministic in ``seed``.
    """
    run = np.asarray(run)
    n = len(run)
    rng = np.random.default_rng([seed, 0xAC7])
    p = rng.permutation(n)
    if len(np.unique(run)) < 2:
        return p
    for _ in range(100):
        bad = np.flatnonzero(run[p] == run)
        if len(bad) == 0:
            break
        # Swap each clash with a random partner; a swap is kept only if it fixes both ends.
        partners = rng.integers(0, n, size=len(bad))
        for i, j in zip(bad, partners, strict=True):
            if run[p[j]] != run[i] and run[p[i]] != run[j]:
                p[i], p[j] = p[j], p[i]
    return p


class ShuffledActions:
    """A window set whose action chunks come from other runs (shuffled-action ablation).

    Wraps any object with ``batch(indices)``, ``__len__`` and ``run_ids``/per-window runs;
    everything except ``actions`` is unchanged.
    """

    def __init__(self, base: Any, seed: int = 0, runs: np.ndarray | None = None) -> None:
        self.base = base
        if runs is None:
            runs = window_runs(base)
        self.perm = shuffled_pairing(runs, seed)

    def __len__(self) -> int:
        return len(self.base)

    def batch(self, indices: Any) -> dict[str, torch.Tensor]:
        idx = np.asarray(indices, dtype=np.int64)
        b = dict(self.base.batch(idx))
        b["actions"] = self.base.batch(self.perm[idx])["actions"]
        return b

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


class Subset:
    """The first ``n`` (or given) windows of a window set, keeping ``batch(indices)``."""

    def __init__(self, base: Any, indices: np.ndarray) -> None:
        self.base = base
        self.indices = np.asarray(indices, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.indices)

    def batch(self, indices: Any) -> dict[str, torch.Tensor]:
        out: dict[str, torch.Tensor] = self.base.batch(
            self.indices[np.asarray(indices, dtype=np.int64)]
        )
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


def window_runs(ws: Any, batch_size: int = 4096) -> np.ndarray:
    """Run number of every window of a window set (from its ``run`` field)."""
    if isinstance(ws, Subset):
        return window_runs(ws.base)[ws.indices]
    if isinstance(ws, ShuffledActions):
        return window_runs(ws.base)
    if hasattr(ws, "anchors") and hasattr(ws, "data"):  # rmi_learn.data.dataset.WindowSet
        return np.asarray(np.asarray(ws.data.row_run)[ws.anchors])
    out = []
    for s in range(0, len(ws), batch_size):
        idx = np.arange(s, min(s + batch_size, len(ws)))
        out.append(np.asarray(ws.batch(idx)["run"]).reshape(-1))
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)
