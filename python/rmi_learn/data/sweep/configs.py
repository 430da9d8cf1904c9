"""The trial configs of a sweep's runs: built by the engine for every run before anything
is written (:func:`configs_of`), and compared with those of the runs a directory already
holds before a sweep resumes over them (:func:`check_stale`)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import rmi_sph
from rmi_learn.data.runs import read_run_meta, run_path
from rmi_learn.data.sweep.grid import RunSpec

#: Builds a run's trial config: ``make_config(size_cm, porosity, hold_force, squeeze_force,
#: radius, seed, **overrides) -> dict``, like ``rmi_sph.trial_config``.
ConfigMaker = Callable[..., dict[str, Any]]


def config_of(spec: RunSpec, make_config: ConfigMaker = rmi_sph.trial_config) -> dict[str, Any]:
    """The trial config ``make_config`` builds for ``spec``."""
    p = spec.params
    return make_config(
        p["size_cm"],
        p["porosity"],
        p["F_hold"],
        p["F_squeeze"],
        spec.radius,
        p["seed"],
        **spec.overrides,
    )


def configs_of(
    specs: list[RunSpec], make_config: ConfigMaker = rmi_sph.trial_config
) -> dict[str, dict[str, Any]]:
    """Every run's trial config by run id, built before anything is written: an override or
    value the engine refuses would otherwise fail each run of the grid one by one, recorded
    as failed. Raises ``ValueError`` naming the first such run and the engine's message."""
    configs: dict[str, dict[str, Any]] = {}
    for spec in specs:
        try:
            configs[spec.run_id] = config_of(spec, make_config)
        except rmi_sph.ConfigError as exc:
            raise ValueError(f"run {spec.run_id}: {exc} (no run was started)") from exc
    return configs


#: Trial config fields added after runs were first stored, whose default reproduces what
#: those runs did (``controller.perturbation`` and ``pressure.single_solve`` are off by
#: default): a stored config without them is compared as if it held the default.
_LATER_FIELDS: tuple[str, ...] = ("controller.perturbation", "pressure.single_solve")


def _get_path(config: Mapping[str, Any], dotted: str) -> Any:
    value: Any = config
    for key in dotted.split("."):
        value = value[key]
    return value


def _set_if_absent(config: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A copy of ``config`` with ``value`` at ``dotted`` when the parent exists and the key
    does not."""
    *parents, last = dotted.split(".")
    out: dict[str, Any] = json.loads(json.dumps(config))
    node: Any = out
    for key in parents:
        if not isinstance(node, dict) or key not in node:
            return out
        node = node[key]
    if isinstance(node, dict) and last not in node:
        node[last] = json.loads(json.dumps(value))
    return out


def with_later_fields(stored: dict[str, Any], default: Mapping[str, Any]) -> dict[str, Any]:
    """``stored`` (a run's saved trial config) with each field of ``_LATER_FIELDS`` that it
    lacks set to its value in ``default`` (the engine's default trial config)."""
    for field_path in _LATER_FIELDS:
        stored = _set_if_absent(stored, field_path, _get_path(default, field_path))
    return stored


def _differences(old: Any, new: Any, path: str = "") -> list[str]:
    """Dotted paths where two JSON values differ, with both values."""
    if isinstance(old, dict) and isinstance(new, dict):
        out: list[str] = []
        for k in sorted(set(old) | set(new)):
            sub = f"{path}.{k}" if path else str(k)
            if k not in old or k not in new:
                was = repr(old[k]) if k in old else "<absent>"
                now = repr(new[k]) if k in new else "<absent>"
                out.append(f"{sub}: {was} -> {now}")
            else:
                out.extend(_differences(old[k], new[k], sub))
        return out
    return [] if old == new else [f"{path}: {old!r} -> {new!r}"]


def check_stale(
    specs: Iterable[RunSpec], runs_root: Path, configs: Mapping[str, dict[str, Any]]
) -> None:
    """Refuse to resume over finished runs that the current engine would configure
    differently (a changed default, say): their data would silently mix two physics.
    ``configs``: the config the engine builds now, by run id.

    Raises ``ValueError`` naming the number of stale runs, one of them and the fields that
    differ; the caller removes them or sweeps into a new directory.
    """
    stale: list[tuple[str, list[str]]] = []
    default = rmi_sph.default_config()
    for spec in specs:
        path = run_path(runs_root, spec.params)
        if not path.exists():
            continue
        stored = with_later_fields(read_run_meta(path)["config"], default)
        diff = _differences(stored, json.loads(json.dumps(configs[spec.run_id])))
        if diff:
            stale.append((spec.run_id, diff))
    if stale:
        run_id, diff = stale[0]
        raise ValueError(
            f"{len(stale)} finished run(s) under {runs_root} were made with another trial config "
            f"than this engine builds now, e.g. {run_id}: "
            + "; ".join(diff[:4])
            + f". Sweep into a new --out directory, or delete {runs_root} to recompute them."
        )


def is_perturbed(config: Mapping[str, Any]) -> bool:
    """Whether a stored trial config follows seeded force targets from the lift on."""
    perturbation = config.get("controller", {}).get("perturbation", {})
    return bool(perturbation.get("enabled", False))
