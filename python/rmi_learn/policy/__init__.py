"""Goal-conditioned UNet policies (diffusion and rectified flow) and world-model ranking.

Modules: :mod:`~rmi_learn.policy.unet` (the shared temporal UNet),
:mod:`~rmi_learn.policy.diffusion` (cosine schedule, x0 prediction, min-SNR, DDIM),
:mod:`~rmi_learn.policy.flow` (rectified flow, Euler sampling),
:mod:`~rmi_learn.policy.ema` (EMA with decay warm-up) and
:mod:`~rmi_learn.policy.ranking` (K-sample proposals scored by the world model).
Import torch-heavy submodules explicitly; this package file imports nothing heavy.
"""

from __future__ import annotations

#: Policy chunk length H_pi (control steps of 20 ms).
POLICY_HORIZON = 32
#: Objectives accepted by ``rmi train-policy --objective``.
OBJECTIVES = ("diffusion", "flow")

__all__ = ["OBJECTIVES", "POLICY_HORIZON"]
