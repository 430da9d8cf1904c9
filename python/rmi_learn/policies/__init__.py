"""Goal-conditioned UNet policies (diffusion and rectified flow), their training, world-model
ranking and closed-loop execution in the simulator.

Modules: :mod:`~rmi_learn.policies.unet` (the shared temporal UNet),
:mod:`~rmi_learn.policies.diffusion` (cosine schedule, x0 prediction, min-SNR, DDIM),
:mod:`~rmi_learn.policies.flow` (rectified flow, Euler sampling),
:mod:`~rmi_learn.policies.ema` (EMA with decay warm-up),
:mod:`~rmi_learn.policies.checkpoint` (policy run directories),
:mod:`~rmi_learn.policies.training` (``rmi train-policy``),
:mod:`~rmi_learn.policies.ranking` (K-sample proposals scored by the world model, ``rmi rank``)
and :mod:`~rmi_learn.policies.closed_loop` (``rmi closed-loop``).
Import torch-heavy submodules explicitly; this package file imports nothing heavy.
"""

from __future__ import annotations

#: Policy chunk length H_pi (control steps of 20 ms).
POLICY_HORIZON = 32
#: Objectives accepted by ``rmi train-policy --objective``.
OBJECTIVES = ("diffusion", "flow")

__all__ = ["OBJECTIVES", "POLICY_HORIZON"]
