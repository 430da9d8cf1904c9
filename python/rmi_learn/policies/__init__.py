"""Goal-conditioned UNet policies (diffusion and rectified flow), their training, world-model
ranking and closed-loop execution in the simulator.

Modules: :mod:`~rmi_learn.policies.unet` (the shared temporal UNet),
:mod:`~rmi_learn.policies.diffusion` (cosine schedule, x0 prediction, min-SNR, DDIM),
:mod:`~rmi_learn.policies.flow` (rectified flow, Euler sampling),
:mod:`~rmi_learn.policies.ema` (EMA with decay warm-up),
:mod:`~rmi_learn.policies.checkpoint` (policy run directories),
:mod:`~rmi_learn.policies.training` (``rmi train-policy``),
:mod:`~rmi_learn.policies.ranking` (K-sample proposals scored by the world model, ``rmi rank``),
:mod:`~rmi_learn.policies.policy` (a trained policy as one object: :func:`load_policy`,
:class:`Policy`) and :mod:`~rmi_learn.policies.closed_loop` (``rmi closed-loop``).
Import torch-heavy submodules explicitly; this package file imports nothing heavy
(``load_policy`` and ``Policy`` are loaded on first use).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rmi_learn.policies.policy import Policy, load_policy

#: Policy chunk length H_pi (control steps of 20 ms).
POLICY_HORIZON = 32
#: Objectives accepted by ``rmi train-policy --objective``.
OBJECTIVES = ("diffusion", "flow")

#: Names this package gives from :mod:`~rmi_learn.policies.policy`, imported on first use.
_LAZY = ("Policy", "load_policy")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from rmi_learn.policies import policy

        return getattr(policy, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["OBJECTIVES", "POLICY_HORIZON", "Policy", "load_policy"]
