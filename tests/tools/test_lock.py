"""requirements-dev.txt: complete, consistent, and what the test environment holds."""

from __future__ import annotations

import importlib.metadata as md
from pathlib import Path

from packaging.requirements import Requirement

from script_module import load_script

ROOT = Path(__file__).resolve().parents[2]


lock = load_script(ROOT / "tools" / "lock.py", "lock_tool")


def pins() -> dict[str, str]:
    out = {}
    for line in lock.pin_lines(lock.LOCK.read_text()):
        name, version = line.split("==")
        out[lock.canonical(name)] = version
    return out


def test_environment_holds_the_pinned_versions() -> None:
    # make test reinstalls when the file changes; a mismatch means a stale environment.
    wrong = {n: (v, md.version(n)) for n, v in pins().items() if md.version(n) != v}
    assert not wrong, (
        f"installed versions differ from requirements-dev.txt (pinned, installed): {wrong}; "
        "`make setup` installs the pins, `make lock` re-pins after a deliberate upgrade"
    )


def test_every_requirement_of_a_pin_is_pinned_and_satisfied() -> None:
    # The Makefile installs with --no-deps, so a dependency missing here would be missing.
    pinned = pins()
    missing = []
    for name, version in pinned.items():
        for text in md.requires(name) or []:
            req = Requirement(text)
            if req.marker is not None and not req.marker.evaluate({"extra": ""}):
                continue
            dep = lock.canonical(req.name)
            if dep in lock.LEFT_OUT:
                continue
            if dep not in pinned or not req.specifier.contains(pinned[dep], prereleases=True):
                missing.append(f"{name}=={version} needs {text}")
    assert not missing, missing


def test_project_extras_are_pinned() -> None:
    pinned = pins()
    for text in md.requires("rmi") or []:
        req = Requirement(text)
        dep = lock.canonical(req.name)
        assert dep in pinned, text
        assert req.specifier.contains(pinned[dep], prereleases=True), (text, pinned[dep])


def test_pins_from_report_drops_project_and_left_out_and_sorts() -> None:
    report = {
        "install": [
            {"metadata": {"name": "Zeta_Pkg", "version": "1.0"}},
            {"metadata": {"name": "rmi", "version": "0.1.0"}},
            {"metadata": {"name": "triton", "version": "3.9.0"}},
            {"metadata": {"name": "alpha", "version": "2.0"}},
        ]
    }
    assert lock.pins_from_report(report) == ["alpha==2.0", "Zeta_Pkg==1.0"]


def test_header_keeps_the_leading_comment_block_only() -> None:
    text = "# one\n#\n# two\n\nnumpy==2.0\n# later\n"
    assert lock.header(text) == ["# one", "#", "# two"]
