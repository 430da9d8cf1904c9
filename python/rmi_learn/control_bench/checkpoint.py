"""The benchmark's checkpointed rows: ``control_windows.parquet`` (one row per start
state, goal and controller) and ``control_samples.parquet`` (every executed chunk)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn import __version__
from rmi_learn.control_bench.inputs import ControlBenchError
from rmi_learn.data.checkpoint_rows import read_rows, write_rows

WINDOWS_FILE = "control_windows.parquet"
SAMPLES_FILE = "control_samples.parquet"
#: Metadata key of the inputs' fingerprint in both files.
FINGERPRINT_KEY = "rmi.control.fingerprint"
#: Row statuses of a start state that ran no controller.
STATE_STATUSES = ("duplicate", "replay_failed")

#: Columns of ``control_windows.parquet``.
ROW_SCHEMA: dict[str, Any] = {
    "size_cm": pl.Int64,
    "run_id": pl.String,
    "t": pl.Int64,
    "k": pl.Int64,
    "anchor_phase": pl.String,
    "state_hash": pl.String,
    "state_bytes_sha256": pl.String,
    "water_now_kg": pl.Float64,
    "reach_min_kg": pl.Float64,
    "reach_max_kg": pl.Float64,
    "goal_kind": pl.String,
    "goal_index": pl.Int64,
    "goal_kg": pl.Float64,
    "controller": pl.String,
    "objective": pl.String,
    "scorer": pl.String,
    "sample_index": pl.Int64,
    "setpoint_N": pl.Float64,
    "M_L_end_kg": pl.Float64,
    "err_g": pl.Float64,
    "pred_err_g": pl.Float64,
    "peak_force_N": pl.Float64,
    "failure": pl.String,
    "phase_end": pl.String,
    "status": pl.String,
    "error": pl.String,
    "spearman": pl.Float64,
    "recorded_rank": pl.Int64,
    "pred_err_recorded_g": pl.Float64,
    "persistence_err_g": pl.Float64,
    "executions": pl.Int64,
    "wall_s": pl.Float64,
}

#: Columns of ``control_samples.parquet``: every executed chunk with every scorer's forecast.
#: ``objective`` is ``constant`` (the setpoint sweep), ``recorded`` or a policy name;
#: ``pred_M_L_kg`` holds one forecast of the terminal M_L per scorer, in the order of the
#: file's ``rmi.control.scorers`` metadata (and ``table_control.json`` -> ``sample_scorers``).
SAMPLE_SCHEMA: dict[str, Any] = {
    "size_cm": pl.Int64,
    "run_id": pl.String,
    "t": pl.Int64,
    "state_hash": pl.String,
    "goal_kind": pl.String,
    "goal_index": pl.Int64,
    "goal_kg": pl.Float64,
    "objective": pl.String,
    "sample_index": pl.Int64,
    "forces_N": pl.List(pl.Float64),
    "water_now_kg": pl.Float64,
    "M_L_end_kg": pl.Float64,
    "peak_force_N": pl.Float64,
    "status": pl.String,
    "pred_M_L_kg": pl.List(pl.Float64),
}


@dataclass
class Checkpoint:
    """``control_windows.parquet`` (the controllers' rows) and ``control_samples.parquet``
    (every executed chunk), tied to the inputs and options by a fingerprint in the files'
    metadata and rewritten atomically after every start state: the samples first, so that
    the windows file, which decides what is done, never lists a state whose samples are
    missing."""

    path: Path
    fingerprint: str
    samples_path: Path | None = None
    scorers: tuple[str, ...] = ()
    #: Settings stored with the samples (``rmi.control.info``): what re-ranking needs.
    info: Mapping[str, Any] | None = None

    def _read(self, path: Path, schema: Mapping[str, Any]) -> pl.DataFrame:
        advice = "use another --out or delete that file to start over"
        try:
            meta, frame = read_rows(path)
        except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same advice
            raise ControlBenchError(f"{path} is not readable ({exc}); {advice}") from exc
        if meta.get(FINGERPRINT_KEY) != self.fingerprint:
            raise ControlBenchError(f"{path} holds results of other inputs; {advice}")
        if frame.columns != list(schema):
            raise ControlBenchError(f"{path} has other columns than this version; {advice}")
        return frame

    def load(self) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
        """The stored rows and sample rows (none when the files do not exist); refuses files
        of other inputs, options or columns with advice, since resuming them would mix
        results. Samples of a state the windows file does not list (an interruption between
        the two writes) are dropped: that state runs again."""
        if not self.path.exists():
            return [], []
        rows = self._read(self.path, ROW_SCHEMA).to_dicts()
        samples: list[dict[str, Any]] = []
        if self.samples_path is not None and self.samples_path.exists():
            done = {(r["run_id"], r["t"]) for r in rows}
            samples = [
                r
                for r in self._read(self.samples_path, SAMPLE_SCHEMA).to_dicts()
                if (r["run_id"], r["t"]) in done
            ]
        return rows, samples

    def save(
        self, rows: Sequence[Mapping[str, Any]], samples: Sequence[Mapping[str, Any]] = ()
    ) -> None:
        """Write every sample row (when there is a samples file), then every row, atomically."""
        meta = {FINGERPRINT_KEY: self.fingerprint, "rmi.version": __version__}
        if self.samples_path is not None:
            smeta = {
                **meta,
                "rmi.control.scorers": json.dumps(list(self.scorers)),
                "rmi.control.info": json.dumps(dict(self.info or {})),
            }
            write_rows(self.samples_path, samples, SAMPLE_SCHEMA, smeta)
        write_rows(self.path, rows, ROW_SCHEMA, meta)


def full_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """A row with every column of :data:`ROW_SCHEMA` (None where it does not apply)."""
    return {c: row.get(c) for c in ROW_SCHEMA}


__all__ = [
    "FINGERPRINT_KEY",
    "ROW_SCHEMA",
    "SAMPLES_FILE",
    "SAMPLE_SCHEMA",
    "STATE_STATUSES",
    "WINDOWS_FILE",
    "Checkpoint",
    "full_row",
]
