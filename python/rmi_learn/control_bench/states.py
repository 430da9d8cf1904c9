"""The benchmark's start states: the pool they are drawn from (:func:`start_pool`), the
runs they are replayed from (:func:`replayable_runs`), and the replay and run of each
state with a checkpoint after every state (:class:`StateRunner`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

import rmi_sph
from rmi_learn.control_bench.checkpoint import (
    STATE_STATUSES,
    Checkpoint,
    full_row,
)
from rmi_learn.control_bench.controllers import (
    Bench,
    StartState,
)
from rmi_learn.control_bench.inputs import (
    ACTING_PHASES,
    Candidate,
    ControlBenchError,
    Setup,
    candidates,
    check_candidates,
    check_goals,
    draw_order,
    total_water,
    validated_configs,
)
from rmi_learn.sim.fingerprint import state_bytes_hash, state_fingerprint
from rmi_learn.sim.replay import (
    RunTrack,
    anchor_step,
    check_anchor,
    control_substeps,
    load_track,
)


def start_pool(
    s: Setup, split: str, sizes: Sequence[int] | None, say: Callable[[str], None]
) -> tuple[str, dict[int, list[Candidate]]]:
    """The split the start states come from (val when ``split`` is empty) and its
    candidates per size, restricted to ``sizes``."""
    split_used = split
    if not len(s.ds.split_runs(split)):
        split_used = "val"
        say(f"control-bench: the {split} split is empty; start states from the val split")
    cands = candidates(s.ds, split_used, s.hist_len, s.h)
    if sizes is not None:
        missing = sorted(set(sizes) - set(cands))
        if missing or not sizes:
            raise ControlBenchError(
                f"--sizes {list(sizes)}: the {split_used} split has start states for sizes "
                f"{sorted(cands)} cm only"
            )
        cands = {size: cs for size, cs in cands.items() if size in sizes}
    if not cands:
        raise ControlBenchError(
            f"no window of the {split_used} split has its anchor in {ACTING_PHASES}"
        )
    return split_used, cands


def replayable_runs(
    s: Setup, cands: Mapping[int, Sequence[Candidate]], runs_p: Path, goal_kg: Sequence[float]
) -> tuple[dict[str, RunTrack], dict[str, dict[str, Any]]]:
    """The tracks and validated configs of the candidates' runs, each checked against the
    dataset, and the given goals checked against the water the runs hold."""
    pool_runs = sorted({c.run_id for cs in cands.values() for c in cs})
    unknown = [r for r in pool_runs if r not in s.index]
    if unknown:
        raise ControlBenchError(
            f"run {unknown[0]!r} of --data is not a completed run of --runs {runs_p}: give the "
            "sweep the dataset was built from"
        )
    tracks = {rid: load_track(s.index[rid]) for rid in pool_runs}
    check_candidates(s.ds, cands, tracks, s.h, runs_p)
    check_goals(list(goal_kg), total_water(pool_runs, tracks, s.index))
    return tracks, validated_configs(pool_runs, tracks)


class StateRunner:
    """The start states of the benchmark as they are replayed and run: the rows and sample
    rows (stored and new), the states done and the distinct states seen, checkpointed after
    every state."""

    def __init__(
        self,
        s: Setup,
        ckpt: Checkpoint,
        tracks: Mapping[str, RunTrack],
        configs: Mapping[str, dict[str, Any]],
        split_used: str,
        threads: int,
        bench_options: Mapping[str, Any],
    ) -> None:
        self.s, self.ckpt, self.tracks, self.configs = s, ckpt, tracks, configs
        self.split_used, self.threads, self.bench_options = split_used, threads, bench_options
        self.rows, self.sample_rows = ckpt.load()
        self.done = {(r["run_id"], r["t"]) for r in self.rows}
        self.seen = {
            r["state_hash"]: (r["run_id"], r["t"])
            for r in self.rows
            if r["status"] not in STATE_STATUSES
        }
        self.n_new = 0

    def run_size(
        self, size: int, cs: Sequence[Candidate], states_per_size: int, seed: int, bar: Any
    ) -> None:
        """Draw and run candidates of one size until it has ``states_per_size`` distinct
        states (or none is left)."""
        order = draw_order(cs, seed, size)
        pos = 0
        while pos < len(order):
            distinct = len(
                {r["state_hash"] for r in self.rows
                 if r["size_cm"] == size and r["status"] not in STATE_STATUSES}
            )  # fmt: skip
            need = states_per_size - distinct
            if need <= 0:
                break
            batch: list[Candidate] = []
            while pos < len(order) and len(batch) < need:
                if (order[pos].run_id, order[pos].t) not in self.done:
                    batch.append(order[pos])
                pos += 1
            ws = self.s.ds.windows(self.split_used, size, history=self.s.hist_len, horizon=self.s.h)
            for rid in sorted({c.run_id for c in batch}):
                self._run_run(size, rid, [c for c in batch if c.run_id == rid], ws, bar)

    def _run_run(self, size: int, rid: str, batch: Sequence[Candidate], ws: Any, bar: Any) -> None:
        """Replay run ``rid`` through its candidates in time order and run each new state."""
        tr = self.tracks[rid]
        sim = rmi_sph.Trial(self.configs[rid], num_threads=self.threads)
        substeps = control_substeps(float(sim.dt))
        bench = Bench(sim, substeps, self.s.ds, self.s.policies, self.s.scorers,
                      **self.bench_options)  # fmt: skip
        auto: bytes | None = None
        for c in sorted(batch, key=lambda c: c.t):
            target = anchor_step(tr, c.t, sim.dt)
            try:
                if auto is not None:
                    sim.set_state(auto)
                elif sim.step_count > 0:
                    sim = rmi_sph.Trial(self.configs[rid], num_threads=self.threads)
                    bench.sim = sim
                sim.step(target - sim.step_count)
            except rmi_sph.RmiError as exc:
                # Deterministic: the same replay fails again, so it is recorded.
                auto = None
                self.rows.append(full_row({
                    "size_cm": size, "run_id": rid, "t": c.t,
                    "k": int(tr.k[c.t]), "anchor_phase": c.phase,
                    "status": "replay_failed", "error": f"{type(exc).__name__}: {exc}",
                }))  # fmt: skip
                self.done.add((rid, c.t))
                self.ckpt.save(self.rows, self.sample_rows)
                continue
            check_anchor(sim, tr, rid, c.t)
            state = sim.get_state()
            auto = state
            self._run_state(bench, sim, size, c, tr, state, ws, bar)
            self.done.add((rid, c.t))
            self.ckpt.save(self.rows, self.sample_rows)
            bar.set_postfix_str(f"{size} cm {rid} t={c.t}", refresh=False)

    def _run_state(
        self,
        bench: Bench,
        sim: Any,
        size: int,
        c: Candidate,
        tr: RunTrack,
        state: bytes,
        ws: Any,
        bar: Any,
    ) -> None:
        """Run every controller from a replayed state, or record it as a duplicate of a
        state already run."""
        fp = state_fingerprint(sim)
        if fp in self.seen:
            self.rows.append(full_row({
                "size_cm": size, "run_id": c.run_id, "t": c.t,
                "k": int(tr.k[c.t]), "anchor_phase": c.phase,
                "state_hash": fp, "state_bytes_sha256": state_bytes_hash(state),
                "status": "duplicate",
                "error": f"same state as run {self.seen[fp][0]}, t={self.seen[fp][1]}",
            }))  # fmt: skip
            return
        b = ws.batch([c.window])
        start = StartState(
            c, tr, state, fp, state_bytes_hash(state), b["hist"], b["hist_mask"], b["water_now"]
        )
        with torch.no_grad():
            self.rows.extend(full_row(r) for r in bench.state_rows(start))
        self.sample_rows.extend(bench.samples)
        self.seen[fp] = (c.run_id, c.t)
        self.n_new += 1
        bar.update(1)
