"""examples/rl_fast_env.py trains, evaluates and writes its files on a tiny budget, and
refuses bad options in one line with exit status 2 before it trains."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from script_module import load_script

pytest.importorskip("stable_baselines3")

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rl_fast_env.py"


def _example() -> Any:
    return load_script(EXAMPLE, "rl_fast_env")


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_example_trains_evaluates_and_writes_its_files(tmp_path: Path, algo: str) -> None:
    out = tmp_path / "ppo"
    argv = ["--out", str(out), "--algo", algo, "--timesteps", "128", "--envs", "1",
            "--validation-states", "1", "--test-states", "2"]  # fmt: skip
    assert _example().main(argv) == 0
    assert {p.name for p in out.iterdir()} == {
        "agent.zip", "vecnormalize.pkl", "rows.json", "summary.json", "summary.md"
    }  # fmt: skip
    facts = json.loads((out / "summary.json").read_text())
    assert facts["algo"] == algo and facts["timesteps"] == 128 and facts["train_s"] > 0
    assert {s["controller"] for s in facts["summary"]} == {
        algo, "pi-privileged", "hold", "oracle-constant"
    }  # fmt: skip
    assert all(s["states"] == 2 for s in facts["summary"])
    assert f"| {algo} | 2 |" in (out / "summary.md").read_text()


def test_in_the_sensors_mode_the_agent_is_paired_with_pi_on_the_weight(tmp_path: Path) -> None:
    out = tmp_path / "sensors"
    argv = ["--out", str(out), "--algo", "ppo", "--timesteps", "64", "--envs", "1",
            "--validation-states", "1", "--test-states", "1",
            "--observation-mode", "sensors"]  # fmt: skip
    assert _example().main(argv) == 0
    facts = json.loads((out / "summary.json").read_text())
    assert facts["reference"] == "pi-weight" and "offset_kg" in facts["tuning"]["pi-weight"]
    assert {s["controller"] for s in facts["summary"]} == {
        "ppo", "pi-privileged", "pi-weight", "hold", "oracle-constant"
    }  # fmt: skip
    assert "vs pi-weight W/T/L" in (out / "summary.md").read_text()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--seed", "-1"], "--seed must be in [0, "),
        (["--timesteps", "0"], "--timesteps must be >= 64"),
        (["--observation-mode", "camera"], "invalid choice: 'camera'"),
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path: Path, extra: list[str], message: str) -> None:
    cmd = [sys.executable, str(EXAMPLE), "--out", str(tmp_path / "new"), *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    last = done.stderr.strip().splitlines()[-1]
    assert message in last and "Traceback" not in done.stderr
    assert not (tmp_path / "new").exists()


def test_a_non_empty_output_directory_is_refused(tmp_path: Path) -> None:
    (tmp_path / "kept.txt").write_text("mine")
    cmd = [sys.executable, str(EXAMPLE), "--out", str(tmp_path), "--timesteps", "64"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "is not an empty directory" in done.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["kept.txt"]
