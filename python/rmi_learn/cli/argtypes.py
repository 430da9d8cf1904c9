"""Argument types for the ``rmi`` commands: numbers checked where they are parsed.

An out-of-range value then fails like any other bad argument, as argparse's usage error
naming the option and the accepted range (exit status 2), before a command creates its
output directory or starts work (``--epochs 0`` would otherwise write a finished run with
no training, ``--batch-size 0`` fail deep inside the data loader).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def count(low: int) -> Callable[[str], int]:
    """An integer of at least ``low``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected an integer >= {low}, got {text!r}"
            ) from None
        if value < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {value}")
        return value

    return parse


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
