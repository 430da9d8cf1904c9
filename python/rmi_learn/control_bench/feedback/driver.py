"""``rmi control-bench --protocol``: the goal-reaching benchmark under a committed protocol.

Steps: read the protocol and the sweep; draw the start states; per size and fold (one
held-out (porosity, F_hold) group each) fit the sensor-mode estimators on the other groups'
runs; when the protocol lists ``pi-settle``, ``mpc-settle`` or ``model-constant``, execute
the release probes from the tuning states and fit their models per fold on the other
groups' probes; execute the PI gain
candidates from the other groups' tuning states and keep, per fold
and estimator, the gains with the least mean reach error; execute every controller from the
test states with their own fold's choices; write the rows, the choices and the summary.
Rows are checkpointed per run under the protocol's digest: a rerun resumes, and an output of
another protocol is refused. Each run is replayed to its start states once; the states wait
in ``OUT/start_states/`` for the later phases and are removed at the end.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

import rmi_sph
from rmi_learn.control_bench.feedback.clusters import summarise_cell
from rmi_learn.control_bench.feedback.estimators import WINDOW
from rmi_learn.control_bench.feedback.fitting import Fits, fit_size, run_rows
from rmi_learn.control_bench.feedback.held_out import (
    RunInfo,
    StartTick,
    draw_states,
    fold_of,
    folds,
    read_runs,
)
from rmi_learn.control_bench.feedback.protocol import CONTROLLERS, Protocol, load_protocol
from rmi_learn.control_bench.feedback.release import PROBE_SCHEMA, SETTLE_CONTROLLER, fit_settle
from rmi_learn.control_bench.feedback.report import markdown
from rmi_learn.control_bench.feedback.settle_planner import PLANNERS, fit_plan
from rmi_learn.control_bench.feedback.start_states import STATES_DIR, Replay
from rmi_learn.control_bench.feedback.worker import RunJob, probe_job, run_job
from rmi_learn.data.checkpoint_rows import read_rows, write_rows
from rmi_learn.data.output_lock import output_lock
from rmi_learn.data.runs import atomic_write_json
from rmi_learn.errors import InputError
from rmi_learn.process_pool import ordered_map
from rmi_learn.sensing import dry_mass
from rmi_learn.sim.replay import load_index

LOCK_NAME = "control-bench-protocol"
ROWS_FILE = "protocol_rows.parquet"
PROBES_FILE = "release_probes.parquet"
DIGEST_KEY = "rmi.protocol.digest"
SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "size_cm": pl.Int64,
    "porosity": pl.Float64,
    "F_hold": pl.Float64,
    "F_squeeze": pl.Float64,
    "seed": pl.Int64,
    "tick": pl.Int64,
    "role": pl.String,
    "fold": pl.String,
    "task": pl.String,
    "goal_kg": pl.Float64,
    "controller": pl.String,
    "status": pl.String,
    "M_L_kg": pl.Float64,
    "abs_error_g": pl.Float64,
    "peak_force_N": pl.Float64,
    "ki": pl.Float64,
    "kp": pl.Float64,
    "setpoint_N": pl.Float64,
    "error": pl.String,
}


def _grid_name(runs_dir: Path) -> str:
    try:
        return str(json.loads((runs_dir / "grid.json").read_text()).get("name"))
    except (OSError, ValueError) as exc:
        raise InputError(f"--runs {runs_dir}: no readable grid.json ({exc})") from exc


def _load_done(path: Path, digest: str) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    try:
        meta, df = read_rows(path)
    except (OSError, pl.exceptions.PolarsError) as exc:
        raise InputError(f"{path} is not readable ({exc}); remove it to start over") from exc
    if meta.get(DIGEST_KEY) != digest:
        raise InputError(
            f"{path} was written under another protocol (digest {meta.get(DIGEST_KEY)!r:.20}); "
            "give a new --out or the protocol it was written with"
        )
    return df.to_dicts()


#: The files of a benchmark output that belong to its protocol.
OUTPUT_FILES = (ROWS_FILE, PROBES_FILE, "table_protocol.json", "table_protocol.md", STATES_DIR)


def set_aside(out: Path, digest: str, say: Any) -> Path | None:
    """When ``out`` holds rows written under another protocol than ``digest``'s, move its
    protocol files to the sibling folder ``<out>.<their protocol>-<digest, 12 hex>`` (kept,
    not removed) and return that folder; else None. An unreadable rows file stays and is
    refused as before."""
    for name in (ROWS_FILE, PROBES_FILE):
        try:
            meta, _ = read_rows(out / name)
        except (OSError, pl.exceptions.PolarsError):
            continue
        old = str(meta.get(DIGEST_KEY))
        if old == digest:
            continue
        label = f"{meta.get('rmi.protocol.name', 'protocol')}-{old[:12]}"
        dest = out.parent / f"{out.name}.{label}"
        dest.mkdir(exist_ok=True)
        for f in OUTPUT_FILES:
            if (out / f).exists():
                shutil.move(out / f, dest / f)
        say(f"{out} held the output of protocol {label}: moved to {dest}")
        return dest
    return None


def _dry_masses(runs: Sequence[RunInfo], threads: int) -> dict[str, float]:
    cache: dict[tuple[Any, ...], float] = {}
    out = {}
    for r in runs:
        key = (r.size_cm, r.porosity, json.dumps(r.config.get("particle_radius")))
        if key not in cache:
            cache[key] = dry_mass(rmi_sph.Trial(r.config, num_threads=threads))
        out[r.run_id] = cache[key]
    return out


def _fits(p: Protocol, runs: Sequence[RunInfo], threads: int) -> dict[int, dict[str, Fits]]:
    """Per size and fold, the estimators fitted on the runs of the fold's other groups."""
    out: dict[int, dict[str, Fits]] = {}
    dry = _dry_masses(runs, threads)
    # Each run's sensor rows serve every fold that trains on it: read and featurised once.
    rows = {r.run_id: run_rows(r, p.sensors, p["states"]["phases"], dry[r.run_id]) for r in runs}
    for size in sorted({r.size_cm for r in runs}):
        out[size] = {}
        for fold in folds(runs, size):
            train = [r for r in runs if r.size_cm == size and fold_of(r) != fold]
            out[size][fold] = fit_size(train, rows, dry)
    return {s: f for s, f in out.items() if f}


def _run_jobs(
    jobs: list[RunJob],
    workers: int,
    done: list[dict[str, Any]],
    save: Any,
    log: Any,
    what: str,
    work: Any = run_job,
) -> list[dict[str, Any]]:
    """Run ``work`` on ``jobs`` (in this process, or a pool of ``workers``), saving the rows
    after each."""
    rows = list(done)
    for i, (job, res) in enumerate(zip(jobs, ordered_map(work, jobs, workers), strict=True)):
        rows += res
        save(rows)
        log(f"{what}: run {i + 1}/{len(jobs)} done ({job.run.run_id})")
    return rows


def _replay(p: Protocol, run_id: str, ticks: Sequence[StartTick], folder: Path) -> Replay:
    """One replay of the run for every phase: all its start ticks, and the logged setpoints
    past them when a test state's scripted controller repeats them."""
    mine = [t for t in ticks if t.run_id == run_id]
    scripted = "scripted" in p["controllers"] and any(t.role == "test" for t in mine)
    return Replay(
        tuple(sorted({t.tick for t in mine})),
        int(p["horizon"]) if scripted else 0,
        WINDOW + p.sensors.latency_ticks,
        folder,
    )


def _jobs(
    p: Protocol,
    runs: Sequence[RunInfo],
    ticks: Sequence[StartTick],
    role: str,
    fits: dict[int, dict[str, Fits]],
    gains: dict[int, dict[str, dict[str, tuple[float, float]]]],
    done: set[str],
    threads: int,
    out: Path,
) -> list[RunJob]:
    by_run: dict[str, list[tuple[int, str]]] = {}
    for t in ticks:
        if t.role == role:
            by_run.setdefault(t.run_id, []).append((t.tick, t.role))
    info = {r.run_id: r for r in runs}
    jobs = []
    for rid, tt in sorted(by_run.items()):
        if rid in done:
            continue
        r = info[rid]
        own = fold_of(r)
        if role == "tuning":
            mine = {f: x for f, x in fits[r.size_cm].items() if f != own}
            g: dict[str, tuple[float, float]] = {}
        else:
            mine, g = {own: fits[r.size_cm][own]}, gains[r.size_cm][own]
        replay = _replay(p, rid, ticks, out / STATES_DIR)
        jobs.append(RunJob(r, tt, p.raw, p.sensors, mine, replay, g, threads))
    return jobs


def _release_probes(
    p: Protocol,
    infos: Sequence[RunInfo],
    ticks: Sequence[StartTick],
    fits: dict[int, dict[str, Fits]],
    out: Path,
    workers: int,
    threads: int,
    log: Any,
) -> None:
    """Execute the release probes of the tuning states (resumed per run from ``out``) and
    give each fold's fits the settle estimator (and, for ``mpc-settle``, the settled-water
    model) of the other groups' probes."""
    path = out / PROBES_FILE
    done = _load_done(path, p.digest)

    def save(rows: list[dict[str, Any]]) -> None:
        write_rows(path, rows, PROBE_SCHEMA, {DIGEST_KEY: p.digest, "rmi.protocol.name": p["name"]})

    probed = {r["run_id"] for r in done}
    jobs = _jobs(p, infos, ticks, "tuning", fits, {}, probed, threads, out)
    rows = _run_jobs(jobs, workers, done, save, log, "release probes", probe_job)
    for size, by_fold in fits.items():
        for fold, f in by_fold.items():
            fit = fit_settle(rows, size, fold, float(p["release_probes"]["penalty"]))
            if fit is None:
                raise InputError(
                    f"no release probe of the groups other than {fold} ({size} cm) ended ok: "
                    f"{SETTLE_CONTROLLER} has nothing to learn from (see {path})"
                )
            f.settle = fit.model
            f.report.update(fit.report)
            if set(PLANNERS) & set(p["controllers"]):
                spec = p["settle_model"]
                plan = fit_plan(rows, size, fold, float(spec["penalty"]), spec["inputs"])
                assert plan is not None  # the same probes as the settle fit's
                f.plan = plan.model
                f.report.update(plan.report)


def choose_gains(
    rows: Sequence[dict[str, Any]], names: Sequence[str], fold_names: dict[int, list[str]]
) -> dict[int, dict[str, dict[str, tuple[float, float]]]]:
    """Per size, fold and PI estimator, the (ki, kp) with the least mean error over the
    tuning states of the fold's other groups (reach error; settle error for ``pi-settle``;
    executed with the fold's own fits; the privileged loop's executions serve every fold).
    A failed execution counts as infinitely bad; ties take the smaller gains."""
    out: dict[int, dict[str, dict[str, tuple[float, float]]]] = {}
    tune = [r for r in rows if r["role"] == "tuning" and r["controller"] in names]
    for size, fold_list in fold_names.items():
        out[size] = {}
        for fold in fold_list:
            out[size][fold] = {}
            for name in names:
                score: dict[tuple[float, float], list[float]] = {}
                for r in tune:
                    own = f"{r['porosity']:g}/{r['F_hold']:g}"
                    serves = r["fold"] == fold if name != "pi-privileged" else own != fold
                    if r["size_cm"] == size and r["controller"] == name and serves:
                        e = r["abs_error_g"]
                        score.setdefault((r["ki"], r["kp"]), []).append(np.inf if e is None else e)
                if score:
                    out[size][fold][name] = min(
                        sorted(score), key=lambda g: float(np.mean(score[g]))
                    )
    return out


def summary(p: Protocol, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per size and task, :func:`summarise_cell` over the test rows."""
    test = [r for r in rows if r["role"] == "test"]
    out = []
    for size in sorted({r["size_cm"] for r in test}):
        for task in p["tasks"]:
            cell = [r for r in test if r["size_cm"] == size and r["task"] == task]
            lines = summarise_cell(
                cell,
                p["controllers"],
                p["references"],
                CONTROLLERS,
                int(p["bootstrap"]["resamples"]),
                int(p["bootstrap"]["seed"]),
            )
            out.append({"size_cm": size, "task": task, "controllers": lines})
    return out


def run_protocol_bench(
    protocol: str | Path,
    runs: str | Path,
    out: str | Path,
    workers: int = 1,
    threads: int = 1,
    log: Any = None,
    replace_other: bool = False,
) -> dict[str, Any]:
    """Run the benchmark of ``protocol`` (a file or a shipped name) on the sweep ``runs`` (a
    sweep output directory) into ``out``, with ``workers`` processes of ``threads`` engine
    threads each (results do not depend on either); returns the summary written to
    ``out/table_protocol.json``; ``log`` (a callable of one line) hears of each finished
    run. An output of another protocol in ``out`` is refused, or with ``replace_other``
    moved aside (:func:`set_aside`) and the benchmark started over."""
    say = log or (lambda msg: None)
    p = load_protocol(protocol)
    runs_p, out_p = Path(runs), Path(out)
    grid = _grid_name(runs_p)
    if grid != p["grid"]:
        raise InputError(
            f"protocol {p['name']} is for the {p['grid']!r} grid; --runs {runs_p} holds {grid!r}"
        )
    if workers < 1 or threads < 1:
        raise InputError("--workers and --threads must be at least 1")
    out_p.mkdir(parents=True, exist_ok=True)
    with output_lock(out_p, LOCK_NAME):
        if replace_other:
            set_aside(out_p, p.digest, say)
        sizes = set(p.raw.get("sizes_cm", [8, 10, 12]))
        infos = [r for r in read_runs(load_index(runs_p)) if r.size_cm in sizes]
        ticks = draw_states(infos, p["states"], int(p["horizon"]))
        fits = _fits(p, infos, threads)
        if {SETTLE_CONTROLLER, *PLANNERS} & set(p["controllers"]):
            _release_probes(p, infos, ticks, fits, out_p, workers, threads, say)
        rows_path = out_p / ROWS_FILE
        done = _load_done(rows_path, p.digest)

        def save(rows: list[dict[str, Any]]) -> None:
            write_rows(
                rows_path, rows, SCHEMA, {DIGEST_KEY: p.digest, "rmi.protocol.name": p["name"]}
            )

        pis = [c for c in p["controllers"] if c.startswith("pi-")]
        tuned = {r["run_id"] for r in done if r["role"] == "tuning"}
        jobs = _jobs(p, infos, ticks, "tuning", fits, {}, tuned, threads, out_p)
        rows = _run_jobs(jobs, workers, done, save, say, "tuning")
        gains = choose_gains(rows, pis, {s: list(f) for s, f in fits.items()})
        tested = {r["run_id"] for r in rows if r["role"] == "test"}
        jobs = _jobs(p, infos, ticks, "test", fits, gains, tested, threads, out_p)
        rows = _run_jobs(jobs, workers, rows, save, say, "test")
        # Every row is kept: the start states have served their phases.
        shutil.rmtree(out_p / STATES_DIR, ignore_errors=True)
        size_of = {r.run_id: r.size_cm for r in infos}
        result = {
            "protocol": p.raw,
            "protocol_digest": p.digest,
            "runs": str(runs_p),
            "folds": {str(s): list(f) for s, f in fits.items()},
            "states": {
                role: {
                    str(s): sum(1 for t in ticks if t.role == role and size_of[t.run_id] == s)
                    for s in sorted(fits)
                }
                for role in ("tuning", "test")
            },
            "estimators": {str(s): {f: x.report for f, x in ff.items()} for s, ff in fits.items()},
            "gains": {
                str(s): {f: {k: list(v) for k, v in g.items()} for f, g in gg.items()}
                for s, gg in gains.items()
            },
            "summary": summary(p, rows),
        }
        atomic_write_json(out_p / "table_protocol.json", result)
        (out_p / "table_protocol.md").write_text(markdown(result))
    return result


__all__ = ["ROWS_FILE", "choose_gains", "run_protocol_bench", "set_aside", "summary"]
