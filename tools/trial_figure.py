"""Draw the README's trial figure, ``docs/trial_figure.png``.

One scripted trial with the phase timings and dt of the ``quick`` grid
(``python/rmi_learn/data/grids/quick.json``) at the engine's default particle radius of 5 mm:
a 10 cm sponge of porosity 0.5 held at 80 N, lifted, then squeezed at 300 N, so the squeeze
presses clearly harder than the hold and releases water. The figure is ``rmi analyze``'s
single-run plot (force targets and loads in N, retained water in g, phases shaded). The trial
is deterministic, so the same command redraws the same figure:

    nice .venv/bin/python tools/trial_figure.py

Options change the trial (``--size``, ``--porosity``, ``--hold``, ``--squeeze``, ``--radius``)
or the output (``--out``).
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path
from typing import Any

import polars as pl

import rmi_sph
from rmi_learn.analysis.figures import plot_single_run
from rmi_learn.data.runs import atomic_write_bytes
from rmi_learn.data.sweep import load_grid

ROOT = Path(__file__).resolve().parent.parent
#: The figure the README shows.
DEFAULT_OUT = ROOT / "docs" / "trial_figure.png"
#: Particle radius of the figure's trial (m).
RADIUS_M = 0.005
#: Resolution of the saved PNG (dots per inch); the README figure stays below 200 kB.
DPI = 110


def trial_figure_config(
    size_cm: float = 10,
    porosity: float = 0.5,
    hold_n: float = 80.0,
    squeeze_n: float = 300.0,
    radius_m: float = RADIUS_M,
) -> dict[str, Any]:
    """The trial config: the ``quick`` grid's phase timings and dt, the given sponge (cm, -),
    forces (N) and particle radius (m)."""
    overrides = load_grid("quick")["overrides"]
    return rmi_sph.trial_config(size_cm, porosity, hold_n, squeeze_n, radius=radius_m, **overrides)


def draw(config: dict[str, Any], out: Path, threads: int = 1) -> dict[str, Any]:
    """Run the trial of ``config`` on ``threads`` engine threads, write its figure to ``out``
    (PNG, atomically) and return the trial's outcome."""
    result = rmi_sph.run_trial(config, num_threads=threads)
    frame = pl.DataFrame({k: v for k, v in result["columns"].items()})
    size_cm = round(float(config["size"][0]) * 100)
    title = (
        f"{size_cm} cm sponge, porosity {config['porosity']:g}: hold "
        f"{config['hold_force']:g} N, lift, squeeze {config['squeeze_force']:g} N "
        f"(r = {float(config['particle_radius']) * 1e3:g} mm, dt = "
        f"{float(config['dt']) * 1e3:g} ms)"
    )
    fig = plot_single_run(frame, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    data = buf.getvalue()
    atomic_write_bytes(out, lambda f: f.write(data))
    return dict(result["outcome"])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--size", type=float, default=10, help="sponge size (cm): 8, 10 or 12")
    ap.add_argument("--porosity", type=float, default=0.5)
    ap.add_argument("--hold", type=float, default=80.0, help="holding force (N)")
    ap.add_argument("--squeeze", type=float, default=300.0, help="squeeze force (N)")
    ap.add_argument("--radius", type=float, default=RADIUS_M, help="particle radius (m)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    a = ap.parse_args(argv)
    cfg = trial_figure_config(a.size, a.porosity, a.hold, a.squeeze, a.radius)
    outcome = draw(cfg, a.out, a.threads)
    removed = {k: round(v * 1e3, 1) for k, v in outcome["water_removed"].items()}
    print(f"{a.out}: lift_success={outcome['lift_success']} water removed (g) {removed}")


if __name__ == "__main__":
    main()
