"""Run files: one Parquet file per simulated trial, written atomically with polars.

A run file has one row per record (every 5 ms by default) and the columns of
:data:`RUN_COLUMNS`: every name in ``schema.EXTRAS`` (``time`` f64 in s, ``phase`` str,
``gate_open`` bool, the others f64), every name in ``schema.OBS`` (f64, SI units; ``c`` and
``r_*`` are 0/1; ``v_res`` is NaN without contact, every other channel has physical zeros)
and ``schema.ACTIONS`` (f64). Parquet file-level key-value metadata holds
``rmi.config`` (trial config JSON), ``rmi.params`` (JSON: ``size_cm``, ``porosity``,
``F_hold`` N, ``F_squeeze`` N, ``seed``), ``rmi.outcome`` (JSON: ``lift_success``,
``stable_squeeze``, ``failure``, ``water_removed`` {phase: kg}, ``initial_water`` kg,
``final_water`` kg, ``wall_s`` s, plus any extra scalars the engine reports), ``rmi.version``
and ``rmi.git``. polars (>= 1.x) writes this metadata itself (``write_parquet(metadata=)``)
and reads it back without the data (``read_parquet_metadata``), so no pyarrow and no sidecar
file is needed.

Layout of a grid (:func:`run_path`): hive-style directories, one per parameter,
``size_cm=10/porosity=0.6/F_hold=110/F_squeeze=200/seed=0/run.parquet``, so that
``pl.scan_parquet(root / "**/*.parquet", hive_partitioning=True)`` (or :func:`scan_runs`,
which pins the partition types) yields the parameters as columns. A run that raised is
recorded as ``error.json`` in the same directory (:func:`write_error`).

Writes are atomic: data go to a hidden temporary name in the destination directory
(``.run.parquet.<random>.tmp``, never matched by ``*.parquet``), are flushed and fsynced,
then renamed over the destination with :func:`os.replace`; the directory is fsynced too. A
reader therefore sees either no file or a complete one, even after ``kill -9``.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import subprocess
import tempfile
from collections.abc import Iterator, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn import __version__
from rmi_learn.data.schema import ACTIONS, EXTRAS, OBS, SEED_MAX, SEED_RANGE
from rmi_learn.errors import RunFileError
from rmi_learn.user_files import read_user_text

#: Every column of a run file, in file order.
RUN_COLUMNS: tuple[str, ...] = EXTRAS + OBS + ACTIONS
#: The only channel allowed to hold NaN (undefined without contact).
NAN_ALLOWED: frozenset[str] = frozenset({"v_res"})
#: Columns that are not f64.
_STRING_COLUMNS = frozenset({"phase"})
_BOOL_COLUMNS = frozenset({"gate_open"})

#: Parameters that name a run, in partition order, with their polars types.
PARAM_KEYS: tuple[str, ...] = ("size_cm", "porosity", "F_hold", "F_squeeze", "seed")
PARAM_SCHEMA: dict[str, pl.DataType] = {
    "size_cm": pl.Int64(),
    "porosity": pl.Float64(),
    "F_hold": pl.Float64(),
    "F_squeeze": pl.Float64(),
    "seed": pl.Int64(),
}
RUN_FILE = "run.parquet"
ERROR_FILE = "error.json"
TMP_SUFFIX = ".tmp"

META_KEYS = {
    "config": "rmi.config",
    "params": "rmi.params",
    "outcome": "rmi.outcome",
    "version": "rmi.version",
    "git": "rmi.git",
}


# --------------------------------------------------------------------------------------
# Atomic writes


def fsync_dir(directory: Path) -> None:
    """Make the renames into ``directory`` durable, where the platform has directory handles."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # platforms without directory handles
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# Read once at import: os.umask can only be read by setting it, which is not thread-safe.
_UMASK = _current_umask()


def atomic_write_bytes(path: str | os.PathLike[str], writer: Any) -> Path:
    """Write ``path`` atomically: ``writer(fileobj)`` fills a temporary file in the same
    directory, which is fsynced and renamed over ``path``. Returns ``path``.

    The temporary file is ``.<name>.<random>.tmp`` and is removed if ``writer`` raises.
    """
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=TMP_SUFFIX, dir=dest.parent)
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as f:
            writer(f)
            f.flush()
            # mkstemp creates 0600; give the file the permissions a plain open() would.
            if hasattr(os, "fchmod"):
                os.fchmod(f.fileno(), 0o666 & ~_UMASK)
            os.fsync(f.fileno())
        os.replace(tmp, dest)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
            # A failed write (a full disk) names no file; the user needs to know which.
            raise OSError(exc.errno, exc.strerror, str(dest)) from exc
        raise
    fsync_dir(dest.parent)
    return dest


def json_safe(obj: Any) -> Any:
    """A JSON-ready copy of ``obj``: NaN and inf become ``None`` (tables and summaries never
    hold NaN), numpy scalars and arrays become Python numbers and lists, tuples lists."""
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [json_safe(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def read_json_source(
    package: str, presets: tuple[str, ...], preset: str | None, path: Any, kind: str
) -> tuple[Any, str]:
    """Parse a built-in preset (``<package>/<preset>.json``) or a JSON file: exactly one of
    ``preset`` and ``path``. Returns the parsed value and a label naming its source for error
    messages; ``kind`` names what is read (e.g. "grid") in those messages. A file is read
    within the limits of :func:`~rmi_learn.user_files.read_user_text`."""
    if (preset is None) == (path is None):
        raise ValueError("give exactly one of preset or path")
    if preset is not None:
        if preset not in presets:
            raise ValueError(f"unknown {kind} preset {preset!r}; choose one of {presets}")
        text = resources.files(package).joinpath(f"{preset}.json").read_text()
        source = f"{kind} preset {preset}"
    else:
        source = str(path)
        try:
            text = read_user_text(path, f"{kind} file")
        except UnicodeDecodeError as exc:
            where = f"{exc.reason} at byte {exc.start}"
            raise ValueError(f"{source}: not UTF-8 text ({where})") from None
    try:
        return json.loads(text), source
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source}: not valid JSON: {exc}") from exc
    except RecursionError:
        raise ValueError(f"{source}: JSON nested too deeply to be a {kind}") from None


def json_kind(value: Any) -> str:
    """The JSON name of a parsed value's type (object, array, string, number, boolean, null),
    for messages about a file that holds the wrong kind."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    kinds = ((Mapping, "object"), (list, "array"), (str, "string"), ((int, float), "number"))
    return next((name for t, name in kinds if isinstance(value, t)), type(value).__name__)


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` as indented JSON to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    data = (json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n").encode()
    return atomic_write_bytes(path, lambda f: f.write(data))


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _dumps(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, default=_json_default, allow_nan=True)


# --------------------------------------------------------------------------------------
# Provenance


@functools.lru_cache(maxsize=1)
def git_revision() -> str:
    """The git revision of the source tree this package runs from (``<sha>`` or
    ``<sha>-dirty``), ``$RMI_GIT_REV`` if set, or ``"unknown"`` outside a checkout."""
    env = os.environ.get("RMI_GIT_REV")
    if env:
        return env
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10
        )
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "diff-index", "--quiet", "HEAD", "--"], cwd=here, timeout=20
        ).returncode
        return sha.stdout.strip() + ("-dirty" if dirty == 1 else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


# --------------------------------------------------------------------------------------
# Paths


def format_value(x: float | int) -> str:
    """Shortest text of a parameter value for a path: ``110.0 -> "110"``, ``0.6 -> "0.6"``."""
    if isinstance(x, (bool, np.bool_)):
        raise TypeError("parameters are numbers, not booleans")
    if isinstance(x, (int, np.integer)):
        # Exactly: through a float, seeds above 2^53 would round into another run's name.
        return str(int(x))
    xf = float(x)
    if xf.is_integer():
        return str(int(xf))
    return repr(xf)


def run_relpath(params: Mapping[str, Any]) -> Path:
    """Hive-style relative directory of a run, e.g.
    ``size_cm=10/porosity=0.6/F_hold=110/F_squeeze=200/seed=0``."""
    missing = [k for k in PARAM_KEYS if k not in params]
    if missing:
        raise RunFileError(f"params lack {missing} (need {list(PARAM_KEYS)})")
    return Path(*(f"{k}={format_value(params[k])}" for k in PARAM_KEYS))


def run_path(root: str | os.PathLike[str], params: Mapping[str, Any]) -> Path:
    """Path of the run file of ``params`` under ``root`` (see :func:`run_relpath`)."""
    return Path(root) / run_relpath(params) / RUN_FILE


def run_id(params: Mapping[str, Any]) -> str:
    """Stable text name of a run: its relative directory with ``/`` separators."""
    return run_relpath(params).as_posix()


def iter_run_files(root: str | os.PathLike[str]) -> Iterator[Path]:
    """Every complete run file under ``root`` (recursively, sorted; temporaries ignored)."""
    yield from sorted(Path(root).rglob(RUN_FILE))


# --------------------------------------------------------------------------------------
# Write and read


def _validate_columns(columns: Mapping[str, Any]) -> dict[str, np.ndarray]:
    missing = [c for c in RUN_COLUMNS if c not in columns]
    extra = [c for c in columns if c not in RUN_COLUMNS]
    if missing or extra:
        raise RunFileError(
            f"run columns differ from the contract: missing {missing}, unknown {extra}"
        )
    out: dict[str, np.ndarray] = {}
    n: int | None = None
    for name in RUN_COLUMNS:
        raw = columns[name]
        if name in _STRING_COLUMNS:
            arr = np.asarray(raw, dtype=object).astype(str)
        elif name in _BOOL_COLUMNS:
            arr = np.asarray(raw)
            if arr.dtype != np.bool_:
                if not np.all(np.isin(arr, (0, 1))):
                    raise RunFileError(f"channel {name!r} must be boolean (0/1)")
                arr = arr.astype(bool)
        else:
            try:
                arr = np.asarray(raw, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise RunFileError(f"channel {name!r} is not numeric: {exc}") from exc
            if name not in NAN_ALLOWED:
                bad = ~np.isfinite(arr)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise RunFileError(
                        f"channel {name!r} has {int(bad.sum())} non-finite value(s) "
                        f"(first at row {i}: {arr[i]}); only {sorted(NAN_ALLOWED)} may be NaN"
                    )
            elif np.isinf(arr).any():
                raise RunFileError(f"channel {name!r} has infinite values (NaN is allowed)")
        if arr.ndim != 1:
            raise RunFileError(f"channel {name!r} must be one-dimensional, got shape {arr.shape}")
        if n is None:
            n = arr.shape[0]
        elif arr.shape[0] != n:
            raise RunFileError(f"channel {name!r} has {arr.shape[0]} rows, expected {n}")
        out[name] = arr
    if n == 0:
        raise RunFileError("a run file needs at least one row")
    t = out["time"]
    if np.any(np.diff(t) <= 0):
        raise RunFileError("channel 'time' must be strictly increasing")
    return out


def _validate_params(params: Mapping[str, Any]) -> dict[str, Any]:
    run_relpath(params)  # checks presence
    out = dict(params)
    for k in PARAM_KEYS:
        v = params[k]
        if k in ("size_cm", "seed"):
            # An int is compared as itself: as a float, one above 2^53 would not equal itself.
            if not isinstance(v, (int, np.integer)) and float(v) != int(v):
                raise RunFileError(f"param {k!r} must be an integer, got {v!r}")
            out[k] = int(v)
        else:
            if not math.isfinite(float(v)):
                raise RunFileError(f"param {k!r} must be finite, got {v!r}")
            out[k] = float(v)
    if not 0 <= out["seed"] <= SEED_MAX:
        raise RunFileError(f"param 'seed' must be {SEED_RANGE}, got {out['seed']}")
    return out


def write_run(
    path: str | os.PathLike[str],
    columns: Mapping[str, Any],
    config: Mapping[str, Any],
    params: Mapping[str, Any],
    outcome: Mapping[str, Any],
) -> Path:
    """Write one run file atomically and return its path.

    ``columns`` maps every name of :data:`RUN_COLUMNS` to a 1-D array of equal length (SI
    units; ``time`` in s, strictly increasing). Raises :class:`RunFileError` naming the
    channel if a column is missing or unknown, or if any channel other than ``v_res`` holds
    NaN or inf. ``config``, ``params`` and ``outcome`` are stored as JSON in the file
    metadata together with the package version and git revision.
    """
    data = run_file_bytes(columns, config, params, outcome)
    return atomic_write_bytes(path, lambda f: f.write(data))


def run_file_bytes(
    columns: Mapping[str, Any],
    config: Mapping[str, Any],
    params: Mapping[str, Any],
    outcome: Mapping[str, Any],
) -> bytes:
    """The bytes of the run file :func:`write_run` writes (checked the same way), for a
    process that computes a run on one machine and stores it on another."""
    cols = _validate_columns(columns)
    p = _validate_params(params)
    df = pl.DataFrame({n: pl.Series(n, arr, dtype=_dtype_of(n)) for n, arr in cols.items()})
    meta = {
        META_KEYS["config"]: _dumps(dict(config)),
        META_KEYS["params"]: _dumps(p),
        META_KEYS["outcome"]: _dumps(dict(outcome)),
        META_KEYS["version"]: __version__,
        META_KEYS["git"]: git_revision(),
    }
    buf = io.BytesIO()
    df.write_parquet(buf, metadata=meta)
    return buf.getvalue()


def read_run_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The metadata of a run file without its data: ``{"config", "params", "outcome"}``
    as dicts and ``"version"``, ``"git"`` as strings."""
    try:
        raw = pl.read_parquet_metadata(Path(path))
    except pl.exceptions.PolarsError as exc:
        raise _unreadable(path, exc) from exc
    if META_KEYS["params"] not in raw:
        raise RunFileError(f"{path}: not an rmi run file (no {META_KEYS['params']} metadata)")
    meta: dict[str, Any] = {}
    for key, mkey in META_KEYS.items():
        value = raw.get(mkey)
        if key in ("config", "params", "outcome"):
            meta[key] = json.loads(value) if value is not None else {}
        else:
            meta[key] = value
    return meta


def _dtype_of(name: str) -> pl.DataType:
    if name in _STRING_COLUMNS:
        return pl.String()
    return pl.Boolean() if name in _BOOL_COLUMNS else pl.Float64()


def check_run_schema(path: str | os.PathLike[str], schema: Mapping[str, Any]) -> None:
    """Refuse a run file whose columns lack a name of :data:`RUN_COLUMNS` or hold one with
    another type than the contract's (f64; ``phase`` string; ``gate_open`` bool): raises
    :class:`RunFileError` naming the file and the column. Further columns are allowed."""
    missing = [c for c in RUN_COLUMNS if c not in schema]
    if missing:
        raise RunFileError(
            f"{path}: not a run file of this contract: missing column(s) {missing} "
            "(see docs/data-contract.md)"
        )
    for name in RUN_COLUMNS:
        want = _dtype_of(name)
        if schema[name] != want:
            raise RunFileError(
                f"{path}: column {name!r} is {schema[name]}, the contract says {want}"
            )


def check_run_values(path: str | os.PathLike[str], df: pl.DataFrame) -> None:
    """Refuse a run file (already schema-checked) with no rows, a null, a non-finite value
    where the contract forbids one (NaN only in ``v_res``, inf nowhere) or a ``time`` that
    does not increase: raises :class:`RunFileError` naming the file and the column."""
    if df.height == 0:
        raise RunFileError(f"{path}: a run file needs at least one row")
    floats = [c for c in RUN_COLUMNS if _dtype_of(c) == pl.Float64()]
    bad = df.select(
        [pl.col(c).null_count().alias(f"null:{c}") for c in RUN_COLUMNS]
        + [
            (pl.col(c).is_infinite() if c in NAN_ALLOWED else ~pl.col(c).is_finite())
            .sum()
            .alias(f"value:{c}")
            for c in floats
        ]
        + [(pl.col("time").diff() <= 0).sum().alias("order:time")]
    ).row(0, named=True)
    for key, n in bad.items():
        if n:
            kind, name = key.split(":")
            what = {
                "null": "null value(s)",
                "value": "infinite value(s)"
                if name in NAN_ALLOWED
                else f"non-finite value(s) (only {sorted(NAN_ALLOWED)} may be NaN)",
                "order": "step(s) where it does not increase",
            }[kind]
            raise RunFileError(f"{path}: column {name!r} has {n} {what}")


def check_run_params(path: str | os.PathLike[str], params: Any) -> None:
    """Refuse a run file whose parameters (``rmi.params``) break the contract that
    :func:`write_run` checks: one missing, not a number, a fraction where an integer
    belongs, a seed outside [0, SEED_MAX]. Raises :class:`RunFileError` naming the file."""
    if not isinstance(params, Mapping):
        raise RunFileError(f"{path}: {META_KEYS['params']} is not a JSON object")
    try:
        _validate_params(params)
    except RunFileError as exc:
        raise RunFileError(f"{path}: {exc}") from exc
    except (TypeError, ValueError, OverflowError) as exc:
        raise RunFileError(f"{path}: a parameter is not a number ({exc})") from exc


def read_run(path: str | os.PathLike[str]) -> tuple[pl.DataFrame, dict[str, Any]]:
    """Read a run file: its rows as a polars DataFrame and its metadata
    (see :func:`read_run_meta`). The rows and parameters are checked against the run-file
    contract (:func:`check_run_schema`, :func:`check_run_values`,
    :func:`check_run_params`), so a file written by other tools cannot carry a NaN, inf, a
    missing channel or a seed that does not fit Int64 into the dataset; raises
    :class:`RunFileError` naming the file and the column or parameter."""
    meta = read_run_meta(path)
    check_run_params(path, meta["params"])
    try:
        df = pl.read_parquet(Path(path))
    except pl.exceptions.PolarsError as exc:
        raise _unreadable(path, exc) from exc
    check_run_schema(path, df.schema)
    check_run_values(path, df)
    return df, meta


def _unreadable(path: str | os.PathLike[str], exc: Exception) -> RunFileError:
    # Run files are written atomically, so a damaged one came from outside (a full disk, a
    # copy cut short): say which, and how to get the run back.
    return RunFileError(f"{path}: unreadable run file ({exc}); delete it and sweep again to rerun")


def scan_runs(root: str | os.PathLike[str]) -> pl.LazyFrame:
    """Lazily scan every run file under a grid root, with the hive partition columns
    ``size_cm, porosity, F_hold, F_squeeze, seed`` typed as in :data:`PARAM_SCHEMA`."""
    return pl.scan_parquet(
        Path(root) / "**" / RUN_FILE,
        hive_partitioning=True,
        hive_schema=PARAM_SCHEMA,
    )


def write_error(
    directory: str | os.PathLike[str], params: Mapping[str, Any], record: Mapping[str, Any]
) -> Path:
    """Record a run that produced no run file (``status`` failed or unstable, ``error``
    text, ``wall_s``) as ``error.json`` in its run directory, atomically."""
    body = {"params": _validate_params(params), **dict(record)}
    body.setdefault("version", __version__)
    body.setdefault("git", git_revision())
    return atomic_write_json(Path(directory) / ERROR_FILE, body)
