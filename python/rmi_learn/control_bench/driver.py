"""The benchmark driver (``rmi control-bench``): load and check the inputs, replay the
drawn start states, run the controllers of each with a checkpoint after every state, and
write the tables and figures. See :mod:`rmi_learn.control_bench`."""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm  # type: ignore[import-untyped]

from rmi_learn import __version__
from rmi_learn.control_bench import measures
from rmi_learn.control_bench.checkpoint import (
    SAMPLES_FILE,
    STATE_STATUSES,
    WINDOWS_FILE,
    Checkpoint,
)
from rmi_learn.control_bench.controllers import (
    ENSEMBLE,
    FAMILIES,
    SETPOINT_LOW_FRACTION,
)
from rmi_learn.control_bench.inputs import (
    ACTING_PHASES,
    OBJECTIVES,
    Candidate,
    ControlBenchError,
    Setup,
    load_policies,
    load_scorers,
)
from rmi_learn.control_bench.states import StateRunner, replayable_runs, start_pool
from rmi_learn.data.checkpoint_rows import file_sha256
from rmi_learn.data.dataset import load_dataset
from rmi_learn.data.output_lock import output_lock
from rmi_learn.data.runs import atomic_write_bytes, atomic_write_json, json_safe
from rmi_learn.data.schema import CONTROL_DT, FORCE_LIMIT_N
from rmi_learn.planning.refine import METRICS
from rmi_learn.sim.replay import (
    load_index,
)

#: The command name the benchmark locks its output directory under.
LOCK_NAME = "control-bench"
TABLE_STEM = "table_control"
FIGURE_FILE = "fig_control.png"
SCORERS_FIGURE_FILE = "fig_control_scorers.png"


def _check_counts(
    states_per_size: int,
    goals_per_state: int,
    setpoints: int,
    k: int,
    receding: int,
    threads: int,
) -> None:
    for name, v, low in (
        ("states_per_size", states_per_size, 1),
        ("goals_per_state", goals_per_state, 0),
        ("setpoints", setpoints, 2),
        ("k", k, 1),
        ("receding", receding, 0),
        ("threads", threads, 1),
    ):
        if v < low:
            raise ControlBenchError(f"{name} must be >= {low}, got {v}")


def _load_inputs(
    runs_p: Path,
    data_p: Path,
    wm_p: Path,
    pol_p: Path,
    receding: int,
    scorers: Sequence[str] | None,
) -> Setup:
    try:
        ds = load_dataset(data_p)
    except (OSError, ValueError) as exc:
        raise ControlBenchError(f"--data {data_p}: {exc}") from exc
    index = load_index(runs_p)
    pols = load_policies(pol_p, ds)
    first_pol = next(iter(pols.values()))
    hist_len, h = first_pol.history, first_pol.horizon
    if receding > h:
        raise ControlBenchError(f"receding must be at most the chunk length {h}, got {receding}")
    scs, skipped = load_scorers(wm_p, ds, h, scorers)
    return Setup(ds, index, pols, hist_len, h, scs, skipped)


def _resolve_scorers(
    rank_names: Sequence[str], receding_scorers: Sequence[str], refine_scorers: Sequence[str]
) -> tuple[list[str], list[str]]:
    """The re-planning and refining scorers, checked; by default the first scorer re-plans
    and the re-planning scorers refine."""
    for flag, names in (("--receding-scorers", receding_scorers),
                        ("--refine-scorers", refine_scorers)):  # fmt: skip
        bad = [n for n in names if n not in rank_names]
        if bad:
            raise ControlBenchError(f"{flag} {bad}: not among the scorers {list(rank_names)}")
    receding = list(receding_scorers) or [rank_names[0]]
    return receding, list(refine_scorers) or receding


def _check_refine_metrics(refine_metrics: Sequence[str]) -> None:
    bad = [m for m in refine_metrics if m not in METRICS] or (
        ["(none)"] if not refine_metrics else []
    )
    if bad or len(set(refine_metrics)) != len(refine_metrics):
        raise ControlBenchError(
            f"--refine-metrics {list(refine_metrics)}: give distinct metrics of {list(METRICS)}"
        )


def _families(controllers: Sequence[str] | None) -> list[str]:
    families = list(FAMILIES) if controllers is None else list(controllers)
    bad = [f for f in families if f not in FAMILIES]
    if bad or not families:
        raise ControlBenchError(f"--controllers {bad or '(none)'}: choose among {list(FAMILIES)}")
    return families


def _options(
    k: int,
    goals_per_state: int,
    setpoints: int,
    receding: int,
    goal_kg: Sequence[float],
    split_used: str,
    seed: int,
    s: Setup,
    ensemble: bool,
    receding_scorers: Sequence[str],
    refine_scorers: Sequence[str],
    refine_metrics: Sequence[str],
    families: Sequence[str],
) -> dict[str, Any]:
    """The options that decide the results (part of the checkpoint's fingerprint)."""
    return {
        "k": k,
        "goals_per_state": goals_per_state,
        "setpoints": setpoints,
        "receding": receding,
        "goal_kg": [float(g) for g in goal_kg],
        "split": split_used,
        "seed": seed,
        "scorers": sorted(s.scorers),
        "ensemble": bool(ensemble and len(s.scorers) >= 2),
        "receding_scorers": receding_scorers,
        "refine_scorers": refine_scorers,
        "refine_metrics": list(refine_metrics),
        "controllers": [f for f in FAMILIES if f in families],
        "horizon": s.h,
        "history": s.hist_len,
    }


def _fingerprint(options: Mapping[str, Any], data_p: Path, pol_p: Path, s: Setup) -> str:
    """The options and the hashes of the dataset's, policies' and scorers' files."""
    digest = hashlib.sha256(json.dumps(options, sort_keys=True).encode())
    for p in (
        [data_p / "stats.json", data_p / "runs.parquet"]
        + [d for pol in sorted(s.policies) for d in (pol_p / pol / "model.ema.safetensors",)]
        + [sc.path / "model.safetensors" for sc in s.scorers.values()]
    ):
        if p.exists():
            digest.update(f"{p.name}={file_sha256(p)}".encode())
    return digest.hexdigest()


def _states_info(
    s: Setup,
    cands: Mapping[int, Sequence[Candidate]],
    rows: Sequence[Mapping[str, Any]],
    split_used: str,
) -> dict[str, Any]:
    """Per size: candidates, replayed, distinct, failed and duplicate states."""
    states_info = {}
    ds, hist_len, h = s.ds, s.hist_len, s.h
    for size, cs in cands.items():
        srows = [r for r in rows if r["size_cm"] == size]
        anchors = ds.windows(split_used, size, hist_len, h).anchors
        # Windows whose recorded rows (history, anchor and future) are identical.
        recorded_keys = {
            hashlib.sha256(
                ds.y_std[anchors[c.window] - hist_len + 1 : anchors[c.window] + h + 1].tobytes()
            ).hexdigest()
            for c in cs
        }
        states_info[str(size)] = {
            "candidate_windows": len(cs),
            "candidate_windows_distinct_recorded_rows": len(recorded_keys),
            "replayed": len({(r["run_id"], r["t"]) for r in srows}),
            "distinct_states": len(
                {r["state_hash"] for r in srows if r["status"] not in STATE_STATUSES}
            ),
            "replay_failed": len(
                {(r["run_id"], r["t"]) for r in srows if r["status"] == "replay_failed"}
            ),
            "duplicates": len({(r["run_id"], r["t"]) for r in srows if r["status"] == "duplicate"}),
            "distinct_raw_state_bytes": len(
                {r["state_bytes_sha256"] for r in srows if r["state_bytes_sha256"]}
            ),
        }
    return states_info


def _info(
    where: Mapping[str, str],
    split: str,
    split_used: str,
    states_per_size: int,
    options: Mapping[str, Any],
    threads: int,
    setpoints: int,
    s: Setup,
    rank_names: Sequence[str],
    objectives: Sequence[str],
) -> dict[str, Any]:
    """The settings of the tables (``table_control.json`` and the Markdown table)."""
    return {
        **where,
        "split": split,
        "split_used": split_used,
        "phases": list(ACTING_PHASES),
        "states_per_size": states_per_size,
        **options,
        "threads": threads,
        "control_dt_s": CONTROL_DT,
        "force_limit_N": FORCE_LIMIT_N,
        "setpoint_low_fraction": SETPOINT_LOW_FRACTION,
        "setpoint_fractions": [float(x) for x in np.linspace(0.0, 1.0, setpoints)],
        "scorers_skipped": s.skipped,
        "sample_scorers": rank_names,
        "default_scorer": next(iter(s.scorers)),
        "objectives": objectives,
        "unit": "g",
        "tie_g": measures.TIE_G,
    }


def _run_sizes(
    states: StateRunner,
    cands: Mapping[int, Sequence[Candidate]],
    states_per_size: int,
    seed: int,
    progress: bool,
) -> float:
    """Run the start states of every size (see :meth:`StateRunner.run_size`); returns the wall
    time (s)."""
    t_start = time.perf_counter()
    bar = tqdm(desc="control-bench", unit="state", disable=not progress, dynamic_ncols=True)
    try:
        for size, cs in cands.items():
            states.run_size(size, cs, states_per_size, seed, bar)
    finally:
        bar.close()
    return time.perf_counter() - t_start


def _objectives(s: Setup) -> list[str]:
    """The policies in table order: the two objectives first, then any other by name."""
    return [o for o in OBJECTIVES if o in s.policies] + sorted(set(s.policies) - set(OBJECTIVES))


def _payload(
    s: Setup,
    cands: Mapping[int, Sequence[Candidate]],
    states: StateRunner,
    info: Mapping[str, Any],
    wall: float,
    seed: int,
    rank_names: Sequence[str],
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """The summary, the scorers' diagnostics and the payload of ``table_control.json``."""
    summary = measures.summarise(states.rows, list(info["objectives"]), seed)
    diag = measures.scorer_diagnostics(states.sample_rows, rank_names)
    payload = {
        **info,
        "states": _states_info(s, cands, states.rows, str(info["split_used"])),
        "summary": summary,
        "scorer_diagnostics": diag,
        "states_run_now": states.n_new,
        "wall_s": wall,
        "wall_s_per_state": wall / states.n_new if states.n_new else None,
        "version": __version__,
    }
    return summary, diag, payload


def _write_outputs(
    out_p: Path,
    payload: Any,
    summary: Mapping[str, Any],
    info: Mapping[str, Any],
    diag: Mapping[str, Any],
    states: StateRunner,
    rank_names: Sequence[str],
) -> None:
    atomic_write_json(out_p / f"{TABLE_STEM}.json", json_safe(payload))
    md = measures.markdown(summary, info, diag)
    atomic_write_bytes(out_p / f"{TABLE_STEM}.md", lambda f: f.write(md.encode("utf-8")))
    tmp = out_p / f".{FIGURE_FILE}.tmp.png"
    measures.figure(states.rows, tmp)
    os.replace(tmp, out_p / FIGURE_FILE)
    tmp = out_p / f".{SCORERS_FIGURE_FILE}.tmp.png"
    measures.figure_scorers(states.sample_rows, list(rank_names), tmp)
    os.replace(tmp, out_p / SCORERS_FIGURE_FILE)


def run_control_bench(
    runs: str | os.PathLike[str],
    data: str | os.PathLike[str],
    wm: str | os.PathLike[str],
    policy: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    states_per_size: int = 4,
    goals_per_state: int = 2,
    setpoints: int = 5,
    k: int = 8,
    receding: int = 8,
    scorers: Sequence[str] | None = None,
    ensemble: bool = True,
    receding_scorers: Sequence[str] = (),
    refine_scorers: Sequence[str] = (),
    refine_metrics: Sequence[str] = ("smooth",),
    controllers: Sequence[str] | None = None,
    sizes: Sequence[int] | None = None,
    goal_kg: Sequence[float] = (),
    split: str = "test",
    seed: int = 0,
    threads: int = 1,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the goal-reaching benchmark (see :mod:`rmi_learn.control_bench`) and write
    ``control_windows.parquet``, ``control_samples.parquet``, ``table_control.{md,json}``,
    ``fig_control.png`` and ``fig_control_scorers.png`` to ``out``. ``runs``: the sweep
    output (``index.parquet``) the dataset ``data`` was built from; ``wm``: a directory of
    world-model runs (``rmi train-wm`` outputs) or one run;
    ``policy``: a directory holding ``diffusion/`` and/or ``flow/`` policy runs.
    ``receding``: re-planning period of the receding-horizon controller in control steps
    (0: none). ``scorers``: world models to rank with (default every one that can);
    ``ensemble``: with two or more, also rank by their ensemble (``ranked-ensemble``: mean
    forecast, members' spread as a penalty). ``receding_scorers``: the scorers of the
    receding-horizon controller (default the first scorer, W_T when present; others are
    named ``receding-<n>-<scorer>``). ``refine_scorers``: the scorers whose gradient
    refines the ranked chunk (``refined-<scorer>/<policy>``, one per metric of
    ``refine_metrics``, see :mod:`rmi_learn.planning.refine`), the re-planned chunks
    (``receding-<n>-refined-<scorer>/<policy>``) and a held setpoint without a policy
    (``model-<scorer>``, ``receding-<n>-model-<scorer>``); default the receding scorers.
    ``controllers``: the families of :data:`~rmi_learn.control_bench.controllers.FAMILIES`
    to run (default all). ``sizes``: the sponge sizes (cm) to draw start states from
    (default every size of the split; each size's states are drawn independently, so a run
    can be extended to other sizes).
    ``goal_kg``: extra goals (kg) for every state. States already in the checkpoint are not
    run again; a larger ``states_per_size`` extends it. Returns the summary written to
    ``table_control.json``. Raises :class:`ControlBenchError` for unusable inputs, before
    anything is written, and :class:`~rmi_learn.errors.StageFailure` when another
    control-bench writes ``out`` (it holds ``OUT/.control-bench.lock``): each run rewrites
    the whole checkpoint, so two at once would lose one's rows."""
    say = log or (lambda _m: None)
    _check_counts(states_per_size, goals_per_state, setpoints, k, receding, threads)
    runs_p, data_p, wm_p, pol_p, out_p = map(Path, (runs, data, wm, policy, out))
    s = _load_inputs(runs_p, data_p, wm_p, pol_p, receding, scorers)
    rank_names = list(s.scorers) + ([ENSEMBLE] if ensemble and len(s.scorers) >= 2 else [])
    receding_scorers, refine_scorers = _resolve_scorers(
        rank_names, receding_scorers, refine_scorers
    )
    _check_refine_metrics(refine_metrics)
    families = _families(controllers)
    split_used, cands = start_pool(s, split, sizes, say)
    tracks, configs = replayable_runs(s, cands, runs_p, goal_kg)
    options = _options(
        k, goals_per_state, setpoints, receding, goal_kg, split_used, seed, s, ensemble,
        receding_scorers, refine_scorers, refine_metrics, families,
    )  # fmt: skip
    out_p.mkdir(parents=True, exist_ok=True)
    ckpt = Checkpoint(
        out_p / WINDOWS_FILE, _fingerprint(options, data_p, pol_p, s), out_p / SAMPLES_FILE,
        tuple(rank_names),
        {"data": str(data_p), "wm": str(wm_p), "policy": str(pol_p), "split_used": split_used,
         **options},
    )  # fmt: skip
    bench_options = {
        "k": k, "horizon": s.h, "n_setpoints": setpoints, "goals_per_state": goals_per_state,
        "given_goals": goal_kg, "receding": receding, "seed": seed, "ensemble": ensemble,
        "receding_scorers": receding_scorers, "refine_scorers": refine_scorers,
        "refine_metrics": refine_metrics, "controllers": families,
    }  # fmt: skip
    with output_lock(out_p, LOCK_NAME):
        states = StateRunner(s, ckpt, tracks, configs, split_used, threads, bench_options)
        say(
            f"control-bench: {sum(len(c) for c in cands.values())} candidate windows in "
            f"{len(cands)} size(s), scorers {sorted(s.scorers)}, policies {sorted(s.policies)}"
        )
        wall = _run_sizes(states, cands, states_per_size, seed, progress)
        where = {"runs": str(runs_p), "data": str(data_p), "wm": str(wm_p), "policy": str(pol_p)}
        info = _info(where, split, split_used, states_per_size, options, threads, setpoints, s,
                     rank_names, _objectives(s))  # fmt: skip
        summary, diag, payload = _payload(s, cands, states, info, wall, seed, rank_names)
        _write_outputs(out_p, payload, summary, info, diag, states, rank_names)
    say(f"control-bench: {states.n_new} start states run in {wall:.1f} s -> {out_p}")
    return payload


__all__ = ["FIGURE_FILE", "SCORERS_FIGURE_FILE", "TABLE_STEM", "run_control_bench"]
