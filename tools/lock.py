"""Re-resolve requirements-dev.txt, the exact versions `make setup` installs.

pip's resolver works out the project's `test`, `learn`, `ray` and `lerobot` extras, the build
backend (maturin, with pyproject.toml's range) and pip itself against PyPI, for this interpreter and
platform. It reads package metadata only: no wheel is downloaded, nothing is installed (about
20 s). Every package of the result is pinned except the project itself and those in
LEFT_OUT; the file's leading comment block is kept. Run it with the interpreter the pins are
for (3.11 unless you mean to move the floor):

    make lock        # or: .venv/bin/python tools/lock.py

then `make test`, which reinstalls because the file's hash changed.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / "requirements-dev.txt"
PROJECT = "rmi"
EXTRAS = "test,learn,ray,lerobot,rl,video"
# torch's compiler for GPU kernels: 1 GB that only torch.compile on a GPU would load.
LEFT_OUT = frozenset({"triton"})


def canonical(name: str) -> str:
    """PEP 503 normal form of a distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def pins_from_report(report: dict[str, Any]) -> list[str]:
    """`name==version` lines for a pip installation report, sorted by name."""
    pins = {}
    for item in report["install"]:
        meta = item["metadata"]
        key = canonical(meta["name"])
        if key == PROJECT or key in LEFT_OUT:
            continue
        pins[key] = f"{meta['name']}=={meta['version']}"
    return [pins[k] for k in sorted(pins)]


def pin_lines(text: str) -> list[str]:
    """The `name==version` lines of a requirements file, in file order."""
    return [ln for ln in text.splitlines() if "==" in ln and not ln.startswith("#")]


def header(text: str) -> list[str]:
    """The leading comment block of a requirements file (comments and blank lines)."""
    out = []
    for line in text.splitlines():
        if line and not line.startswith("#"):
            break
        out.append(line)
    while out and not out[-1]:
        out.pop()
    return out


def resolve() -> dict[str, Any]:
    """pip's installation report for the extras, maturin and pip (metadata only)."""
    build = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed"]
        cmd += ["--quiet", "--no-cache-dir", "--report", str(report)]
        cmd += [f".[{EXTRAS}]", *build, "pip"]
        subprocess.run(cmd, cwd=ROOT, check=True)
        result: dict[str, Any] = json.loads(report.read_text())
        return result


def main() -> int:
    old = LOCK.read_text() if LOCK.exists() else ""
    lines = header(old) + pins_from_report(resolve())
    tmp = LOCK.with_suffix(".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, LOCK)
    before = set(pin_lines(old))
    after = set(pin_lines("\n".join(lines)))
    for ln in sorted(before - after):
        print(f"- {ln}")
    for ln in sorted(after - before):
        print(f"+ {ln}")
    print(f"{LOCK.name}: {len(after)} pins, {len(after - before)} changed or new")
    return 0


if __name__ == "__main__":
    sys.exit(main())
