"""``rmi --version``: the package version, and the engine's when it differs."""

from __future__ import annotations

import subprocess
import sys

import pytest

import rmi_sph
from rmi_learn import __version__
from rmi_learn.cli import main


def test_version_prints_the_package_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    line = capsys.readouterr().out.strip()
    expected = __version__ if not __version__.startswith("0.0.0+") else rmi_sph.__version__
    assert line.startswith(f"rmi {expected}")
    if rmi_sph.__version__ == expected:
        assert line == f"rmi {expected}"
    else:
        assert line.endswith(f"(engine {rmi_sph.__version__})")


def test_version_names_an_engine_of_another_version(monkeypatch: pytest.MonkeyPatch) -> None:
    from rmi_learn.cli.version import version_text

    monkeypatch.setattr(rmi_sph, "__version__", "9.9.9")
    assert version_text().endswith("(engine 9.9.9)")


def test_help_does_not_load_torch() -> None:
    """Building the parser (``rmi --help``) imports no learning stack."""
    code = (
        "import sys\n"
        "from rmi_learn.cli import build_parser\n"
        "build_parser()\n"
        "assert 'torch' not in sys.modules, 'torch loaded'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
