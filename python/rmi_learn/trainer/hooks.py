"""Extension points of the training loop (:class:`Hook`) and the exponential moving average
of the weights (:class:`EMA`)."""

from __future__ import annotations

from typing import Any, Protocol

import torch

from rmi_learn.trainer.config import TrainState


class Trainer(Protocol):
    """What a hook sees of the training loop (:class:`rmi_learn.trainer.loop.Trainer`): the
    model being trained and the loop's position."""

    model: torch.nn.Module
    state: TrainState


class Hook:
    """Extension point (e.g. EMA weights). Override what you need; all methods are optional."""

    #: names the extra weight files: ``model.<name>.safetensors``
    name: str = "hook"

    def on_fit_start(self, trainer: Trainer) -> None:
        """Called once per ``fit`` after the state was created or restored."""

    def on_step_end(self, trainer: Trainer) -> None:
        """Called after every optimiser step (``trainer.state.step`` already counts it)."""

    def on_epoch_end(self, trainer: Trainer, metrics: dict[str, float]) -> None:
        """Called after evaluation at the end of each epoch; may add entries to ``metrics``."""

    def state_dict(self) -> dict[str, Any]:
        """Resume state (tensors and plain Python values)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned."""

    def weights(self) -> dict[str, torch.Tensor]:
        """Extra weights to save next to the selected checkpoint ({} for none)."""
        return {}


class EMA(Hook):
    """Exponential moving average of the parameters with a warmed-up decay.

    decay(n) = min(max_decay, 1 - (1 + n)^-power) after n updates, so early weights are
    forgotten quickly (a constant 0.999 from step 0 would keep 37 % of the initial weights
    after 1000 steps). ``with ema.applied(model): ...`` evaluates with the averaged weights;
    the averaged weights are saved as ``model.ema.safetensors`` with the selected checkpoint.
    """

    name = "ema"

    def __init__(self, max_decay: float = 0.999, power: float = 0.75) -> None:
        self.max_decay = max_decay
        self.power = power
        self.updates = 0
        self.shadow: dict[str, torch.Tensor] = {}

    def decay(self) -> float:
        """Decay used for the next update (dimensionless)."""
        return float(min(self.max_decay, 1.0 - (1.0 + self.updates) ** -self.power))

    def _init(self, model: torch.nn.Module) -> None:
        self.shadow = {k: v.detach().clone() for k, v in model.state_dict().items()}

    def on_fit_start(self, trainer: Trainer) -> None:
        if not self.shadow:
            self._init(trainer.model)

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        """One EMA update from the live weights of ``model``."""
        if not self.shadow:
            self._init(model)
        d = self.decay()
        for k, v in model.state_dict().items():
            s = self.shadow[k]
            if v.dtype.is_floating_point:
                s.mul_(d).add_(v.detach(), alpha=1.0 - d)
            else:
                s.copy_(v)
        self.updates += 1

    def on_step_end(self, trainer: Trainer) -> None:
        self.update(trainer.model)

    def state_dict(self) -> dict[str, Any]:
        return {"updates": self.updates, "shadow": dict(self.shadow)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.updates = int(state["updates"])
        self.shadow = {k: v.clone() for k, v in state["shadow"].items()}

    def weights(self) -> dict[str, torch.Tensor]:
        return dict(self.shadow)

    def applied(self, model: torch.nn.Module) -> _Swap:
        """Context manager: ``model`` holds the EMA weights inside, its live weights after."""
        return _Swap(model, self.shadow)


class _Swap:
    def __init__(self, model: torch.nn.Module, weights: dict[str, torch.Tensor]) -> None:
        self.model, self.weights = model, weights
        self.saved: dict[str, torch.Tensor] = {}

    def __enter__(self) -> torch.nn.Module:
        self.saved = {k: v.detach().clone() for k, v in self.model.state_dict().items()}
        self.model.load_state_dict(self.weights)
        return self.model

    def __exit__(self, *exc: object) -> None:
        self.model.load_state_dict(self.saved)
