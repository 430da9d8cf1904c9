"""The benchmark's protocol: a committed JSON file that fixes, before the test run, the
controllers, how they are tuned, the task variants, the observation modes, the seeds and the
measures. The benchmark reads it, records its digest with every row, and refuses to resume
or extend an output written under another protocol or to run on another grid.

Fields (all required unless marked):
- ``name`` (str), ``grid`` (the sweep's grid name), optional ``sizes_cm`` (the sizes run;
  default all);
- ``split``: ``leave-one-group-out`` (per size, each (porosity, F_hold) group is once the
  held-out test condition; its fold's choices use the other groups only);
- ``states``: ``phases`` (start phases, lifted: the wrist load weighs the sponge),
  ``tuning_per_group`` (tuning states per group, from distinct runs), ``test_per_size``,
  ``max_per_run`` (1-4), ``seed``;
- ``horizon`` (control steps to the reach score) and ``settle_ticks`` (control steps at
  F_hold before the settle score);
- ``tasks``: a non-empty subset of ``reach``, ``settle``;
- ``goal_seed`` (int), ``setpoint_low_fraction`` (the lower setpoint bound as a fraction of
  F_hold), ``bisection_steps`` (the constant-setpoint oracle's executed bisection steps);
- ``sensors``: the sensor model (:class:`rmi_learn.sensing.SensorModel` fields);
- ``controllers``: names of :data:`CONTROLLERS`;
- ``pi``: ``ki`` (N/(kg s)) and ``kp`` (N/kg) candidate lists, tuned per size and estimator
  on the tuning states' reach error (``pi-settle``: the settle error);
- ``release_probes`` (required with ``pi-settle``): ``setpoints`` (2-20, spaced evenly over
  the setpoint bounds), ``ticks`` (control steps before the release, each in [1,
  horizon]) and ``penalty`` (the settle regression's ridge penalty on standardised
  features), executed from every tuning state (:mod:`~rmi_learn.control_bench.feedback.release`);
- ``references``: the PI controller each observation mode's ratios are taken against;
- ``bootstrap``: ``resamples`` and ``seed`` of the cluster bootstrap by run.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rmi_learn.errors import InputError
from rmi_learn.sensing import SensorModel
from rmi_learn.user_files import read_user_text

#: Controller name -> observation mode (``oracle`` executes the simulator itself).
CONTROLLERS: dict[str, str] = {
    "pi-privileged": "privileged",
    "pi-weight": "sensors",
    "pi-width": "sensors",
    "pi-learned": "sensors",
    "pi-settle": "sensors",
    "mpc-settle": "sensors",
    "model-constant": "sensors",
    "hold": "sensors",
    "scripted": "sensors",
    "oracle-constant": "oracle",
}
TASKS: tuple[str, ...] = ("reach", "settle")
PHASES: tuple[str, ...] = ("lift", "waiting", "squeeze")
PROTOCOL_DIR = Path(__file__).resolve().parent / "protocols"


@dataclass(frozen=True)
class Protocol:
    """A validated protocol and the SHA-256 digest of its canonical JSON."""

    raw: dict[str, Any]
    digest: str
    sensors: SensorModel

    def __getitem__(self, key: str) -> Any:
        return self.raw[key]


def _int(m: Mapping[str, Any], key: str, lo: int, hi: int, where: str) -> int:
    v = m.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise InputError(f"protocol {where}{key} must be an integer in [{lo}, {hi}] (got {v!r})")
    return v


def _obj(m: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    v = m.get(key)
    if not isinstance(v, Mapping):
        raise InputError(f"protocol {key} must be an object (got {type(v).__name__})")
    return v


def _numbers(m: Mapping[str, Any], key: str, where: str, lo: float, hi: float) -> list[float]:
    v = m.get(key)
    ok = (
        isinstance(v, list)
        and v
        and all(isinstance(x, int | float) and not isinstance(x, bool) and lo <= x <= hi for x in v)
    )
    if not ok:
        raise InputError(
            f"protocol {where}{key} must be a non-empty list of numbers in [{lo}, {hi}]"
        )
    return [float(x) for x in v]


def _penalty(m: Mapping[str, Any], where: str) -> float:
    lam = m.get("penalty")
    if isinstance(lam, bool) or not isinstance(lam, int | float) or not 0.0 < lam <= 1e6:
        raise InputError(f"protocol {where}penalty must be a number in (0, 1e6] (got {lam!r})")
    return float(lam)


def validate(raw: Mapping[str, Any]) -> Protocol:
    """Check every field (one line naming the first bad one) and compute the digest."""
    if not isinstance(raw, Mapping):
        raise InputError("the protocol must be a JSON object")
    for key in ("name", "grid"):
        if not isinstance(raw.get(key), str) or not raw[key]:
            raise InputError(f"protocol {key} must be a non-empty string")
    sizes = raw.get("sizes_cm", [8, 10, 12])
    if not isinstance(sizes, list) or not sizes or not all(x in (8, 10, 12) for x in sizes):
        raise InputError("protocol sizes_cm must be a non-empty list of 8, 10, 12")
    if raw.get("split") != "leave-one-group-out":
        raise InputError('protocol split must be "leave-one-group-out"')
    states = _obj(raw, "states")
    phases = states.get("phases")
    if not isinstance(phases, list) or not phases or not set(phases) <= set(PHASES):
        raise InputError(
            f"protocol states.phases must be a non-empty subset of {', '.join(PHASES)}"
        )
    _int(states, "max_per_run", 1, 4, "states.")
    _int(states, "tuning_per_group", 1, 100, "states.")
    _int(states, "test_per_size", 1, 10000, "states.")
    _int(states, "seed", 0, 2**31, "states.")
    _int(raw, "horizon", 1, 200, "")
    _int(raw, "settle_ticks", 0, 200, "")
    tasks = raw.get("tasks")
    if not isinstance(tasks, list) or not tasks or not set(tasks) <= set(TASKS):
        raise InputError(f"protocol tasks must be a non-empty subset of {', '.join(TASKS)}")
    if "settle" in tasks and raw["settle_ticks"] < 1:
        raise InputError("protocol settle_ticks must be at least 1 for the settle task")
    _int(raw, "goal_seed", 0, 2**31, "")
    _int(raw, "bisection_steps", 0, 10, "")
    low = raw.get("setpoint_low_fraction")
    if isinstance(low, bool) or not isinstance(low, int | float) or not 0.0 < low <= 1.0:
        raise InputError("protocol setpoint_low_fraction must be a number in (0, 1]")
    sensors = SensorModel.from_mapping(raw.get("sensors"))
    ctrls = raw.get("controllers")
    if not isinstance(ctrls, list) or not ctrls or not all(c in CONTROLLERS for c in ctrls):
        raise InputError(
            f"protocol controllers must be a non-empty list of {', '.join(CONTROLLERS)}"
        )
    probing = [c for c in ("pi-settle", "mpc-settle", "model-constant") if c in ctrls]
    if {"mpc-settle", "model-constant"} & set(ctrls):
        # Imported here: the planner's module brings the engine and (through held_out)
        # torch, which the command-line parser (it names the shipped protocols) must not load.
        from rmi_learn.control_bench.feedback.settle_planner import FEATURE_SETS

        model = _obj(raw, "settle_model")
        _penalty(model, "settle_model.")
        inputs = model.get("inputs")
        if (
            not isinstance(inputs, list)
            or not inputs
            or not all(isinstance(n, str) and n in FEATURE_SETS for n in inputs)
        ):
            names = ", ".join(FEATURE_SETS)
            raise InputError(f"protocol settle_model.inputs must be a non-empty list of {names}")
        _int(model, "candidates", 2, 200, "settle_model.")
        _int(model, "replan_ticks", 1, raw["horizon"], "settle_model.")
    if probing:
        if "settle" not in tasks:
            raise InputError(f"protocol controllers: {probing[0]} needs the settle task in tasks")
        probes = _obj(raw, "release_probes")
        _int(probes, "setpoints", 2, 20, "release_probes.")
        _penalty(probes, "release_probes.")
        ticks = probes.get("ticks")
        ok = (
            isinstance(ticks, list)
            and ticks
            and all(
                isinstance(k, int) and not isinstance(k, bool) and 1 <= k <= raw["horizon"]
                for k in ticks
            )
        )
        if not ok:
            raise InputError(
                "protocol release_probes.ticks must be a non-empty list of integers in "
                f"[1, {raw['horizon']}] (the horizon)"
            )
    pi = _obj(raw, "pi")
    _numbers(pi, "ki", "pi.", 0.0, 1e8)
    _numbers(pi, "kp", "pi.", 0.0, 1e8)
    refs = _obj(raw, "references")
    for mode, ref in refs.items():
        if ref not in ctrls or CONTROLLERS[ref] != mode:
            raise InputError(
                f"protocol references.{mode} must name a listed controller of that mode "
                f"(got {ref!r})"
            )
    boot = _obj(raw, "bootstrap")
    _int(boot, "resamples", 100, 100000, "bootstrap.")
    _int(boot, "seed", 0, 2**31, "bootstrap.")
    canonical = json.dumps(raw, sort_keys=True, separators=(",", ":"))
    return Protocol(dict(raw), hashlib.sha256(canonical.encode()).hexdigest(), sensors)


def load_protocol(source: str | Path) -> Protocol:
    """A protocol from a file path or the name of a shipped one (``control``, ``quick``)."""
    path = Path(source)
    if not path.suffix and not path.exists():
        path = PROTOCOL_DIR / f"{source}.json"
        if not path.exists():
            shipped = sorted(p.stem for p in PROTOCOL_DIR.glob("*.json"))
            raise InputError(
                f"--protocol {source}: no such file or shipped protocol ({', '.join(shipped)})"
            )
    try:
        raw = json.loads(read_user_text(path, "protocol file", label=f"--protocol {path}"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--protocol {path}: cannot read it ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"--protocol {path}: not JSON ({exc})") from exc
    return validate(raw)


__all__ = ["CONTROLLERS", "PROTOCOL_DIR", "TASKS", "Protocol", "load_protocol", "validate"]
