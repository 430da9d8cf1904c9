"""Running a Python snippet that kills itself with SIGKILL mid-write, with this checkout's
package importable: the crash tests of the staged outputs share it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import rmi_learn

PACKAGE_ROOT = Path(rmi_learn.__file__).resolve().parents[1]


def run_killed(script: str, *args: str) -> subprocess.CompletedProcess[bytes]:
    """Run ``script`` with ``args`` in a fresh interpreter; the caller checks its status."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE_ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-c", script, *args], env=env, timeout=300, check=False)
