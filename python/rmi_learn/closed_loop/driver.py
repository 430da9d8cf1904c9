"""The closed-loop driver (``rmi closed-loop``): check the inputs, replay every run to its
windows' anchors, execute their chunks (runs side by side when there are threads for it) with
a checkpoint after every window or run, and write the tables. See
:mod:`rmi_learn.closed_loop`."""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm  # type: ignore[import-untyped]

import rmi_sph
from rmi_learn import __version__
from rmi_learn.closed_loop.execute import failed_rows, window_rows
from rmi_learn.closed_loop.table import (
    FINGERPRINT_KEY,
    TABLE_STEM,
    WINDOWS_FILE,
    markdown,
    read_checkpoint,
    summarise,
    write_checkpoint,
)
from rmi_learn.closed_loop.windows import (
    COMMAND_MODES,
    ClosedLoopError,
    Window,
    as_closed_loop_error,
    check_window,
    load_chunks,
    select_windows,
)
from rmi_learn.data.checkpoint_rows import file_sha256
from rmi_learn.data.output_lock import output_lock
from rmi_learn.data.runs import atomic_write_bytes, atomic_write_json, json_safe
from rmi_learn.data.schema import CONTROL_DT
from rmi_learn.data.sweep import INDEX_FILE
from rmi_learn.process_pool import ordered_map
from rmi_learn.sim.replay import (
    RunTrack,
    anchor_step,
    check_anchor,
    control_substeps,
    load_index,
    load_track,
)

#: The command name the closed loop locks its output directory under.
LOCK_NAME = "closed-loop"


@dataclass
class Inputs:
    """The checked inputs: the chunk files, the sweep's run files, the chunk length ``h``
    and the windows to execute."""

    chunks: dict[str, dict[str, np.ndarray]]
    index: dict[str, Path]
    h: int
    windows: list[Window]


@dataclass
class Checkpoint:
    """``closed_loop_windows.parquet``: its path, the metadata written with it, and the rows
    stored so far (extended as windows finish)."""

    path: Path
    meta: dict[str, str]
    rows: list[dict[str, Any]]

    def save(self) -> None:
        write_checkpoint(self.path, self.rows, self.meta)


def _check_options(command: str, max_windows: int, threads: int) -> None:
    if command not in COMMAND_MODES:
        raise ClosedLoopError(f"command must be one of {COMMAND_MODES}, got {command!r}")
    if max_windows < 0:
        raise ClosedLoopError("max_windows must be >= 0 (0: all windows)")
    if threads < 1:
        raise ClosedLoopError("threads must be >= 1")


def _load_inputs(sweep: Path, cdir: Path, max_windows: int) -> Inputs:
    """The chunk files and the windows to execute, each window's run a completed run of the
    sweep whose file exists."""
    chunks = load_chunks(cdir)
    with as_closed_loop_error():
        index = load_index(sweep)
    h = next(iter(chunks.values()))["original"].shape[1]
    windows = select_windows(chunks, max_windows)
    unknown = sorted({w.run_id for w in windows} - set(index))
    if unknown:
        raise ClosedLoopError(
            f"{len(unknown)} run(s) of the chunk files are not completed runs in "
            f"{sweep / INDEX_FILE}, e.g. {unknown[0]!r}: give the sweep the dataset was built from"
        )
    for rid in sorted({w.run_id for w in windows}):
        if not index[rid].exists():
            raise ClosedLoopError(f"run file {index[rid]} of {rid} is missing")
    return Inputs(chunks, index, h, windows)


def _fingerprint(chunks_dir: Path, objectives: Iterable[str], command: str) -> str:
    parts = [f"command={command}"]
    parts += [f"{o}={file_sha256(chunks_dir / f'chunks_{o}.npz')}" for o in sorted(objectives)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _open_checkpoint(out: Path, cdir: Path, inputs: Inputs, command: str) -> Checkpoint:
    fingerprint = _fingerprint(cdir, inputs.chunks, command)
    meta = {
        FINGERPRINT_KEY: fingerprint,
        "rmi.version": __version__,
        "rmi.closed_loop.command": command,
    }
    path = out / WINDOWS_FILE
    return Checkpoint(path, meta, read_checkpoint(path, fingerprint))


def _prepare_runs(
    pending: Sequence[Window], inputs: Inputs
) -> tuple[dict[str, list[Window]], dict[str, RunTrack], dict[str, dict[str, Any]]]:
    """The pending windows by run, each run's track and validated config.

    Every input check that needs no simulation runs before the first (long) replay, so a
    bad input stops the command at once rather than hours later."""
    by_run: dict[str, list[Window]] = {}
    for w in pending:
        by_run.setdefault(w.run_id, []).append(w)
    tracks: dict[str, RunTrack] = {}
    configs: dict[str, dict[str, Any]] = {}
    for rid, run_windows in by_run.items():
        with as_closed_loop_error():
            track = load_track(inputs.index[rid])
        for w in run_windows:
            check_window(track, w, inputs.chunks, inputs.h)
        try:
            cfg = rmi_sph.validate_config(track.config)
        except rmi_sph.ConfigError as exc:
            raise ClosedLoopError(
                f"the stored config of run {rid} is refused by this engine: {exc}"
            ) from exc
        with as_closed_loop_error():
            control_substeps(float(cfg["dt"]))
        tracks[rid] = track
        configs[rid] = cfg
    return by_run, tracks, configs


def _execute_run(
    sim: Any,
    track: RunTrack,
    run_windows: Sequence[Window],
    inputs: Inputs,
    command: str,
    keep: Callable[[Window, list[dict[str, Any]]], None],
) -> None:
    """Replay one run through its windows in time order, executing each window's chunks
    from its anchor, and ``keep`` each window's rows. A failed replay fails the rest of the
    run's windows too."""
    h = inputs.h
    with as_closed_loop_error():
        substeps = control_substeps(float(sim.dt))
    autonomous: bytes | None = None
    for w in run_windows:
        t0 = time.perf_counter()
        target = anchor_step(track, w.t, sim.dt)
        error = None
        try:
            if autonomous is not None:
                sim.set_state(autonomous)
            if target < sim.step_count:
                raise ClosedLoopError("windows out of order")  # pragma: no cover
            sim.step(target - sim.step_count)
            state = sim.get_state()
        except rmi_sph.RmiError as exc:
            error = f"{type(exc).__name__}: {exc}"
        replay_wall = time.perf_counter() - t0
        if error is not None:
            new = failed_rows(track, w, h, command, error, replay_wall)
            autonomous = None
        else:
            with as_closed_loop_error():
                check_anchor(sim, track, w.run_id, w.t)
            autonomous = state
            new = window_rows(
                sim, state, track, w, inputs.chunks, h, substeps, command, replay_wall
            )
        keep(w, new)
        if error is not None:
            # The autonomous trajectory of this run is lost: its later windows fail too.
            for rest in run_windows[run_windows.index(w) + 1 :]:
                keep(rest, failed_rows(track, rest, h, command, error, 0.0))
            break


@dataclass(frozen=True)
class _RunJob:
    """One run's windows for a worker process: its track, config and windows, the inputs
    (chunks) and the command mode."""

    track: RunTrack
    config: dict[str, Any]
    windows: list[Window]
    inputs: Inputs
    command: str


def _run_job(job: _RunJob) -> list[dict[str, Any]]:
    """The rows of one run's windows, on one engine thread (in a worker process)."""
    rows: list[dict[str, Any]] = []
    sim = rmi_sph.Trial(job.config, num_threads=1)
    _execute_run(sim, job.track, job.windows, job.inputs, job.command, lambda w, r: rows.extend(r))
    return rows


def _execute(
    pending: Sequence[Window],
    inputs: Inputs,
    command: str,
    threads: int,
    ckpt: Checkpoint,
    progress: bool,
) -> float:
    """Execute every pending window; returns the wall time (s). With ``threads`` > 1 and
    several runs, the runs go to ``threads`` processes of one engine thread each (the rows
    are the same: the engine's results do not depend on its threads), each run's rows
    checkpointed when it ends; else one run at a time on ``threads`` threads, checkpointed
    after every window."""
    by_run, tracks, configs = _prepare_runs(pending, inputs)
    windows = inputs.windows
    bar = tqdm(
        total=len(windows),
        initial=len(windows) - len(pending),
        desc="closed-loop",
        unit="window",
        disable=not progress,
        dynamic_ncols=True,
    )
    t_start = time.perf_counter()

    def keep(w: Window, rows: list[dict[str, Any]]) -> None:
        ckpt.rows.extend(rows)
        ckpt.save()
        bar.set_postfix_str(f"{w.run_id} t={w.t}", refresh=False)
        bar.update(1)

    runs = sorted(by_run)
    ordered = {rid: sorted(by_run[rid], key=lambda w: w.t) for rid in runs}
    try:
        if threads > 1 and len(runs) > 1:
            jobs = [_RunJob(tracks[r], configs[r], ordered[r], inputs, command) for r in runs]
            results = ordered_map(_run_job, jobs, min(threads, len(runs)))
            for job, rows in zip(jobs, results, strict=True):
                ckpt.rows.extend(rows)
                ckpt.save()
                bar.update(len(job.windows))
        else:
            for rid in runs:
                sim = rmi_sph.Trial(configs[rid], num_threads=threads)
                _execute_run(sim, tracks[rid], ordered[rid], inputs, command, keep)
    finally:
        bar.close()
    return time.perf_counter() - t_start


def _payload(
    sweep: Path,
    cdir: Path,
    inputs: Inputs,
    rows: Sequence[Mapping[str, Any]],
    options: Mapping[str, Any],
    n_exec: int,
    wall: float,
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """The summary, the table's settings and the JSON payload of ``table_closed_loop``."""
    summary = summarise(rows, inputs.windows)
    table3 = cdir / "table3_ranking.json"
    try:
        ranked: dict[str, Any] = json.loads(table3.read_text()) if table3.exists() else {}
    except ValueError:
        ranked = {}
    # Rankings written before the scorer was named in them were all W_T's.
    scorer = str(ranked.get("scorer_name", "W_T"))
    info = {
        "sweep": str(sweep),
        "chunks": str(cdir),
        **options,
        "chunk_steps": inputs.h,
        "control_dt_s": CONTROL_DT,
        "objectives": sorted(inputs.chunks),
        "unit": "g",
        "goal": "collected M_L at t + H (kg in data, g in the table)",
        "scorer_name": scorer,
        "note": f"real error executed in the simulator; *_pred_g are {scorer}'s own predictions",
    }
    payload = {
        **info,
        "sizes": summary,
        "windows_total": len(inputs.windows),
        "windows_executed_now": n_exec,
        "wall_s": wall,
        "wall_s_per_window": (wall / n_exec) if n_exec else None,
        "version": __version__,
    }
    if "rows" in ranked:
        # The scorer's predictions over every ranked window (Table III of `rmi rank`), for
        # comparison; the per-window predictions of the executed windows are in `sizes`.
        payload["rank_table3_predicted"] = ranked["rows"]
    return summary, info, payload


def _write_tables(
    out: Path, summary: Mapping[str, Any], info: Mapping[str, Any], payload: Any
) -> None:
    atomic_write_json(out / f"{TABLE_STEM}.json", json_safe(payload))
    md = markdown(summary, info)
    atomic_write_bytes(out / f"{TABLE_STEM}.md", lambda f: f.write(md.encode("utf-8")))


def run_closed_loop(
    sweep_dir: str | os.PathLike[str],
    chunks_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    max_windows: int = 4,
    threads: int = 1,
    command: str = "force",
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Execute the original, first and selected chunks of ``chunks_dir`` (``rmi rank``
    output) in the simulator, starting from deterministic replays of the runs of
    ``sweep_dir`` (a sweep output with ``index.parquet``), and write the closed-loop tables
    to ``out_dir`` (see :mod:`rmi_learn.closed_loop`).

    ``max_windows``: windows per sponge size, evenly spaced (0: every ranked window).
    ``threads``: the engine threads in all (several runs: that many runs at a time, one thread
    each; results do not depend on it). ``command``:
    ``force`` (F_target, engine force regulation), the only mode.
    Windows already in ``out_dir/closed_loop_windows.parquet`` are not executed again.
    Returns the summary written to ``table_closed_loop.json``. Raises
    :class:`ClosedLoopError` for unusable inputs, and
    :class:`~rmi_learn.errors.StageFailure` when another closed-loop writes ``out_dir`` (it
    holds ``OUT/.closed-loop.lock``): each run rewrites the whole checkpoint, so two at once
    would lose one's rows.
    """
    _check_options(command, max_windows, threads)
    say = log or (lambda _msg: None)
    sweep, cdir, out = Path(sweep_dir), Path(chunks_dir), Path(out_dir)
    inputs = _load_inputs(sweep, cdir, max_windows)
    out.mkdir(parents=True, exist_ok=True)
    with output_lock(out, LOCK_NAME):
        ckpt = _open_checkpoint(out, cdir, inputs, command)
        done = {(r["run_id"], r["t"]) for r in ckpt.rows}
        windows = inputs.windows
        pending = [w for w in windows if (w.run_id, w.t) not in done]
        say(
            f"closed-loop: {len(windows)} windows ({len(windows) - len(pending)} already done), "
            f"objectives {sorted(inputs.chunks)}, command {command}"
        )
        wall = _execute(pending, inputs, command, threads, ckpt, progress)
        options = {"command": command, "threads": threads, "max_windows": max_windows}
        summary, info, payload = _payload(
            sweep, cdir, inputs, ckpt.rows, options, len(pending), wall
        )
        _write_tables(out, summary, info, payload)
    say(f"closed-loop: {len(pending)} windows executed in {wall:.1f} s -> {out}")
    return payload


__all__ = ["run_closed_loop"]
