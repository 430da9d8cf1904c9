"""Water a gripped sponge releases against the pore volume it closes.

A saturated sponge under compression keeps its pores full: the water it can release is the
pore volume the skeleton closes (plus what free drainage lets through, nothing at the
sponges' permeability; see the "hung sponge drainage" validation case). Released water above
rho_f times the closed pore volume means the pores empty while gripped, which a sponge under
positive pore pressure cannot do. This runs one scripted grasp-lift-squeeze trial through
``rmi_sph.Trial`` and prints, per controller phase, the retained water M_L and the pore
volume V_pore at the phase's first and last sample, and the ratio of the water released to
the pore volume closed since the plates closed.

    .venv/bin/python studies/pore_balance.py --radius 0.008 [--size 8] [--porosity 0.7] \\
        [--hold 140] [--squeeze 150] [--seed 0] [--gap G] [--layers] [--threads 2] \\
        [--every 50] [--json]

``--layers`` adds, at the start of each phase (the last, done, is the end), the mean
saturation of each layer of skeleton particles across the squeeze axis (x), from the left
plate to the right: where in the sponge the pores empty.

``--gap`` sets the gripper's initial gap to the sponge's faces (m; the engine's default is
5 mm): at coarse radii the plates' boundary reaches the pore water from a gap of 3r on.

Phases and time step are those of ``studies/grids/resolution/`` (the study's phases at the
engine's default dt = 1 ms), read from its grid file by ``studies/series_trial.py``.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

# The study scripts are files, not a package: make their shared module importable however the
# script is loaded (run from anywhere, or loaded by path in the tests).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from series_trial import add_condition_args, report, trial_config  # noqa: E402

#: Density of water (kg/m^3) for turning a pore volume into the water it holds.
RHO_WATER = 1000.0


def per_phase(samples: Sequence[tuple[str, float, float]]) -> list[dict[str, Any]]:
    """Per run of equal phase in ``samples`` (phase, M_L in kg, V_pore in m^3, in time
    order): the first and last retained water (g) and pore volume (cm^3), and the water
    released and pore volume closed within it."""
    out = []
    for phase, grp in itertools.groupby(samples, key=lambda s: s[0]):
        g = list(grp)
        (_, m0, v0), (_, m1, v1) = g[0], g[-1]
        out.append(
            {
                "phase": phase,
                "water_g": (1e3 * m0, 1e3 * m1),
                "pore_cm3": (1e6 * v0, 1e6 * v1),
                "released_g": 1e3 * (m0 - m1),
                "closed_cm3": 1e6 * (v0 - v1),
            }
        )
    return out


def balance(samples: Sequence[tuple[str, float, float]], since: str = "close") -> dict[str, float]:
    """Water released (g) and pore volume closed (cm^3) from the first sample of phase
    ``since`` to the last sample, and their ratio in g per g of closed pores (inf when no
    pore volume closed)."""
    start = next((k for k, s in enumerate(samples) if s[0] == since), None)
    if start is None:
        raise ValueError(f"no sample of phase {since!r}")
    (_, m0, v0), (_, m1, v1) = samples[start], samples[-1]
    released = 1e3 * (m0 - m1)
    closed = 1e6 * (v0 - v1)
    closed_g = closed * RHO_WATER / 1e3
    ratio = released / closed_g if closed_g > 0 else float("inf")
    return {"released_g": released, "closed_cm3": closed, "ratio": ratio}


def layer_saturation(rest_x: np.ndarray, saturation: np.ndarray) -> list[tuple[float, float]]:
    """(rest x in m, mean saturation) of each layer of skeleton particles that share a rest
    x coordinate (to 1e-6 m), ordered along x."""
    key = np.round(np.asarray(rest_x) / 1e-6).astype(np.int64)
    layers = np.unique(key)
    sat = np.asarray(saturation, dtype=float)
    return [(float(k) * 1e-6, float(sat[key == k].mean())) for k in layers]


def run(a: argparse.Namespace) -> dict[str, Any]:
    """The trial of ``a``'s options, sampled every ``a.every`` steps."""
    import rmi_sph

    cfg = trial_config(a, **({"gripper": {"gap": a.gap}} if a.gap is not None else {}))
    sim = rmi_sph.Trial(cfg, num_threads=a.threads)
    t0 = time.perf_counter()
    samples: list[tuple[str, float, float]] = []
    layers: list[dict[str, Any]] = []

    def record_layers(phase: str) -> None:
        s = sim.particles("solid")
        rest_x = np.asarray(s["rest_positions"])[:, 0]
        layers.append({"phase": phase, "layers": layer_saturation(rest_x, s["saturation"])})

    while True:
        o = sim.observation()
        phase = str(o["phase"])
        if a.layers and (not samples or samples[-1][0] != phase):
            record_layers(phase)
        samples.append((phase, float(o["M_L"]), float(o["V_pore"])))
        if phase == "done":
            break
        sim.step(a.every)
    return {
        "radius_m": a.radius,
        "size_cm": a.size,
        "gap_m": a.gap,
        "wall_s": time.perf_counter() - t0,
        "phases": per_phase(samples),
        "since_close": balance(samples),
        "layer_saturation": layers,
    }


def show(a: argparse.Namespace, res: dict[str, Any]) -> None:
    """The result as text: per phase, then the layers, then the balance since the close."""
    print(f"{a.size} cm, r = {1000 * a.radius:g} mm ({res['wall_s']:.0f} s)")
    for p in res["phases"]:
        print(
            f"  {p['phase']:8s} water {p['water_g'][0]:6.0f} -> {p['water_g'][1]:6.0f} g "
            f"(released {p['released_g']:6.1f}), pores {p['pore_cm3'][0]:6.0f} -> "
            f"{p['pore_cm3'][1]:6.0f} cm^3 (closed {p['closed_cm3']:6.1f})"
        )
    if res["layer_saturation"]:
        xs = " ".join(f"{1000 * x:6.0f}" for x, _ in res["layer_saturation"][0]["layers"])
        print(f"  saturation per skeleton layer, rest x (mm): {xs}")
        for row in res["layer_saturation"]:
            print(f"    {row['phase']:8s} " + " ".join(f"{v:6.2f}" for _, v in row["layers"]))
    b = res["since_close"]
    print(
        f"  since the plates closed: released {b['released_g']:.1f} g, pores closed "
        f"{b['closed_cm3']:.1f} cm^3: {b['ratio']:.2f} g per g of closed pores"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_condition_args(ap)
    ap.add_argument("--gap", type=float, default=None, help="gripper's initial gap (m)")
    ap.add_argument("--layers", action="store_true", help="saturation per skeleton layer in x")
    ap.add_argument("--every", type=int, default=50, help="steps between samples")
    a = ap.parse_args(argv)
    if a.every < 1:
        print(f"pore_balance: --every must be >= 1 (got {a.every})", file=sys.stderr)
        return 2
    return report("pore_balance", run, a, show)


if __name__ == "__main__":
    raise SystemExit(main())
