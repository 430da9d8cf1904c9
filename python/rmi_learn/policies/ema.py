"""EMA of the policy weights with a warm-up of the decay.

A constant decay of 0.999 from step 0 still holds ``0.999^1000 = 37 %`` of the random
initial weights after 1000 updates. The decay therefore warms up as
``decay(n) = min(1 - (1 + n)^-power, max_decay)`` with ``power = 0.75`` and
``max_decay = 0.999`` (``n`` = number of updates already applied): the first update copies
the live weights and the average forgets the initialisation quickly.

The averaging itself is the shared training loop's hook :class:`rmi_learn.trainer.EMA`
(re-exported here) so the policy and the world models use one implementation;
:func:`ema_decay` states the formula and ``tests/policies/test_policy.py`` pins the hook to it. The
policy trainer computes the validation loss with the live weights and samples, selects and
saves checkpoints with the EMA weights (``model.ema.safetensors``).
"""

from __future__ import annotations

from rmi_learn.trainer import EMA

__all__ = ["EMA", "ema_decay"]


def ema_decay(n_updates: int, power: float = 0.75, max_decay: float = 0.999) -> float:
    """Warm-up EMA decay after ``n_updates`` previous updates: ``min(1-(1+n)^-p, max)``."""
    if n_updates < 0:
        raise ValueError("n_updates must be >= 0")
    return min(1.0 - float((1.0 + n_updates) ** (-power)), max_decay)
