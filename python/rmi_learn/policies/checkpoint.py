"""Build, batch helpers and loading of trained policies (run directories of train-policy).

A policy run directory (written by ``rmi train-policy`` through :mod:`rmi_learn.trainer`)
holds ``config.json`` (``config["model"]`` as written by :func:`model_config`),
``model.safetensors`` (live weights of the selected epoch) and ``model.ema.safetensors``
(EMA weights of the same epoch, used for sampling).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from rmi_learn.policies import OBJECTIVES, POLICY_HORIZON
from rmi_learn.policies.diffusion import DiffusionObjective
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import PolicyUNet, UNetConfig

#: Index of M_L in the 18 continuous channels (schema.CONTINUOUS[0]).
WATER = 0

Objective = DiffusionObjective | FlowObjective


def make_objective(name: str, **kwargs: Any) -> Objective:
    """``"diffusion"`` -> :class:`DiffusionObjective`, ``"flow"`` -> :class:`FlowObjective`."""
    if name == "diffusion":
        return DiffusionObjective(**kwargs)
    if name == "flow":
        return FlowObjective(**kwargs)
    raise ValueError(f"objective must be one of {OBJECTIVES}, got {name!r}")


def model_config(unet: UNetConfig, objective: Objective, history: int) -> dict[str, Any]:
    """The ``config["model"]`` JSON of a policy run."""
    cfg = objective.config()
    name = cfg.pop("objective")
    return {
        "kind": "policy-unet",
        "objective": name,
        "objective_config": cfg,
        "unet": unet.to_dict(),
        "history": history,
        "horizon": unet.horizon,
    }


def goal_from_batch(batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """Training goal of dataset windows: ``g`` = standardised M_L at ``t + H`` (the last
    target row) and the goal vector ``[g, g - M_L(t)]`` (N, 2), both in units of the
    training-split M_L std (the difference has no mean shift)."""
    g = batch["target"][:, -1, WATER]
    return g, torch.stack([g, g - batch["water_now"]], dim=-1)


def load_policy(
    out_dir: str | Path, weights: str = "model.ema", device: str = "cpu"
) -> tuple[PolicyUNet, Objective, dict[str, Any]]:
    """Rebuild a trained policy: (network in eval mode, objective, config.json).

    ``weights`` names the safetensors file without suffix: ``model.ema`` (default, the
    sampling weights) or ``model`` (live weights of the selected epoch). A ``model.unet``
    field of the wrong kind raises ValueError naming the config file and the field.
    """
    from rmi_learn.trainer import CONFIG_FILE, load_weights, read_config

    cfg = read_config(out_dir)
    m = cfg["model"]
    if m.get("kind") != "policy-unet":
        raise ValueError(f"{out_dir} is not a policy run (model kind {m.get('kind')!r})")
    try:
        unet = UNetConfig.from_dict(m["unet"])
    except ValueError as exc:
        raise ValueError(f"{Path(out_dir) / CONFIG_FILE}: model.{exc}") from exc
    net = PolicyUNet(unet)
    load_weights(net, out_dir, which=weights)
    objective = make_objective(m["objective"], **m["objective_config"])
    return net.to(device).eval(), objective, cfg


__all__ = [
    "POLICY_HORIZON",
    "goal_from_batch",
    "load_policy",
    "make_objective",
    "model_config",
]
