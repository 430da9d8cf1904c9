"""studies/wm_seeds.py: the seed-average forecast and its report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from study_scripts import load_study


def test_average_forecasts_means_states_and_probabilities() -> None:
    m = load_study("wm_seeds")
    g = torch.Generator().manual_seed(0)
    outs = [
        {
            "z": torch.randn(3, 5, 18, generator=g),
            "contact_logit": 4 * torch.randn(3, 5, generator=g),
            "friction_logit": 4 * torch.randn(3, 5, 4, generator=g),
        }
        for _ in range(3)
    ]
    avg = m.average_forecasts(outs)
    assert torch.equal(avg["z"], (outs[0]["z"] + outs[1]["z"] + outs[2]["z"]) / 3)
    p_c = sum(torch.sigmoid(o["contact_logit"]) for o in outs) / 3
    p_f = sum(torch.softmax(o["friction_logit"], dim=-1) for o in outs) / 3
    torch.testing.assert_close(torch.sigmoid(avg["contact_logit"]), p_c)
    torch.testing.assert_close(torch.softmax(avg["friction_logit"], dim=-1), p_f)


def test_report_of_two_seeds(
    synthetic_dataset_dir: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from rmi_learn.cli import main as rmi

    runs = []
    for seed in (0, 1):
        out = tmp_path / f"mlp-s{seed}"
        argv = ["train-wm", "--model", "ac-mlp", "--data", str(synthetic_dataset_dir)]
        argv += ["--out", str(out), "--debug", "--no-progress", "--seed", str(seed)]
        assert rmi(argv) == 0
        runs.append(str(out))
    capsys.readouterr()
    m = load_study("wm_seeds")
    assert m.main(["--runs", *runs, "--data", str(synthetic_dataset_dir), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res, "no size with validation windows"
    for rows in res.values():
        assert list(rows) == ["Baseline", "mlp-s0", "mlp-s1", "average of 2"]
        for s in m.STEPS:
            key = f"water_mae_g@{s}"
            # |mean(z) - t| <= mean |z_i - t| element by element, so also in the mean, up to
            # the float32 rounding of forecasts in grams (relative 1e-7 per operation).
            members = (rows["mlp-s0"][key] + rows["mlp-s1"][key]) / 2
            assert rows["average of 2"][key] <= members * (1 + 1e-6)
        assert rows["mlp-s0"] != rows["mlp-s1"]
    with pytest.raises(SystemExit):
        m.main(["--runs", runs[0], "--data", str(synthetic_dataset_dir)])
