"""Dam-break throughput comparison: SPlisHSPlasH (pysplishsplash) against the rmi engine.

Both engines run the same scene, alternating in one invocation, each in a fresh process:

* SPlisHSPlasH's ``DamBreakModel`` geometry: a closed 4 x 3 x 1.5 m walled box (y up) with a
  1 x 1 x 1 m water column against one wall, particle radius 0.0125 m (39^3 = 59,319 fluid
  particles), rest density 1000 kg/m^3, gravity -9.81 m/s^2 on the vertical axis;
* fixed dt = 1 ms (no CFL adaptation), ``--steps`` steps (default 500);
* pressure solver DFSPH (max density error 0.05 %, at least 2 iterations, divergence solver on,
  max divergence error 0.1 %) or, with ``--method iisph``, SPlisHSPlasH's IISPH (same limits);
* explicit "Standard" viscosity with kinematic viscosity 0.01 m^2/s; no surface tension,
  vorticity, drag or XSPH; ``--threads`` worker threads (default 2, via OMP_NUM_THREADS).

Only the stepping loop is timed: scene loading and boundary volume-map generation are not.

Setup::

    python3 -m venv /tmp/sphvenv
    /tmp/sphvenv/bin/pip install pysplishsplash numpy

Run from anywhere (the rmi side is built with cargo from the repository root)::

    /tmp/sphvenv/bin/python benches/compare_splishsplash.py                 # 2 rounds, 500 steps
    /tmp/sphvenv/bin/python benches/compare_splishsplash.py --steps 50 --rounds 1
    /tmp/sphvenv/bin/python benches/compare_splishsplash.py --method iisph --json-out out/cmp.json
    /tmp/sphvenv/bin/python benches/compare_splishsplash.py --skip-rmi --rounds 1   # SPH only
    /tmp/sphvenv/bin/python benches/compare_splishsplash.py --only splishsplash --steps 500

Each round runs SPlisHSPlasH first, then ``target/release/dambreak --steps N --threads T --json``
(built once with ``cargo build --release -p rmi-benches --bin dambreak``). If the build fails or
the binary is missing, the SPlisHSPlasH figures are still reported. The final table gives the
median over rounds and the ratios rmi / SPlisHSPlasH of throughput (fluid particle-steps per
second, higher is better for rmi when > 1) and of milliseconds per pressure iteration (lower is
better for rmi when < 1); the latter is ms/step divided by solver iterations per step, computed
by this script for both engines, whatever each engine reports as ``ms_per_pressure_iteration``.
``--only splishsplash`` prints a single JSON line (the same keys as the rmi binary prints) and is
how the driver runs the SPlisHSPlasH half.

Notes on the SPlisHSPlasH side:

* the walls are the inverted unit-box mesh of DamBreakModel with Bender et al. 2019 volume maps
  (no boundary particles, so ``boundary_particles`` is 0); ``--sph-boundary akinci2012`` samples
  the walls with boundary particles instead;
* the headless simulator only initialises its boundary data inside ``runSimulation()``, so the
  loop is driven through ``runSimulation()`` with a per-step callback: the time between two
  callbacks is one step. The first step (which directly follows initialisation) is run untimed,
  so ``steps + 1`` steps are simulated and the last ``steps`` are timed;
* DFSPH's iteration count is density iterations + divergence iterations per step;
* ``mean_density_error`` is, averaged over the timed steps, the mean over fluid particles of
  max(rho / rho0 - 1, 0) (a fraction, 5e-4 == 0.05 %), read from the density field at the start
  of each step, outside the timed interval;
* SPlisHSPlasH picks the kernel per method: DFSPH runs the precomputed (tabulated) cubic
  spline, IISPH the analytic cubic spline; both are left as shipped.

Timings only mean something on an otherwise idle machine: for every run the driver records how
many CPU cores' worth of work other processes did meanwhile ("other CPU load") and warns when it
is noticeable. A round in which either run saw more than ``OTHER_LOAD_WARN`` cores of it is set
aside whole (both engines) from the medians, unless ``--keep-noisy`` or no round was quiet. After
the table the driver prints each round's own ratio (its two runs are back to back, so the
machine's drift over an evening cancels better than in the ratio of medians) and their median,
minimum and maximum over the quiet rounds; the JSON keeps them under ``paired``.
"""

from __future__ import annotations

import argparse
import ctypes
import importlib.metadata
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
# Importing pysplishsplash headless crashes (SIGSEGV) on Linux unless libGLdispatch is loaded
# before the module's own GL libraries.
GL_DISPATCH = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"

PARTICLE_RADIUS = 0.0125
DT = 1.0e-3
DENSITY0 = 1000.0
VISCOSITY = 0.01
GRAVITY = (0.0, -9.81, 0.0)
MAX_ERROR_PERCENT = 0.05
MAX_ERROR_V_PERCENT = 0.1
MIN_ITERATIONS = 2
MAX_ITERATIONS = 100
BOX_SCALE = (4.0, 3.0, 1.5)
BOX_TRANSLATION = (0.0, 1.5, 0.0)
# DamBreakModel uses a 40x30x15 volume map at r = 0.025; scaling it with 1/r keeps the map cell
# the same size relative to the kernel support.
REFERENCE_RADIUS = 0.025
REFERENCE_MAP_RESOLUTION = (40, 30, 15)

# A unit cube, faces wound counter-clockwise seen from outside; with mapInvert the inside of the
# box becomes the fluid domain, exactly as DamBreakModel's UnitBox.obj.
UNIT_BOX_OBJ = """\
v -0.5 -0.5 0.5
v 0.5 -0.5 0.5
v -0.5 0.5 0.5
v 0.5 0.5 0.5
v -0.5 0.5 -0.5
v 0.5 0.5 -0.5
v -0.5 -0.5 -0.5
v 0.5 -0.5 -0.5
f 1 2 3
f 3 2 4
f 3 4 5
f 5 4 6
f 5 6 7
f 7 6 8
f 7 8 1
f 1 8 2
f 2 8 4
f 4 8 6
f 7 1 5
f 5 1 3
"""

# CPU cores' worth of foreign work during a run above which its timings are flagged.
OTHER_LOAD_WARN = 0.15

ENGINE_NAMES = {"dfsph": "splishsplash-dfsph", "iisph": "splishsplash-iisph"}
JSON_KEYS = (
    "engine",
    "fluid_particles",
    "boundary_particles",
    "steps",
    "ms_per_step",
    "mean_pressure_iterations",
    "ms_per_pressure_iteration",
    "particle_steps_per_s",
    "mean_density_error",
    "peak_rss_bytes",
)


# --------------------------------------------------------------------------------------------
# SPlisHSPlasH child (--only splishsplash)
# --------------------------------------------------------------------------------------------


def ensure_preload(threads: int) -> None:
    """Re-exec with LD_PRELOAD / OMP_NUM_THREADS set: both are read at library load time."""
    preload = os.environ.get("LD_PRELOAD", "")
    want_preload = os.path.exists(GL_DISPATCH) and GL_DISPATCH not in preload.split(":")
    want_omp = os.environ.get("OMP_NUM_THREADS") != str(threads)
    if not (want_preload or want_omp):
        return
    env = dict(os.environ)
    if want_preload:
        env["LD_PRELOAD"] = f"{GL_DISPATCH}:{preload}" if preload else GL_DISPATCH
    env["OMP_NUM_THREADS"] = str(threads)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, str(Path(__file__).resolve()), *sys.argv[1:]], env)


def map_resolution(radius: float) -> list[int]:
    return [max(1, round(n * REFERENCE_RADIUS / radius)) for n in REFERENCE_MAP_RESOLUTION]


def build_scene(sph, workdir: Path, method: str, boundary: str) -> Path:
    box = workdir / "UnitBox.obj"
    box.write_text(UNIT_BOX_OBJ)
    if method == "dfsph":
        sim_method = int(sph.SimulationMethods.DFSPH)
        solver = {
            "DFSPH": {
                "minIterations": MIN_ITERATIONS,
                "maxIterations": MAX_ITERATIONS,
                "maxError": MAX_ERROR_PERCENT,
                "maxIterationsV": MAX_ITERATIONS,
                "maxErrorV": MAX_ERROR_V_PERCENT,
                "enableDivergenceSolver": True,
            }
        }
    else:
        sim_method = int(sph.SimulationMethods.IISPH)
        solver = {
            "IISPH": {
                "minIterations": MIN_ITERATIONS,
                "maxIterations": MAX_ITERATIONS,
                "maxError": MAX_ERROR_PERCENT,
            }
        }
    boundary_method = {
        "bender2019": int(sph.BoundaryHandlingMethods.Bender2019),
        "akinci2012": int(sph.BoundaryHandlingMethods.Akinci2012),
    }[boundary]
    scene = {
        "Configuration": {
            "particleRadius": PARTICLE_RADIUS,
            "simulationMethod": sim_method,
            "gravitation": list(GRAVITY),
            "timeStepSize": DT,
            "cflMethod": 0,
            "boundaryHandlingMethod": boundary_method,
            **solver,
        },
        "Materials": [
            {
                "id": "Fluid",
                "density0": DENSITY0,
                "viscosityMethod": 1,
                "viscosity": VISCOSITY,
                "viscosityBoundary": 0.0,
                "surfaceTensionMethod": 0,
                "vorticityMethod": 0,
                "dragMethod": 0,
                "elasticityMethod": 0,
            }
        ],
        "RigidBodies": [
            {
                "geometryFile": box.name,
                "translation": list(BOX_TRANSLATION),
                "rotationAxis": [1, 0, 0],
                "rotationAngle": 0,
                "scale": list(BOX_SCALE),
                "isDynamic": False,
                "isWall": True,
                "mapInvert": True,
                "mapThickness": 0.0,
                "mapResolution": map_resolution(PARTICLE_RADIUS),
            }
        ],
        "FluidBlocks": [
            {
                "denseMode": 0,
                "start": [-0.5, 0.0, -0.5],
                "end": [0.5, 1.0, 0.5],
                "translation": [-1.45, 0.05, 0.0],
                "scale": [1, 1, 1],
            }
        ],
    }
    path = workdir / f"dambreak_{method}_{boundary}.json"
    path.write_text(json.dumps(scene, indent=1))
    return path


def enum_name(obj, param: int) -> str:
    value = obj.getValueInt(param)
    names = {e.id: e.name for e in obj.getEnumValues(param)}
    return names.get(value, str(value))


def read_back_config(sph, base, method: str) -> dict:
    """Read the parameters SPlisHSPlasH actually uses, so a silently ignored JSON key shows."""
    sim = sph.Simulation.getCurrent()
    ts = sim.getTimeStep()
    fluid = sim.getFluidModel(0)
    visc = fluid.getViscosityBase()
    xsph = fluid.getXSPH()
    cfg = {
        "time_step_method": ts.getMethodName(),
        "dt": sph.TimeManager.getCurrent().getTimeStepSize(),
        "cfl_method": sim.getValueInt(sim.CFL_METHOD),
        "boundary_method": sim.getBoundaryHandlingMethod().name,
        "particle_radius": sim.getValueFloat(sim.PARTICLE_RADIUS),
        "support_radius": sim.getSupportRadius(),
        "gravity": [float(g) for g in sim.getVec3ValueReal(sim.GRAVITATION)],
        "density0": fluid.getDensity0(),
        "z_sort": sim.getValueBool(sim.ENABLE_Z_SORT),
        "kernel": enum_name(sim, sim.KERNEL_METHOD),
        "grad_kernel": enum_name(sim, sim.GRAD_KERNEL_METHOD),
        "max_error_percent": ts.getValueFloat(ts.MAX_ERROR),
        "min_iterations": ts.getValueUInt(ts.MIN_ITERATIONS),
        "max_iterations": ts.getValueUInt(ts.MAX_ITERATIONS),
        "viscosity_method": visc.getMethodName() if visc is not None else None,
        "viscosity": visc.getValueFloat(visc.VISCOSITY_COEFFICIENT) if visc is not None else 0.0,
        "viscosity_boundary": (
            visc.getValueFloat(visc.VISCOSITY_COEFFICIENT_BOUNDARY) if visc is not None else 0.0
        ),
        "surface_tension_method": fluid.getSurfaceTensionMethod(),
        "vorticity_method": fluid.getVorticityMethod(),
        "drag_method": fluid.getDragMethod(),
        "elasticity_method": fluid.getElasticityMethod(),
        "xsph": xsph.getValueFloat(xsph.FLUID_COEFFICIENT),
        "stop_at": base.getValueFloat(base.STOP_AT),
    }
    if method == "dfsph":
        cfg["max_error_v_percent"] = ts.getValueFloat(ts.MAX_ERROR_V)
        cfg["divergence_solver"] = ts.getValueBool(ts.USE_DIVERGENCE_SOLVER)
    return cfg


def check_config(cfg: dict, method: str) -> list[str]:
    problems = []

    def near(a: float, b: float) -> bool:
        return abs(a - b) <= 1e-6 * max(1.0, abs(b))

    if cfg["time_step_method"].lower() != method:
        problems.append(f"time step method {cfg['time_step_method']}")
    if not near(cfg["dt"], DT) or cfg["cfl_method"] != 0:
        problems.append(f"dt {cfg['dt']} / cfl {cfg['cfl_method']}")
    if not near(cfg["particle_radius"], PARTICLE_RADIUS):
        problems.append(f"radius {cfg['particle_radius']}")
    if not near(cfg["max_error_percent"], MAX_ERROR_PERCENT):
        problems.append(f"max error {cfg['max_error_percent']}")
    if cfg["min_iterations"] < MIN_ITERATIONS:
        problems.append(f"min iterations {cfg['min_iterations']}")
    if cfg["viscosity_method"] != "Standard viscosity" or not near(cfg["viscosity"], VISCOSITY):
        problems.append(f"viscosity {cfg['viscosity_method']} {cfg['viscosity']}")
    extras = ("surface_tension_method", "vorticity_method", "drag_method", "elasticity_method")
    if any(cfg[k] != 0 for k in extras) or cfg["xsph"] != 0.0:
        problems.append("unexpected non-pressure forces enabled")
    if any(not near(a, b) for a, b in zip(cfg["gravity"], GRAVITY, strict=True)):
        problems.append(f"gravity {cfg['gravity']}")
    return problems


def peak_rss_self() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class StdoutToStderr:
    """SPlisHSPlasH logs to stdout; keep the child's stdout for the one JSON result line."""

    def __enter__(self):
        sys.stdout.flush()
        self.saved = os.dup(1)
        os.dup2(2, 1)
        return self

    def __exit__(self, *exc):
        sys.stdout.flush()
        # C stdio may still hold buffered log text that would otherwise land after the JSON.
        ctypes.CDLL(None).fflush(None)
        os.dup2(self.saved, 1)
        os.close(self.saved)
        return False


def run_splishsplash(args) -> dict:
    ensure_preload(args.threads)
    # Imported here, after the re-exec: the driver process never loads the GL-linked module.
    import numpy as np
    import pysplishsplash as sph

    try:
        sph_version = importlib.metadata.version("pysplishsplash")
    except importlib.metadata.PackageNotFoundError:
        sph_version = "unknown"

    own_tmp = None
    if args.workdir:
        workdir = Path(args.workdir)
    else:
        own_tmp = tempfile.TemporaryDirectory(prefix="sph_dambreak_")
        workdir = Path(own_tmp.name)
    workdir.mkdir(parents=True, exist_ok=True)
    # Volume maps are cached next to the scene file, so runs sharing a workdir build them once.
    scene_file = build_scene(sph, workdir, args.method, args.sph_boundary)
    steps = args.steps

    rec_ms: list[float] = []
    rec_it: list[int] = []
    rec_itv: list[int] = []
    rec_err: list[float] = []
    state = {"calls": 0, "mark": None}

    with StdoutToStderr():
        t_setup = time.perf_counter()
        base = sph.Exec.SimulatorBase()
        base.init(
            useGui=False,
            sceneFile=str(scene_file),
            outputDir=str(workdir / "output"),
            initialPause=False,
        )
        base.initSimulation()
        # The headless loop refuses to start without a positive stop time; the callback below
        # ends the run by step count instead.
        base.setValueFloat(base.STOP_AT, 1.0e6)
        cfg = read_back_config(sph, base, args.method)
        problems = check_config(cfg, args.method)
        if problems:
            raise SystemExit(
                "SPlisHSPlasH scene does not match the benchmark: " + "; ".join(problems)
            )

        sim = sph.Simulation.getCurrent()
        ts = sim.getTimeStep()
        fluid = sim.getFluidModel(0)
        has_v = hasattr(ts, "SOLVER_ITERATIONS_V")
        density = np.asarray(fluid.getFieldBuffer("density"))
        setup_end = [0.0]

        def on_step() -> None:
            now = time.perf_counter()
            calls = state["calls"]
            if calls == 0:
                setup_end[0] = now
            else:
                rec_ms.append((now - state["mark"]) * 1e3)
                rec_it.append(int(ts.getValueUInt(ts.SOLVER_ITERATIONS)))
                rec_itv.append(int(ts.getValueUInt(ts.SOLVER_ITERATIONS_V)) if has_v else 0)
                n = fluid.numActiveParticles()
                rho = density[:n] / DENSITY0 - 1.0
                rec_err.append(float(np.maximum(rho, 0.0).mean()))
            state["calls"] = calls + 1
            if state["calls"] > steps:
                base.setValueFloat(base.STOP_AT, 1.0e-12)
            # Re-read the clock so this bookkeeping stays out of the next step's interval.
            state["mark"] = time.perf_counter()

        base.setTimeStepCB(on_step)
        base.runSimulation()
        n_fluid = int(fluid.numActiveParticles())
        n_boundary = 0
        if cfg["boundary_method"] == "Akinci2012":
            n_boundary = sum(
                int(sim.getBoundaryModel(i).numberOfParticles())
                for i in range(sim.numberOfBoundaryModels())
            )
        sim_time = float(sph.TimeManager.getCurrent().getTime())
        base.cleanup()

    if len(rec_ms) != steps:
        raise SystemExit(f"expected {steps} timed steps, got {len(rec_ms)}")
    total_ms = sum(rec_ms)
    ms_per_step = total_ms / steps
    mean_it = statistics.fmean(rec_it)
    mean_itv = statistics.fmean(rec_itv)
    mean_total = mean_it + mean_itv
    result = {
        "engine": ENGINE_NAMES[args.method],
        "fluid_particles": n_fluid,
        "boundary_particles": n_boundary,
        "steps": steps,
        "ms_per_step": ms_per_step,
        "mean_pressure_iterations": mean_total,
        "ms_per_pressure_iteration": ms_per_step / mean_total if mean_total else None,
        "particle_steps_per_s": n_fluid * steps / (total_ms * 1e-3),
        "mean_density_error": statistics.fmean(rec_err),
        "peak_rss_bytes": peak_rss_self(),
        # Extras beyond the shared keys.
        "mean_density_iterations": mean_it,
        "mean_divergence_iterations": mean_itv,
        "median_ms_per_step": statistics.median(rec_ms),
        # Scene loading, volume-map generation and the untimed first step.
        "untimed_setup_s": setup_end[0] - t_setup,
        "simulated_time_s": sim_time,
        "threads": args.threads,
        "version": sph_version,
        "config": cfg,
        "per_step": {"ms": rec_ms, "iterations": rec_it, "iterations_v": rec_itv},
    }
    if own_tmp is not None:
        own_tmp.cleanup()
    return result


# --------------------------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------------------------


def busy_cpu_seconds() -> float | None:
    """Machine-wide busy CPU time so far, from /proc/stat (None where unavailable)."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
    except OSError:
        return None
    # user nice system idle iowait irq softirq steal: everything but idle and iowait is busy.
    ticks = [int(x) for x in fields[1:9]]
    busy = sum(ticks) - ticks[3] - ticks[4]
    return busy / os.sysconf("SC_CLK_TCK")


def run_child(cmd: list[str], env: dict, log_path: Path) -> tuple[int, str, dict]:
    """Run one engine; returns (exit code, stdout, process statistics).

    wait4 gives this child's own rusage; RUSAGE_CHILDREN would be the maximum over every child
    reaped so far, which hides a smaller second engine. The CPU time the rest of the machine
    burnt meanwhile tells whether the timings were taken on a quiet machine.
    """
    with tempfile.TemporaryFile() as out, open(log_path, "wb") as err:
        busy0 = busy_cpu_seconds()
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        busy1 = busy_cpu_seconds()
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        stdout = out.read().decode(errors="replace")
    cpu = usage.ru_utime + usage.ru_stime
    stats = {
        "peak_rss_bytes_wait4": usage.ru_maxrss * 1024,
        "process_wall_s": wall,
        "process_cpu_s": cpu,
        "other_load": None,
    }
    if busy0 is not None and busy1 is not None and wall > 0:
        stats["other_load"] = max(0.0, (busy1 - busy0 - cpu) / wall)
    return proc.returncode, stdout, stats


def check_quiet(res: dict) -> None:
    load = res.get("other_load")
    if load is not None and load > OTHER_LOAD_WARN:
        print(
            f"  warning: other processes used {load:.2f} CPU cores on average during this run; "
            "its timings are not trustworthy",
            file=sys.stderr,
        )


def last_json_line(text: str) -> dict | None:
    for raw in reversed(text.splitlines()):
        line = raw.strip()
        if line.startswith("{"):
            try:
                obj = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(obj, dict) and "engine" in obj:
                return obj
    return None


def tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def rmi_binary() -> Path:
    target = os.environ.get("CARGO_TARGET_DIR")
    target_dir = Path(target) if target else REPO_ROOT / "target"
    if not target_dir.is_absolute():
        target_dir = REPO_ROOT / target_dir
    return target_dir / "release" / "dambreak"


def build_rmi(skip: bool) -> tuple[Path | None, str]:
    binary = rmi_binary()
    if not skip:
        cmd = ["cargo", "build", "--release", "-p", "rmi-benches", "--bin", "dambreak"]
        print("building rmi:", " ".join(cmd), flush=True)
        try:
            res = subprocess.run(cmd, cwd=REPO_ROOT, capture_output=True, text=True, check=False)
        except FileNotFoundError:
            return None, "cargo not found on PATH"
        if res.returncode != 0:
            lines = res.stderr.strip().splitlines()
            first_error = next((x for x in lines if x.startswith("error")), "see cargo output")
            detail = "\n".join(lines[-12:])
            return None, f"cargo build failed (exit {res.returncode}): {first_error}\n{detail}"
    if not binary.is_file():
        return None, f"rmi binary not found at {binary}"
    return binary, ""


def run_sph_round(args, workdir: Path, log_dir: Path, rnd: int) -> dict:
    env = dict(os.environ)
    env["OMP_NUM_THREADS"] = str(args.threads)
    if os.path.exists(GL_DISPATCH):
        pre = env.get("LD_PRELOAD", "")
        if GL_DISPATCH not in pre.split(":"):
            env["LD_PRELOAD"] = f"{GL_DISPATCH}:{pre}" if pre else GL_DISPATCH
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--only",
        "splishsplash",
        "--steps",
        str(args.steps),
        "--threads",
        str(args.threads),
        "--method",
        args.method,
        "--sph-boundary",
        args.sph_boundary,
        "--workdir",
        str(workdir),
    ]
    log = log_dir / f"splishsplash_round{rnd}.log"
    rc, stdout, stats = run_child(cmd, env, log)
    res = last_json_line(stdout)
    if rc != 0 or res is None:
        return {"error": f"SPlisHSPlasH run failed (exit {rc}); log tail:\n{tail(log)}"}
    res.update(stats)
    return res


def run_rmi_round(args, binary: Path, log_dir: Path, rnd: int) -> dict:
    env = dict(os.environ)
    # The GL preload is only for pysplishsplash; keep it away from the Rust binary.
    env.pop("LD_PRELOAD", None)
    env["RAYON_NUM_THREADS"] = str(args.threads)
    cmd = [str(binary), "--steps", str(args.steps), "--threads", str(args.threads), "--json"]
    log = log_dir / f"rmi_round{rnd}.log"
    rc, stdout, stats = run_child(cmd, env, log)
    res = last_json_line(stdout)
    if rc != 0 or res is None:
        return {"error": f"rmi run failed (exit {rc}); stderr tail:\n{tail(log)}"}
    warnings = []
    missing = [k for k in JSON_KEYS if k not in res]
    if missing:
        warnings.append(f"missing keys: {', '.join(missing)}")
    if res.get("steps") != args.steps:
        warnings.append(f"ran {res.get('steps')} steps, asked for {args.steps}")
    if warnings:
        res["warning"] = "; ".join(warnings)
    res.update(stats)
    return res


def summarize(results: list[dict]) -> dict | None:
    ok = [r for r in results if "error" not in r]
    if not ok:
        return None
    out = {"engine": ok[0].get("engine"), "rounds": len(ok)}
    numeric = tuple(k for k in JSON_KEYS if k not in ("engine", "steps")) + (
        "peak_rss_bytes_wait4",
        "other_load",
    )
    for key in numeric:
        vals = [r[key] for r in ok if isinstance(r.get(key), (int, float))]
        out[key] = statistics.median(vals) if vals else None
    # Engines may time "a pressure iteration" differently (e.g. solver loop only); this one is
    # computed the same way for both, from the whole step, so it is the one the ratio uses.
    per_step_per_it = [
        r["ms_per_step"] / r["mean_pressure_iterations"]
        for r in ok
        if isinstance(r.get("ms_per_step"), (int, float)) and r.get("mean_pressure_iterations")
    ]
    out["ms_per_step_per_iteration"] = (
        statistics.median(per_step_per_it) if per_step_per_it else None
    )
    return out


def ratio(a, b):
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and b:
        return a / b
    return None


def round_load(entry: dict) -> float | None:
    """The larger other-CPU load of a round's runs (cores), None when neither was measured."""
    loads = [
        r.get("other_load")
        for r in (entry.get("splishsplash"), entry.get("rmi"))
        if isinstance(r, dict) and isinstance(r.get("other_load"), (int, float))
    ]
    return max(loads) if loads else None


def is_quiet(entry: dict, max_load: float = OTHER_LOAD_WARN) -> bool:
    """Whether no run of the round saw more than `max_load` cores of other processes' work
    (a round whose load was not measured counts as quiet)."""
    return (round_load(entry) or 0.0) <= max_load


def quiet_rounds(rounds: list[dict], max_load: float = OTHER_LOAD_WARN) -> list[dict]:
    """The quiet rounds (see `is_quiet`).

    A round is kept or set aside whole, so that the medians of both engines come from the
    same stretches of time (the machine's speed drifts; a round's two runs are back to back).
    """
    return [e for e in rounds if is_quiet(e, max_load)]


def paired(rounds: list[dict], max_load: float = OTHER_LOAD_WARN) -> dict:
    """Per-round throughput ratios rmi / SPlisHSPlasH and their spread over the quiet rounds.

    The ratio of one round compares two runs made minutes apart, so it is less exposed to the
    machine's drift over an evening than the ratio of the two engines' medians; its spread
    over rounds is what a claim about the ratio has to survive.
    """
    per_round = []
    for e in rounds:
        sph, rmi = e.get("splishsplash") or {}, e.get("rmi") or {}
        # A failed or missing run has no throughput, so `ratio` gives None.
        r = ratio(rmi.get("particle_steps_per_s"), sph.get("particle_steps_per_s"))
        if r is None or "error" in sph or "error" in rmi:
            continue
        per_round.append(
            {
                "round": e.get("round"),
                "ratio": r,
                "other_load": round_load(e),
                "quiet": is_quiet(e, max_load),
            }
        )
    quiet = [p["ratio"] for p in per_round if p["quiet"]]
    return {
        "rounds": per_round,
        "max_other_load": max_load,
        "quiet_rounds": len(quiet),
        "set_aside": len(per_round) - len(quiet),
        "median": statistics.median(quiet) if quiet else None,
        "min": min(quiet) if quiet else None,
        "max": max(quiet) if quiet else None,
    }


def print_paired(pairs: dict) -> None:
    if not pairs["rounds"]:
        return
    print()
    print("per round (rmi / SPlisHSPlasH throughput, the round's two runs back to back):")
    for p in pairs["rounds"]:
        note = "" if p["quiet"] else f"  set aside: other load {p['other_load']:.2f} cores"
        print(f"  round {p['round']}: {p['ratio']:.3f}{note}")
    if pairs["quiet_rounds"]:
        print(
            f"median of {pairs['quiet_rounds']} quiet round(s): {pairs['median']:.3f} "
            f"(min {pairs['min']:.3f}, max {pairs['max']:.3f}); {pairs['set_aside']} set aside"
        )
    else:
        print(
            "no quiet round: every round saw other processes' work; "
            "the ratios above are not trustworthy"
        )


def fmt(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def print_table(sph: dict | None, rmi: dict | None, args) -> dict:
    def get(d, key):
        return None if d is None else d.get(key)

    def mib(d):
        v = get(d, "peak_rss_bytes") or get(d, "peak_rss_bytes_wait4")
        return None if v is None else v / 2**20

    def mps(d):
        v = get(d, "particle_steps_per_s")
        return None if v is None else v / 1e6

    def pct(d):
        v = get(d, "mean_density_error")
        return None if v is None else v * 100.0

    rows = [
        ("fluid particles", lambda d: get(d, "fluid_particles"), ".0f"),
        ("boundary particles", lambda d: get(d, "boundary_particles"), ".0f"),
        ("ms / step", lambda d: get(d, "ms_per_step"), ".2f"),
        ("pressure iterations / step", lambda d: get(d, "mean_pressure_iterations"), ".2f"),
        ("ms/step / iterations", lambda d: get(d, "ms_per_step_per_iteration"), ".3f"),
        ("ms / iteration (reported)", lambda d: get(d, "ms_per_pressure_iteration"), ".3f"),
        ("M fluid particle-steps / s", mps, ".3f"),
        ("mean density error (%)", pct, ".4f"),
        ("peak RSS (MiB)", mib, ".0f"),
        ("other CPU load (cores)", lambda d: get(d, "other_load"), ".2f", False),
    ]
    sph_name = get(sph, "engine") or ENGINE_NAMES[args.method]
    n_rounds = max(get(sph, "rounds") or 0, get(rmi, "rounds") or 0)
    print()
    print(
        f"dam break, dt {DT * 1e3:g} ms, {args.steps} steps, {args.threads} threads, "
        f"median of {n_rounds} round(s)"
    )
    header = f"{'':28s}{sph_name:>20s}{'rmi':>14s}{'rmi / SPH':>12s}"
    print(header)
    print("-" * len(header))
    for label, fn, spec, *with_ratio in rows:
        a, b = fn(sph), fn(rmi)
        r = ratio(b, a) if not with_ratio or with_ratio[0] else None
        print(f"{label:28s}{fmt(a, spec):>20s}{fmt(b, spec):>14s}{fmt(r, '.3f'):>12s}")
    thr = ratio(get(rmi, "particle_steps_per_s"), get(sph, "particle_steps_per_s"))
    per_it = ratio(get(rmi, "ms_per_step_per_iteration"), get(sph, "ms_per_step_per_iteration"))
    print()
    print(f"throughput ratio rmi / {sph_name}: {fmt(thr, '.3f')}  (> 1: rmi faster)")
    print(
        f"ms-per-iteration ratio rmi / {sph_name}: {fmt(per_it, '.3f')}  "
        "(ms/step / iterations; < 1: rmi cheaper)"
    )
    for d in (sph, rmi):
        reported, uniform = get(d, "ms_per_pressure_iteration"), get(d, "ms_per_step_per_iteration")
        if reported and uniform and abs(reported - uniform) > 0.05 * uniform:
            print(
                f"note: {get(d, 'engine')} reports {reported:.3f} ms per pressure iteration, not "
                f"ms/step / iterations = {uniform:.3f}: it times the iterations differently"
            )
    return {"throughput_rmi_over_sph": thr, "ms_per_iteration_rmi_over_sph": per_it}


def one_line(res: dict) -> str:
    if "error" in res:
        return "FAILED"
    return (
        f"{res['ms_per_step']:.2f} ms/step, "
        f"{res['mean_pressure_iterations']:.2f} it/step, "
        f"{fmt(res.get('ms_per_pressure_iteration'), '.3f')} ms/it, "
        f"{res['particle_steps_per_s'] / 1e6:.3f} M particle-steps/s, "
        f"{res['fluid_particles']} fluid"
    )


def drive(args) -> int:
    binary, why = (None, "skipped (--skip-rmi)")
    if not args.skip_rmi:
        binary, why = build_rmi(args.no_build)
        if binary is None:
            print(f"rmi engine unavailable: {why}", file=sys.stderr)
            print("continuing with SPlisHSPlasH only", file=sys.stderr)

    rounds = []
    with tempfile.TemporaryDirectory(prefix="sph_cmp_") as tmp:
        tmp_path = Path(tmp)
        log_dir = Path(args.log_dir) if args.log_dir else tmp_path
        log_dir.mkdir(parents=True, exist_ok=True)
        for rnd in range(1, args.rounds + 1):
            entry = {"round": rnd}
            if not args.skip_splishsplash:
                print(f"round {rnd}/{args.rounds}: SPlisHSPlasH ({args.method}) ...", flush=True)
                entry["splishsplash"] = run_sph_round(args, tmp_path / "scene", log_dir, rnd)
                print(f"  {one_line(entry['splishsplash'])}", flush=True)
                check_quiet(entry["splishsplash"])
                if "error" in entry["splishsplash"]:
                    print(entry["splishsplash"]["error"], file=sys.stderr)
            if binary is not None:
                print(f"round {rnd}/{args.rounds}: rmi ...", flush=True)
                entry["rmi"] = run_rmi_round(args, binary, log_dir, rnd)
                print(f"  {one_line(entry['rmi'])}", flush=True)
                check_quiet(entry["rmi"])
                if "error" in entry["rmi"]:
                    print(entry["rmi"]["error"], file=sys.stderr)
                elif "warning" in entry["rmi"]:
                    print(f"  warning: {entry['rmi']['warning']}", file=sys.stderr)
            rounds.append(entry)

    # The medians come from the quiet rounds unless there is none (or --keep-noisy).
    used = rounds if args.keep_noisy else (quiet_rounds(rounds) or rounds)
    if len(used) < len(rounds):
        print(
            f"\n{len(rounds) - len(used)} of {len(rounds)} round(s) set aside: other processes "
            f"used more than {OTHER_LOAD_WARN} CPU cores during a run (--keep-noisy keeps them)"
        )
    sph_summary = summarize([r["splishsplash"] for r in used if "splishsplash" in r])
    rmi_summary = summarize([r["rmi"] for r in used if "rmi" in r])
    if binary is None:
        print(f"\nrmi: not run ({why.splitlines()[0]})")
    ratios = print_table(sph_summary, rmi_summary, args)
    pairs = paired(rounds)
    print_paired(pairs)
    if sph_summary and rmi_summary:
        nf_a, nf_b = sph_summary["fluid_particles"], rmi_summary["fluid_particles"]
        if nf_a and nf_b and abs(nf_a - nf_b) > 0.01 * nf_a:
            print(f"warning: fluid particle counts differ ({nf_a} vs {nf_b})", file=sys.stderr)

    if args.json_out:
        doc = {
            "scene": {
                "geometry": "SPlisHSPlasH DamBreakModel",
                "box_m": list(BOX_SCALE),
                "column_m": [1.0, 1.0, 1.0],
                "particle_radius": PARTICLE_RADIUS,
                "dt": DT,
                "steps": args.steps,
                "method": args.method,
                "sph_boundary": args.sph_boundary,
                "max_error_percent": MAX_ERROR_PERCENT,
                "min_iterations": MIN_ITERATIONS,
                "viscosity": VISCOSITY,
                "threads": args.threads,
            },
            "host": {
                "machine": platform.machine(),
                "processor": platform.processor(),
                "cpus": os.cpu_count(),
                "python": platform.python_version(),
                "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            },
            "rmi_binary": str(binary) if binary else None,
            "rmi_unavailable": None if binary else why,
            "rounds": rounds,
            "median": {"splishsplash": sph_summary, "rmi": rmi_summary},
            "ratios": ratios,
            "paired": pairs,
            "rounds_in_medians": [r["round"] for r in used],
        }
        out = Path(args.json_out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(doc, indent=1))
        print(f"\nwrote {out}")
    return 0 if sph_summary or rmi_summary else 1


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="Dam break: SPlisHSPlasH vs rmi, alternating rounds.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--steps", type=int, default=500, help="timed steps per run")
    p.add_argument("--rounds", type=int, default=2, help="SPlisHSPlasH-then-rmi rounds")
    p.add_argument("--threads", type=int, default=2, help="worker threads for both engines")
    p.add_argument("--method", choices=("dfsph", "iisph"), default="dfsph")
    p.add_argument(
        "--sph-boundary",
        choices=("bender2019", "akinci2012"),
        default="bender2019",
        help="SPlisHSPlasH wall model: volume maps (as DamBreakModel) or boundary particles",
    )
    p.add_argument(
        "--only",
        choices=("splishsplash",),
        help="run one SPlisHSPlasH simulation in this process and print one JSON line "
        "(what the driver runs in its SPlisHSPlasH subprocess)",
    )
    p.add_argument("--json-out", help="write all results to this JSON file")
    p.add_argument("--no-build", action="store_true", help="use the existing rmi binary")
    p.add_argument("--skip-rmi", action="store_true", help="run only the SPlisHSPlasH rounds")
    p.add_argument("--skip-splishsplash", action="store_true", help="run only the rmi rounds")
    p.add_argument("--log-dir", help="keep the engines' stderr logs here")
    p.add_argument(
        "--keep-noisy",
        action="store_true",
        help="take the medians over every round, also those in which other processes used "
        f"more than {OTHER_LOAD_WARN} CPU cores (by default such rounds are set aside when a "
        "quiet one exists)",
    )
    p.add_argument("--workdir", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.steps < 1 or args.rounds < 1 or args.threads < 1:
        p.error("--steps, --rounds and --threads must be positive")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.only == "splishsplash":
        result = run_splishsplash(args)
        print(json.dumps(result), flush=True)
        print(f"{result['engine']}: {one_line(result)}", file=sys.stderr)
        return 0
    return drive(args)


if __name__ == "__main__":
    sys.exit(main())
