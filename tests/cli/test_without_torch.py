"""`pip install .` without the `learn` extra: the simulator half works with torch absent.

Each test runs a fresh interpreter whose ``sitecustomize`` puts an import finder first on
``sys.meta_path`` that refuses torch and safetensors, as if they were not installed, and
logs every attempt with its stack. The commands of the simulator half (simulate, sweep,
dataset, analyze, report) and the Gymnasium environment must then work and must not even
try the import; the learning commands end with one line naming the extra.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tiny_trial import TINY

ROOT = Path(__file__).resolve().parents[2]

BLOCKER = """
import os, sys, traceback

class _LearnExtraAbsent:
    '''Refuses the learn extra's packages; logs who asked.'''

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] not in ("torch", "safetensors"):
            return None
        stack = traceback.extract_stack()
        # importlib.util.find_spec only asks whether it is installed (polars does at import).
        util = ("<frozen importlib.util>", os.path.join("importlib", "util.py"))
        probe = any(f.name == "find_spec" and f.filename.endswith(util) for f in stack)
        if not probe:
            with open(os.environ["RMI_BLOCKED_LOG"], "a") as log:
                log.write(f"--- import {name}\\n" + "".join(traceback.format_list(stack)))
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, _LearnExtraAbsent())
"""


def run_without_torch(tmp_path: Path, script: str) -> subprocess.CompletedProcess[str]:
    """Run ``script`` in a fresh interpreter (cwd ``tmp_path``) where torch cannot be
    imported; ``tmp_path/blocked.log`` records every attempt."""
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(BLOCKER)
    paths = [str(site), str(ROOT / "python"), str(ROOT / "tests")]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(paths + [os.environ.get("PYTHONPATH", "")]),
        "RMI_BLOCKED_LOG": str(tmp_path / "blocked.log"),
    }
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def blocked_imports(tmp_path: Path) -> str:
    log = tmp_path / "blocked.log"
    return log.read_text() if log.exists() else ""


def test_the_blocker_blocks(tmp_path: Path) -> None:
    done = run_without_torch(tmp_path, "import torch")
    assert done.returncode != 0 and "No module named 'torch'" in done.stderr
    assert "--- import torch" in blocked_imports(tmp_path)


def test_simulator_half_runs_without_torch(tmp_path: Path) -> None:
    trial = {"sizes_cm": [8], "porosities": [0.8], "hold_forces_N": [20.0]}
    grid = {**trial, "squeeze_forces_N": [150.0], "seeds": [0], "radius_m": 0.01}
    (tmp_path / "grid.json").write_text(json.dumps({**grid, "overrides": TINY}))
    script = """
        import sys
        from rmi_learn.cli import main

        def rmi(*argv):
            try:
                status = main(list(argv))
            except SystemExit as done:  # --help and --version exit through argparse
                status = done.code
            assert status == 0, (argv, status)

        rmi("--version")
        for command in ("simulate", "sweep", "dataset", "analyze", "report", "pipeline"):
            rmi(command, "--help")

        from tiny_trial import tiny_config
        import json
        with open("trial.json", "w") as f:
            json.dump(tiny_config(), f)
        rmi("simulate", "--config", "trial.json", "--out", "one", "--threads", "1")
        rmi("sweep", "--grid", "grid.json", "--out", "sweep", "--workers", "0",
            "--no-progress")

        from rmi_learn.data.synthetic import write_synthetic_runs
        from rmi_learn.data.sweep import build_index
        write_synthetic_runs("synthetic/runs", n_per_size=4, seed=0)
        build_index("synthetic")
        rmi("analyze", "--runs", "synthetic", "--out", "analysis", "--bootstrap", "20")
        rmi("report", "--out", ".")

        import gymnasium as gym
        import rmi_learn.sim.env
        env = gym.make("rmi/SpongeSqueeze-v0", config=tiny_config(), max_episode_steps=3,
                       goal_fraction=0.9)
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step([40.0])
        assert obs.shape == (23,)
        print("modules:", sorted(m for m in sys.modules if m.startswith(("torch", "safe"))))
    """
    done = run_without_torch(tmp_path, script)
    assert done.returncode == 0, done.stderr[-4000:]
    assert blocked_imports(tmp_path) == "", blocked_imports(tmp_path)[-4000:]
    assert "modules: []" in done.stdout
    assert (tmp_path / "one" / "run.parquet").is_file()
    assert len(list((tmp_path / "sweep" / "runs").rglob("run.parquet"))) == 1
    assert (tmp_path / "analysis" / "analysis.json").is_file()
    assert (tmp_path / "report" / "report.html").is_file()
    # The dataset stage builds without torch (its module tries the import, and falls back).
    done = run_without_torch(
        tmp_path,
        """
        from rmi_learn.cli import main
        assert main(["dataset", "build", "--runs", "synthetic/runs", "--out", "dataset"]) == 0
    """,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    assert (tmp_path / "dataset" / "dataset.json").is_file()


@pytest.mark.parametrize(
    "argv",
    [
        ["train-wm", "--model", "ac-gru", "--data", "d", "--out", "o"],
        ["eval-wm", "--runs", "r", "--data", "d", "--out", "o"],
        ["train-policy", "--objective", "flow", "--data", "d", "--out", "o", "--device", "cuda"],
    ],
    ids=["train-wm", "eval-wm", "device"],
)
def test_learning_commands_name_the_extra(tmp_path: Path, argv: list[str]) -> None:
    script = f"""
        import sys
        from rmi_learn.cli import main
        try:
            sys.exit(main({argv!r}))
        except SystemExit as done:
            sys.exit(done.code)
    """
    done = run_without_torch(tmp_path, script)
    lines = done.stderr.strip().splitlines()
    assert done.returncode in (1, 2), done.stderr
    assert "Traceback" not in done.stderr and "pip install 'rmi[learn]'" in lines[-1], lines
    assert not (tmp_path / "o").exists()
