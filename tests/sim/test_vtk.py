"""ParaView output (rmi_learn.sim.vtk) and the `rmi simulate` command."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import rmi_sph
from rmi_learn.cli import main
from rmi_learn.data.runs import RUN_COLUMNS, read_run
from rmi_learn.sim.vtk import FrameWriter, polydata_xml, read_vtp_arrays, write_vtp
from tiny_trial import tiny_config


@pytest.mark.parametrize("binary", [False, True])
def test_polydata_round_trip(tmp_path: Path, binary: bool) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(7, 3))
    vel = rng.normal(size=(7, 3))
    phase = np.arange(7, dtype=np.int32) % 3
    tree = polydata_xml(
        pts,
        point_data={"velocity": vel, "phase": phase},
        verts=True,
        polys=[(0, 1, 2, 3)],
        cell_data={"c": np.arange(8, dtype=np.int32)},
        binary=binary,
    )
    path = write_vtp(tmp_path / "a.vtp", tree)
    root = ET.parse(path).getroot()
    assert root.get("type") == "PolyData"
    piece = root.find("PolyData/Piece")
    assert piece is not None and piece.get("NumberOfPoints") == "7"
    back = read_vtp_arrays(path)
    assert (back["n_points"], back["n_verts"], back["n_polys"]) == (7, 7, 1)
    assert np.array_equal(back["points"], pts) and np.array_equal(
        back["point_data"]["velocity"], vel
    )
    assert np.array_equal(back["point_data"]["phase"], phase)
    assert np.array_equal(back["cell_data"]["c"], np.arange(8))
    with pytest.raises(ValueError):
        polydata_xml(pts, point_data={"bad": np.zeros(3)})


def test_frames_of_a_simulation(tmp_path: Path) -> None:
    sim = rmi_sph.Trial(tiny_config(), num_threads=1)
    writer = FrameWriter(tmp_path, include_boundary=True)
    writer.write(sim)
    sim.step(40)
    files = writer.write(sim)
    n_f, n_s = (sim.particles(k)["positions"].shape[0] for k in ("fluid", "solid"))
    n_b = sim.particles("boundary")["positions"].shape[0]
    parts = read_vtp_arrays(files[0])
    assert parts["n_points"] == parts["n_verts"] == n_f + n_s + n_b
    pd = parts["point_data"]
    assert {"phase", "velocity", "pressure", "saturation", "density"} <= set(pd)
    assert np.bincount(pd["phase"]).tolist() == [n_f, n_s, n_b]
    assert pd["velocity"].shape == (n_f + n_s + n_b, 3)
    assert np.array_equal(parts["points"][:n_f], sim.particles("fluid")["positions"])
    sat = pd["saturation"][pd["phase"] == 1]
    assert np.all((sat >= 0) & (sat <= 1))
    boxes = read_vtp_arrays(files[1])
    assert (boxes["n_points"], boxes["n_polys"]) == (24, 18)
    # Pad boxes sit where the engine has them.
    pad = sim.bodies()[1]
    corners = boxes["points"][8:16]
    assert np.allclose(corners.mean(axis=0), pad["position"])
    assert np.allclose(corners.max(axis=0) - corners.min(axis=0), 2 * np.array(pad["half_extents"]))
    pvd = ET.parse(tmp_path / "trial.pvd").getroot()
    sets = pvd.findall("Collection/DataSet")
    assert len(sets) == 4 and {s.get("part") for s in sets} == {"0", "1"}
    assert float(sets[-1].get("timestep", "nan")) == pytest.approx(sim.time)
    for s in sets:
        assert (tmp_path / s.get("file", "")).is_file()


def test_simulate_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tiny_config(seed=2)
    cfg_path = tmp_path / "trial.json"
    cfg_path.write_text(json.dumps(cfg))
    out = tmp_path / "out"
    code = main(
        ["simulate", "--config", str(cfg_path), "--out", str(out), "--vtk-every", "100",
         "--threads", "1", "--vtk-ascii"]
    )  # fmt: skip
    assert code == 0
    outcome = json.loads(capsys.readouterr().out)
    assert outcome["lift_success"] and outcome["failure"] is None
    df, meta = read_run(out / "run.parquet")
    assert tuple(df.columns) == RUN_COLUMNS
    assert meta["params"] == {"size_cm": 8, "porosity": 0.8, "F_hold": 20.0,
                              "F_squeeze": 150.0, "seed": 2}  # fmt: skip
    assert meta["config"] == cfg and meta["outcome"]["final_water"] == outcome["final_water"]
    assert df["phase"][-1] == "done"
    frames = sorted((out / "frames").glob("particles_*.vtp"))
    assert len(frames) == 1 + -(-outcome["steps"] // 100)
    assert json.loads((out / "config.json").read_text()) == cfg
    # Bad configs are reported, not raised, with the input-error status 2.
    cfg_path.write_text(json.dumps({"dt": -1.0}))
    assert main(["simulate", "--config", str(cfg_path), "--out", str(out)]) == 2
    assert "dt" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["--size", "8", "--porosity", "1.5"], "porosity"),
        (["--size", "8", "--hold", "nan"], "hold_force"),
        (["--config", "{missing}"], "No such file"),
        (["--config", "{garbage}"], "garbage.json: not valid JSON"),
        (["--config", "{bad_value}"], "dt"),
    ],
)
def test_simulate_rejects_bad_input_without_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], names: str
) -> None:
    # A flag out of range, a missing or malformed config file, a config value out of range:
    # one line naming the problem, status 2, no traceback, and no output directory left.
    (tmp_path / "garbage.json").write_text("{not json")
    (tmp_path / "bad_value.json").write_text(json.dumps({"dt": -1.0}))
    files = {k: str(tmp_path / f"{k}.json") for k in ("missing", "garbage", "bad_value")}
    out = tmp_path / "out"
    code = main(["simulate", *[a.format(**files) for a in argv], "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("rmi simulate: ") and names in err and "Traceback" not in err
    assert not out.exists()
