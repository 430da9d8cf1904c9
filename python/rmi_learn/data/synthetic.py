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
from dataclasses import dataclass, field
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


#: Gripper gains of the toy trial: force-error gain (m/s per N), opening and closing speed
#: limits (m/s).
_K_F, _V_OPEN, _V_CLOSE = 0.002, 0.05, 0.05
#: Time constants (s) of the measured force and of the water drainage.
_TAU_F, _TAU_M = 0.08, 0.25
#: Integration steps per record interval.
_SUBSTEPS = 5


@dataclass(frozen=True)
class _ToySponge:
    """The toy sponge of one run: its box (m), pore volume, solid and initial water mass
    (kg), stiffness (N per unit strain), and whether it lifts and squeezes without slipping."""

    size_cm: int
    a: float
    b: float
    h: float
    v0: float
    vp0: float
    m_solid: float
    m0: float
    stiffness: float
    lift_ok: bool
    squeeze_ok: bool

    @classmethod
    def of(
        cls,
        size_cm: int,
        porosity: float,
        F_hold: float,
        F_squeeze: float,
        rng: np.random.Generator,
    ) -> _ToySponge:
        """The sponge of a run; draws its initial water from ``rng`` (the run's first draw)."""
        a = size_cm / 100.0  # squeezed extent (m)
        b = size_cm / 100.0
        h = (size_cm + 10) / 100.0
        v0 = a * b * h
        vp0 = porosity * v0
        m_solid = (1.0 - porosity) * v0 * 30.0  # kg, light foam
        m0 = RHO_W * vp0 * (0.85 + 0.1 * rng.random())
        stiffness = 250e3 * b * h * 2.0 * (1.0 - porosity)
        return cls(
            size_cm=size_cm,
            a=a,
            b=b,
            h=h,
            v0=v0,
            vp0=vp0,
            m_solid=m_solid,
            m0=m0,
            stiffness=stiffness,
            lift_ok=toy_lift_success(size_cm, porosity, F_hold),
            squeeze_ok=toy_stable_squeeze(F_squeeze),
        )


@dataclass
class _ToyState:
    """The toy trial as it runs: gripper opening ``w`` (m), measured force (N), water held
    (kg), lift height (m), the phase and its clock (s), and the water removed per phase."""

    w: float
    m_l: float
    m0: float
    f_meas: float = 0.0
    lift_h: float = 0.0
    attached: bool = True
    phase: str = "settle"
    t_phase: float = 0.0
    t: float = 0.0
    f_contact: float = 0.0
    contact_steps: int = 0
    failure: str | None = None
    n_noise: float = 0.0
    phase_start_water: dict[str, float] = field(default_factory=dict)
    water_removed: dict[str, float] = field(default_factory=dict)

    def close_phase(self) -> None:
        """Book the water the current phase removed."""
        self.water_removed[self.phase] = self.phase_start_water.get(self.phase, self.m0) - self.m_l

    def enter(self, phase: str) -> None:
        self.close_phase()
        self.phase, self.t_phase = phase, 0.0
        self.phase_start_water[phase] = self.m_l


def _next_phase(s: _ToyState, sponge: _ToySponge) -> bool:
    """The controller's phase switch at a record; False when the trial is over."""
    if s.phase == "settle" and s.t_phase >= DURATIONS["settle"] - 1e-12:
        s.enter("close")
    elif s.phase == "close" and s.contact_steps >= 3:
        s.f_contact = s.f_meas
        s.enter("ramp")
    elif s.phase in ("ramp", "hold", "waiting", "done") and s.t_phase >= DURATIONS[s.phase] - 1e-12:
        if s.phase == "done":
            return False
        if s.phase == "ramp":
            s.enter("hold")
        elif s.phase == "hold":
            s.enter("lift")
        else:
            s.enter("squeeze")
    elif s.phase == "lift":
        if not sponge.lift_ok and s.t_phase >= 0.4 - 1e-12:
            s.failure = "lift_slip"
            s.attached = False
            s.enter("done")
        elif s.t_phase >= DURATIONS["lift"] - 1e-12:
            s.enter("waiting")
    elif s.phase == "squeeze":
        if not sponge.squeeze_ok and s.t_phase >= 1.0 - 1e-12:
            s.failure = "squeeze_slip"
            s.attached = False
            s.enter("done")
        elif s.t_phase >= DURATIONS["squeeze"] - 1e-12:
            s.enter("done")
    return True


def _command(s: _ToyState, F_hold: float, F_squeeze: float) -> tuple[float, float]:
    """The force target (N) and the gripper's commanded closing speed (m/s) of the phase."""
    if s.phase == "settle":
        return 0.0, 0.0
    if s.phase == "close":
        return 0.0, _V_CLOSE
    if s.phase == "ramp":
        r = min(1.0, s.t_phase / DURATIONS["ramp"])
        f_tgt = s.f_contact + (F_hold - s.f_contact) * (3 * r * r - 2 * r * r * r)
    elif s.phase in ("hold", "lift", "waiting"):
        f_tgt = F_hold
    elif s.phase == "squeeze":
        r = min(1.0, s.t_phase / 0.5)
        f_tgt = F_hold + (F_squeeze - F_hold) * (3 * r * r - 2 * r * r * r)
    else:  # done: open
        f_tgt = 0.0
    v_cmd = float(np.clip(_K_F * (f_tgt - s.f_meas), -_V_OPEN, _V_CLOSE))
    if s.phase == "done":
        v_cmd = -_V_OPEN
    return f_tgt, v_cmd


def _contact_row(
    s: _ToyState, sponge: _ToySponge, strain: float, lifting: bool, rng: np.random.Generator
) -> dict[str, Any]:
    """The contact channels of a record: pad area, tangential slip, friction and its regime
    (nothing without contact)."""
    weight = (sponge.m_solid + s.m_l) * GRAVITY
    slip = (not sponge.lift_ok) and s.phase == "lift"
    area = sponge.b * sponge.h * min(1.0, 0.3 + 20.0 * strain)
    v_tz = (0.05 if lifting else 0.0) + 1e-4 * rng.standard_normal()
    v_tx, v_ty = 1e-4 * rng.standard_normal(2)
    f_fz = weight if s.phase in ("lift", "waiting", "squeeze") else 0.1 * weight * strain
    f_fx, f_fy = 0.5 * rng.standard_normal(2)
    v_res = abs(0.02 * (s.t_phase if slip else 0.0) + 1e-4 * rng.standard_normal())
    if slip and s.t_phase > 0.1:
        regime = 2
    elif s.phase == "squeeze" and s.t_phase < 0.5:
        regime = 3
    else:
        regime = 1
    return {
        "area": area,
        "v_tan": (v_tx, v_ty, v_tz),
        "F_fric": (f_fx, f_fy, f_fz),
        "v_res": v_res,
        "regime": regime,
    }


#: The toy sponge's dry mass as a fraction of its initial water (the wrist load weighs both).
_TOY_DRY_FRACTION = 0.13

_NO_CONTACT: dict[str, Any] = {
    "area": 0.0,
    "v_tan": (0.0, 0.0, 0.0),
    "F_fric": (0.0, 0.0, 0.0),
    "v_res": float("nan"),
    "regime": 0,
}


def _record(
    s: _ToyState, sponge: _ToySponge, f_tgt: float, v_cmd: float, rng: np.random.Generator
) -> dict[str, Any]:
    """One row of the run file (the channels of ``_ALL``) from the state at a record."""
    a, v0, vp0 = sponge.a, sponge.v0, sponge.vp0
    strain = max(0.0, (a - s.w) / a)
    c = 1.0 if (s.f_meas > 1.0 and s.attached) else 0.0
    v_sp = v0 * (1.0 - strain)
    v_pore = max(vp0 - (v0 - v_sp), 0.05 * vp0)
    sat = min(1.0, s.m_l / (RHO_W * v_pore))
    imb = 0.03 * np.sin(7.0 * s.t) + 0.01 * rng.standard_normal()
    f_l = max(0.0, s.f_meas * (1.0 + imb)) * c
    f_r = max(0.0, s.f_meas * (1.0 - imb)) * c
    lifting = s.phase == "lift" and s.attached
    # Carried in the air, the pads hold the toy sponge and all its water.
    carried = s.attached and s.phase in ("lift", "waiting", "squeeze")
    w_z = -GRAVITY * (_TOY_DRY_FRACTION * sponge.m0 + sponge.m0) if carried else 0.0
    contact = _contact_row(s, sponge, strain, lifting, rng) if c else _NO_CONTACT
    onehot = [0.0, 0.0, 0.0, 0.0]
    onehot[contact["regime"]] = 1.0
    (v_tx, v_ty, v_tz), (f_fx, f_fy, f_fz) = contact["v_tan"], contact["F_fric"]
    return {
        "time": s.t,
        "phase": s.phase,
        "v_com_x": 0.0,
        "v_com_y": 0.0,
        "v_com_z": 0.05 if lifting else 0.0,
        "gate_open": s.phase in ("lift", "waiting", "squeeze"),
        "M_expelled": sponge.m0 - s.m_l,
        "lift_height": s.lift_h,
        "W_x": 0.0,
        "W_y": 0.0,
        "W_z": w_z,
        "M_L": s.m_l,
        "S": sat,
        "V_pore": v_pore,
        "V_sponge": v_sp,
        "w": s.w,
        "F_meas": s.f_meas * c,
        "F_L": f_l,
        "F_R": f_r,
        "alpha_F": abs(f_l - f_r) / (f_l + f_r + 1e-6),
        "A_L": contact["area"],
        "A_R": contact["area"] * (1.0 + 0.01 * imb),
        "c": c,
        "v_tan_x": v_tx,
        "v_tan_y": v_ty,
        "v_tan_z": v_tz,
        "F_fric_x": f_fx,
        "F_fric_y": f_fy,
        "F_fric_z": f_fz,
        "v_res": contact["v_res"],
        "r_none": onehot[0],
        "r_stick": onehot[1],
        "r_slip": onehot[2],
        "r_mixed": onehot[3],
        "F_target": f_tgt,
        "v_cmd": v_cmd,
    }


def _integrate(
    s: _ToyState, sponge: _ToySponge, v_cmd: float, record_dt: float, rng: np.random.Generator
) -> None:
    """Advance the state by one record interval (``_SUBSTEPS`` steps): gripper opening,
    measured force through its lag, drainage towards the force's equilibrium, lift."""
    a, m0 = sponge.a, sponge.m0
    dt = record_dt / _SUBSTEPS
    lifting = s.phase == "lift" and s.attached
    for _ in range(_SUBSTEPS):
        s.w -= v_cmd * dt
        s.w = min(max(s.w, 0.2 * a), a + 0.02)
        strain = max(0.0, (a - s.w) / a)
        s.n_noise = 0.9 * s.n_noise + 0.3 * rng.standard_normal()
        f_static = sponge.stiffness * strain * (1.0 + 2.0 * strain) + s.n_noise
        s.f_meas += dt / _TAU_F * (max(f_static, 0.0) - s.f_meas)
        s.f_meas = max(s.f_meas, 0.0)
        m_eq = m0 * (0.15 + 0.85 * np.exp(-s.f_meas / (60.0 * sponge.size_cm / 10.0)))
        if s.f_meas > 1.0:
            s.m_l += dt / _TAU_M * min(0.0, m_eq - s.m_l)
        if lifting:
            s.lift_h += 0.05 * dt
            s.m_l -= 0.002 * s.m_l * dt
        s.t += dt
        s.t_phase += dt
    s.t = round(s.t / record_dt) * record_dt
    s.t_phase = round(s.t_phase / record_dt) * record_dt
    if s.phase == "close":
        s.contact_steps = s.contact_steps + 1 if s.f_meas > 1.0 else 0
    if s.t > 30.0:
        raise RuntimeError("toy trial did not finish")


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
    sponge = _ToySponge.of(size_cm, porosity, F_hold, F_squeeze, rng)
    state = _ToyState(w=sponge.a + 0.01, m_l=sponge.m0, m0=sponge.m0)
    state.phase_start_water["settle"] = sponge.m0
    rows: dict[str, list[Any]] = {k: [] for k in _ALL}
    while _next_phase(state, sponge):
        f_tgt, v_cmd = _command(state, F_hold, F_squeeze)
        for k, v in _record(state, sponge, f_tgt, v_cmd, rng).items():
            rows[k].append(v)
        _integrate(state, sponge, v_cmd, record_dt, rng)
    state.close_phase()
    columns = {k: np.asarray(v) for k, v in rows.items()}
    outcome = {
        "lift_success": bool(sponge.lift_ok),
        "stable_squeeze": bool(sponge.lift_ok and sponge.squeeze_ok),
        "failure": state.failure,
        "water_removed": {
            p: float(state.water_removed[p]) for p in PHASES if p in state.water_removed
        },
        "initial_water": float(sponge.m0),
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
        # What the engine's own configs leave to the skeleton it builds (the dataset reads it).
        "m_dry": _TOY_DRY_FRACTION * sponge.m0,
    }
    return {"columns": columns, "outcome": outcome, "config": config}


_ALL = (
    "time phase v_com_x v_com_y v_com_z gate_open M_expelled lift_height W_x W_y W_z M_L S V_pore "
    "V_sponge w "
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
