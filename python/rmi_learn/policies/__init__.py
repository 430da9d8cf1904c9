"""Goal-conditioned UNet policies (diffusion and rectified flow) and their training.

Modules: :mod:`~rmi_learn.policies.unet` (the shared temporal UNet),
:mod:`~rmi_learn.policies.diffusion` (cosine schedule, x0 prediction, min-SNR, DDIM),
:mod:`~rmi_learn.policies.flow` (rectified flow, Euler sampling),
:mod:`~rmi_learn.policies.fast_sampler` (the samplers with less work per call),
:mod:`~rmi_learn.policies.ema` (EMA with decay warm-up),
:mod:`~rmi_learn.policies.checkpoint` (policy run directories),
:mod:`~rmi_learn.policies.policy` (a run's statistics and stored world model),
:mod:`~rmi_learn.policies.training` (``rmi train-policy``) and
:mod:`~rmi_learn.policies.distill` (``rmi distill-policy``). Sampling and ranking with a world
model, and the policy as one object that acts, are in :mod:`rmi_learn.planning`.
Import torch-heavy submodules explicitly; this package file imports nothing heavy.
"""

#: Policy chunk length H_pi (control steps of 20 ms).
POLICY_HORIZON = 32
#: Objectives accepted by ``rmi train-policy --objective``.
OBJECTIVES = ("diffusion", "flow")

__all__ = ["OBJECTIVES", "POLICY_HORIZON"]
