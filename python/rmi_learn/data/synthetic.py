"""Synthetic run files from a toy ODE, ONLY for fast tests of the data and learning code.

Nothing here is physics: a gripper closes on a box, the load follows the commanded motion
through a first-order lag, water drains towards a force-dependent equilibrium, and contact and
friction labels come from simple thresholds. The files have exactly the run-file schema
(:mod:`rmi_learn.data.runs`), so every consumer of run files can be tested in seconds. Numbers
computed from these runs are meaningless and must never be presented as results; every file
written here says ``"source": "synthetic-toy-ode"`` in its config.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.runs import run_path, write_run
from rmi_learn.data.schema import PHASES

SOURCE = "synthetic-toy-ode"
RHO_W = 1000.0  # kg/m^3
GRAVITY = 9.81  # m/s^2

#: Phase durations of the toy trial (s); close lasts until contact.
DURATIONS = {
    "settle": 0.1,
    "ramp": 0.6,
    "hold": 0.8,
    "lift": 0.6,
    "waiting": 0.4,
    "squeeze": 2.0,
    "done": 0.1,
}
SIZES = (8, 10, 12)
POROSITIES = (0.5, 0.6, 0.7)
HOLD_FORCES = (30.0, 90.0, 150.0, 210.0)


def toy_lift_success(size_cm: int, porosity: float, f_hold: float) -> bool:
    """Toy rule: lift fails when the holding force is below a porosity-dependent threshold."""
    return f_hold >= 20.0 + 150.0 * (porosity - 0.5) + 2.0 * (size_cm - 8)


def toy_stable_squeeze(f_squeeze: float) -> bool:
    """Toy rule: squeezing above 350 N loses the grasp."""
    return f_squeeze <= 350.0


def simulate_toy_run(
    size_cm: int,
    porosity: float,
    F_hold: float,
    F_squeeze: float,
    seed: int = 0,
    record_dt: float = 0.005,
) -> dict[str, Any]:
    """Integrate the toy trial and return ``{"columns", "outcome", "config"}`` in the
    run-file schema (forces N, lengths m, water kg, time s). Deterministic in ``seed``."""
    t_wall = time.perf_counter()
    rng = np.random.default_rng(
        [int(seed), int(size_cm), int(porosity * 100), int(F_hold), int(F_squeeze)]
    )
    a = size_cm / 100.0  # squeezed extent (m)
    b = size_cm / 100.0
    h = (size_cm + 10) / 100.0
    v0 = a * b * h
    vp0 = porosity * v0
    m_solid = (1.0 - porosity) * v0 * 30.0  # kg, light foam
    m0 = RHO_W * vp0 * (0.85 + 0.1 * rng.random())
    stiffness = 250e3 * b * h * 2.0 * (1.0 - porosity)  # N per unit strain
    lift_ok = toy_lift_success(size_cm, porosity, F_hold)
    squeeze_ok = toy_stable_squeeze(F_squeeze)

    k_f, v_open, v_close = 0.002, 0.05, 0.05
    tau_f, tau_m = 0.08, 0.25
    sub = 5
    dt = record_dt / sub

    w = a + 0.01
    f_meas = 0.0
    m_l = m0
    lift_h = 0.0
    attached = True
    phase = "settle"
    t_phase = 0.0
    t = 0.0
    f_contact = 0.0
    contact_steps = 0
    failure: str | None = None
    rows: dict[str, list[Any]] = {k: [] for k in _ALL}
    phase_start_water: dict[str, float] = {}
    water_removed: dict[str, float] = {}

    def enter(p: str) -> None:
        nonlocal phase, t_phase
        water_removed[phase] = phase_start_water.get(phase, m0) - m_l
        phase, t_phase = p, 0.0
        phase_start_water[p] = m_l

    phase_start_water["settle"] = m0
    n_noise = 0.0
    while True:
        # ---- controller (once per record)
        if phase == "settle" and t_phase >= DURATIONS["settle"] - 1e-12:
            enter("close")
        elif phase == "close" and contact_steps >= 3:
            f_contact = f_meas
            enter("ramp")
        elif phase in ("ramp", "hold", "waiting", "done") and t_phase >= DURATIONS[phase] - 1e-12:
            if phase == "done":
                break
            if phase == "ramp":
                enter("hold")
            elif phase == "hold":
                enter("lift")
            else:
                enter("squeeze")
        elif phase == "lift":
            if not lift_ok and t_phase >= 0.4 - 1e-12:
                failure = "lift_slip"
                attached = False
                enter("done")
            elif t_phase >= DURATIONS["lift"] - 1e-12:
                enter("waiting")
        elif phase == "squeeze":
            if not squeeze_ok and t_phase >= 1.0 - 1e-12:
                failure = "squeeze_slip"
                attached = False
                enter("done")
            elif t_phase >= DURATIONS["squeeze"] - 1e-12:
                enter("done")

        if phase == "settle":
            f_tgt, v_cmd = 0.0, 0.0
        elif phase == "close":
            f_tgt, v_cmd = 0.0, v_close
        else:
            if phase == "ramp":
                s = min(1.0, t_phase / DURATIONS["ramp"])
                f_tgt = f_contact + (F_hold - f_contact) * (3 * s * s - 2 * s * s * s)
            elif phase in ("hold", "lift", "waiting"):
                f_tgt = F_hold
            elif phase == "squeeze":
                s = min(1.0, t_phase / 0.5)
                f_tgt = F_hold + (F_squeeze - F_hold) * (3 * s * s - 2 * s * s * s)
            else:  # done: open
                f_tgt = 0.0
            v_cmd = float(np.clip(k_f * (f_tgt - f_meas), -v_open, v_close))
            if phase == "done":
                v_cmd = -v_open

        # ---- record
        strain = max(0.0, (a - w) / a)
        c = 1.0 if (f_meas > 1.0 and attached) else 0.0
        v_sp = v0 * (1.0 - strain)
        v_pore = max(vp0 - (v0 - v_sp), 0.05 * vp0)
        sat = min(1.0, m_l / (RHO_W * v_pore))
        imb = 0.03 * np.sin(7.0 * t) + 0.01 * rng.standard_normal()
        f_l = max(0.0, f_meas * (1.0 + imb)) * c
        f_r = max(0.0, f_meas * (1.0 - imb)) * c
        lifting = phase == "lift" and attached
        weight = (m_solid + m_l) * GRAVITY
        slip = (not lift_ok) and phase == "lift"
        if c:
            area = b * h * min(1.0, 0.3 + 20.0 * strain)
            v_tz = (0.05 if lifting else 0.0) + 1e-4 * rng.standard_normal()
            v_tx, v_ty = 1e-4 * rng.standard_normal(2)
            f_fz = weight if phase in ("lift", "waiting", "squeeze") else 0.1 * weight * strain
            f_fx, f_fy = 0.5 * rng.standard_normal(2)
            v_res = abs(0.02 * (t_phase if slip else 0.0) + 1e-4 * rng.standard_normal())
            if slip and t_phase > 0.1:
                regime = 2
            elif phase == "squeeze" and t_phase < 0.5:
                regime = 3
            else:
                regime = 1
        else:
            area = 0.0
            v_tx = v_ty = v_tz = 0.0
            f_fx = f_fy = f_fz = 0.0
            v_res = float("nan")
            regime = 0
        onehot = [0.0, 0.0, 0.0, 0.0]
        onehot[regime] = 1.0
        vals = {
            "time": t,
            "phase": phase,
            "v_com_x": 0.0,
            "v_com_y": 0.0,
            "v_com_z": 0.05 if lifting else 0.0,
            "gate_open": phase in ("lift", "waiting", "squeeze"),
            "M_expelled": m0 - m_l,
            "lift_height": lift_h,
            "M_L": m_l,
            "S": sat,
            "V_pore": v_pore,
            "V_sponge": v_sp,
            "w": w,
            "F_meas": f_meas * c,
            "F_L": f_l,
            "F_R": f_r,
            "alpha_F": abs(f_l - f_r) / (f_l + f_r + 1e-6),
            "A_L": area,
            "A_R": area * (1.0 + 0.01 * imb),
            "c": c,
            "v_tan_x": v_tx,
            "v_tan_y": v_ty,
            "v_tan_z": v_tz,
            "F_fric_x": f_fx,
            "F_fric_y": f_fy,
            "F_fric_z": f_fz,
            "v_res": v_res,
            "r_none": onehot[0],
            "r_stick": onehot[1],
            "r_slip": onehot[2],
            "r_mixed": onehot[3],
            "F_target": f_tgt,
            "v_cmd": v_cmd,
        }
        for k, v in vals.items():
            rows[k].append(v)

        # ---- integrate one record interval
        for _ in range(sub):
            w -= v_cmd * dt
            w = min(max(w, 0.2 * a), a + 0.02)
            strain = max(0.0, (a - w) / a)
            n_noise = 0.9 * n_noise + 0.3 * rng.standard_normal()
            f_static = stiffness * strain * (1.0 + 2.0 * strain) + n_noise
            f_meas += dt / tau_f * (max(f_static, 0.0) - f_meas)
            f_meas = max(f_meas, 0.0)
            m_eq = m0 * (0.15 + 0.85 * np.exp(-f_meas / (60.0 * size_cm / 10.0)))
            if f_meas > 1.0:
                m_l += dt / tau_m * min(0.0, m_eq - m_l)
            if lifting:
                lift_h += 0.05 * dt
                m_l -= 0.002 * m_l * dt
            t += dt
            t_phase += dt
        t = round(t / record_dt) * record_dt
        t_phase = round(t_phase / record_dt) * record_dt
        if phase == "close":
            contact_steps = contact_steps + 1 if f_meas > 1.0 else 0
        if t > 30.0:
            raise RuntimeError("toy trial did not finish")

    water_removed[phase] = phase_start_water.get(phase, m0) - m_l
    columns = {k: np.asarray(v) for k, v in rows.items()}
    outcome = {
        "lift_success": bool(lift_ok),
        "stable_squeeze": bool(lift_ok and squeeze_ok),
        "failure": failure,
        "water_removed": {p: float(water_removed[p]) for p in PHASES if p in water_removed},
        "initial_water": float(m0),
        "final_water": float(columns["M_L"][-1]),
        "wall_s": time.perf_counter() - t_wall,
    }
    config = {
        "source": SOURCE,
        "record_dt": record_dt,
        "size_cm": size_cm,
        "porosity": porosity,
        "F_hold": F_hold,
        "F_squeeze": F_squeeze,
        "seed": seed,
    }
    return {"columns": columns, "outcome": outcome, "config": config}


_ALL = (
    "time phase v_com_x v_com_y v_com_z gate_open M_expelled lift_height M_L S V_pore V_sponge w "
    "F_meas F_L F_R alpha_F A_L A_R c v_tan_x v_tan_y v_tan_z F_fric_x F_fric_y F_fric_z v_res "
    "r_none r_stick r_slip r_mixed F_target v_cmd"
).split()


def synthetic_grid(n_per_size: int) -> list[tuple[int, float, float, float]]:
    """``(size_cm, porosity, F_hold, F_squeeze)`` of the first ``n_per_size`` toy runs of
    each size. Runs come group by group (a group is one porosity and holding force) with two
    squeeze variants each, (150, 300) N or (150, 380) N alternately; beyond 24 runs per size,
    every group gets further variants (220 N, then 260 N). At most 48 runs per size."""
    groups = [(fh, p) for fh in HOLD_FORCES for p in POROSITIES]
    combos: list[tuple[float, float, float]] = []
    for i, (fh, p) in enumerate(groups):
        for fs in (150.0, 300.0) if i % 2 == 0 else (150.0, 380.0):
            combos.append((p, fh, fs))
    for extra in (220.0, 260.0):
        combos.extend((p, fh, extra) for fh, p in groups)
    if not 1 <= n_per_size <= len(combos):
        raise ValueError(f"n_per_size must be in 1..{len(combos)}, got {n_per_size}")
    return [(s, p, fh, fs) for s in SIZES for (p, fh, fs) in combos[:n_per_size]]


def write_synthetic_runs(
    run_dir: str | os.PathLike[str], n_per_size: int = 12, seed: int = 0
) -> list[Path]:
    """Write ``n_per_size`` toy runs per sponge size (8, 10, 12 cm) under ``run_dir`` in the
    grid layout of :func:`rmi_learn.data.runs.run_path` and return their paths. Some runs fail
    the lift (low holding force at high porosity) and some lose the grasp while squeezing
    (F_squeeze > 350 N), so filters are exercised. Test data only: see the module docstring.
    """
    paths = []
    for size_cm, porosity, f_hold, f_squeeze in synthetic_grid(n_per_size):
        params = {
            "size_cm": size_cm,
            "porosity": porosity,
            "F_hold": f_hold,
            "F_squeeze": f_squeeze,
            "seed": seed,
        }
        res = simulate_toy_run(size_cm, porosity, f_hold, f_squeeze, seed=seed)
        path = run_path(run_dir, params)
        write_run(path, res["columns"], res["config"], params, res["outcome"])
        paths.append(path)
    return paths
