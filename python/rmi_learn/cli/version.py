"""``rmi --version``: the installed distribution's version and the engine's."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any


def version_text() -> str:
    """``rmi X.Y.Z``, with ``(engine A.B.C)`` appended when the native engine module
    reports another version (a stale build beside newer Python sources) or cannot be
    imported."""
    from rmi_learn import __version__ as package

    try:
        import rmi_sph

        engine = str(rmi_sph.__version__)
    except ImportError as exc:
        engine = f"not importable: {exc}"
    # A source tree that was never installed has no distribution metadata; the engine is
    # built from the same version number (maturin reads it from Cargo.toml).
    if package.startswith("0.0.0+unknown") and not engine.startswith("not importable"):
        package = engine
    return f"rmi {package}" if engine == package else f"rmi {package} (engine {engine})"


class VersionAction(argparse.Action):
    """``--version``: print :func:`version_text` and exit 0 (the text is made when asked,
    not each time the parser is built)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.setdefault("help", "print the package and engine versions and exit")
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        print(version_text())
        parser.exit()
