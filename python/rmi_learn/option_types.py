"""Option types: the values of the ``rmi`` commands' options (and of the pipeline presets'
options, which are those of the commands) checked where they are parsed.

An out-of-range value then fails like any other bad argument, as argparse's usage error
naming the option and the accepted range (exit status 2), before a command creates its
output directory or starts work (``--epochs 0`` would otherwise write a finished run with
no training, ``--batch-size 0`` fail deep inside the data loader); a pipeline preset with
such a value is refused when it is read.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from rmi_learn.data.schema import SEED_MAX

#: Largest count an option takes (epochs, threads, batch sizes, steps): the C ``int`` that
#: torch and the engine's u32 fields both hold.
COUNT_MAX = 2**31 - 1


def count(low: int, high: int = COUNT_MAX) -> Callable[[str], int]:
    """An integer in ``[low, high]``; the error names the range (argparse adds the option)."""
    span = f"an integer in [{low}, {high}]"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {span}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected {span}, got {value}")
        return value

    return parse


#: A seed: an integer in [0, SEED_MAX], the engine's range (run files store seeds as Int64;
#: torch takes them too).
seed = count(0, SEED_MAX)


def device(text: str) -> str:
    """A torch device name whose device exists here: ``cpu`` (no torch import), ``cuda``,
    ``cuda:N`` or ``mps``. A missing accelerator is a usage error, not a traceback from the
    first tensor moved to it."""
    if text == "cpu":
        return text
    try:
        import torch
    except ImportError:
        raise argparse.ArgumentTypeError(
            f"{text}: torch is not installed (pip install 'rmi[learn]')"
        ) from None

    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"expected cpu, cuda, cuda:N or mps, got {text!r}"
        ) from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise argparse.ArgumentTypeError(
                f"{text}: CUDA is not available on this machine (use --device cpu)"
            )
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise argparse.ArgumentTypeError(
                f"{text}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    elif dev.type == "mps" and not torch.backends.mps.is_available():
        raise argparse.ArgumentTypeError(f"{text}: MPS is not available on this machine")
    elif dev.type not in ("cpu", "cuda", "mps"):
        raise argparse.ArgumentTypeError(f"expected cpu, cuda, cuda:N or mps, got {text!r}")
    return text


def real(
    low: float, high: float = math.inf, *, low_open: bool = False, high_open: bool = False
) -> Callable[[str], float]:
    """A finite number in the interval from ``low`` to ``high`` (ends closed unless open)."""
    left, right = "(" if low_open else "[", ")" if high_open else "]"
    span = f"{left}{low:g}, {high:g}{right}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in {span}, got {text!r}") from None
        below = value <= low if low_open else value < low
        above = value >= high if high_open else value > high
        if not math.isfinite(value) or below or above:
            raise argparse.ArgumentTypeError(f"expected a finite number in {span}, got {text}")
        return value

    return parse


def counts(text: str) -> tuple[int, ...]:
    """Comma-separated integers >= 1 (layer widths)."""
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers such as 64,128,256, got {text!r}"
        ) from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected integers >= 1, got {text!r}")
    return values


#: A positive finite number (learning rates, loss weights, force limits).
positive = real(0.0, low_open=True)
#: A finite number >= 0 (weight decay, floors).
non_negative = real(0.0)
