"""How well the retained water is known from what a gripper senses: the table ``rmi eval-wm``
adds when it is given a model that reads the sensors (``table_sensors.md``, ``.json``).

On the test windows anchored in the squeeze (the sponge lifted, where the goal-reaching
benchmark acts), per sponge size: the water error now (the state a controller starts from)
and at 0.64 s, of the models that read y_t (the Baseline and AC-GRU-WM, which observe the
water now), of the wrist load's weight estimate persisted
(:class:`~rmi_learn.world_models.weight_persistence.WeightPersistenceWM`, the sensors
mode's persistence) and of each sensor-mode model (a mean over its training seeds, each seed
listed). Every row of a size scores the same windows.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from rmi_learn.data.dataset import Dataset
from rmi_learn.sensing import SensorModel
from rmi_learn.world_models.baseline import BaselineWM
from rmi_learn.world_models.common import WATER
from rmi_learn.world_models.registry import DISPLAY_NAMES
from rmi_learn.world_models.weight_persistence import WeightPersistenceWM

#: The phases the table's windows are anchored in.
ANCHOR_PHASES: tuple[str, ...] = ("squeeze",)
#: The forecast step of the table's second column (0.64 s).
STEP = 32


def _water_now_mae_g(model: Any, ws: Any, idx: np.ndarray, water_std: float, bs: int) -> float:
    """Mean |estimated - true| water at each window's anchor (g); 0 for a model that
    observes it."""
    if not hasattr(model, "estimate_state") or model.observation_mode == "privileged":
        return 0.0
    errs = []
    with torch.no_grad():
        for s in range(0, idx.size, bs):
            b = ws.batch(idx[s : s + bs])
            z0 = model.estimate_state(b["hist"], b["hist_mask"])
            errs.append((z0[:, WATER] - b["z_now"][:, WATER]).abs().double().numpy())
    return float(np.concatenate(errs).mean() * water_std * 1e3)


def _score(model: Any, ws: Any, z_std: np.ndarray, max_windows: int | None, bs: int) -> dict:
    from rmi_learn.world_models.evaluation import evaluate_rollouts, evenly_spaced

    idx = evenly_spaced(len(ws), max_windows)
    model.eval()
    now = _water_now_mae_g(model, ws, idx, float(z_std[WATER]), bs)
    m = evaluate_rollouts(model, ws, z_std, batch_size=bs, max_windows=max_windows, steps=(STEP,))
    return {"water_now_mae_g": now, f"water_mae_g@{STEP}": float(m[f"water_mae_g@{STEP}"])}


def sensor_records(
    runs: Sequence[tuple[Any, dict[str, Any]]],
    ds: Dataset,
    split: str = "test",
    batch_size: int = 256,
    max_windows: int | None = None,
) -> list[dict[str, Any]]:
    """The table's records, one per (row, size): ``method``, ``observation_mode``,
    ``size_cm``, ``windows``, ``water_now_mae_g``, ``water_mae_g@32``, ``seeds`` and, for a
    row of several seeds, ``per_seed``. ``runs`` are loaded ``rmi train-wm`` outputs
    (model, config.json); those of AC-GRU-WM on y_t (all state groups, commands in order)
    and of the sensor-mode models make rows."""
    z_std = np.asarray(ds.stats.z_std, dtype=np.float64)
    groups: dict[tuple[str, str, str], list[tuple[Any, dict[str, Any]]]] = {}
    for model, cfg in runs:
        extra = cfg.get("extra") or {}
        mode = str(extra.get("observation_mode") or "privileged")
        kind = cfg["model"]["kind"]
        if extra.get("shuffle_actions") or extra.get("size_cm") is not None:
            continue
        if mode == "privileged" and (kind != "ac-gru" or model.state_groups != "ALL"):
            continue
        sensors = json.dumps(extra.get("sensors"), sort_keys=True)
        groups.setdefault((kind, mode, sensors), []).append((model, extra))
    sensor_models = {
        sensors: SensorModel.from_mapping(json.loads(sensors))
        for sensors in sorted({k[2] for k in groups if k[1] == "sensors"})
    }
    weights = {s: WeightPersistenceWM.from_dataset(ds, sm) for s, sm in sensor_models.items()}
    records = []
    for size in sorted(int(s) for s in ds.runs["size_cm"].unique().to_list()):
        ws_p = ds.windows(split, size, anchor_phases=ANCHOR_PHASES)
        if len(ws_p) == 0:
            continue
        rows: list[tuple[str, str, Any, list[tuple[Any, dict[str, Any]]]]] = [
            ("Baseline (y_t)", "privileged", ws_p, [(BaselineWM(), {})])
        ]
        for (kind, mode, _), members in sorted(groups.items()):
            if mode == "privileged":
                rows.append((f"{DISPLAY_NAMES[kind]} (y_t)", mode, ws_p, members))
        for sensors, sm in sensor_models.items():
            ws_s = ds.windows(
                split, size, observation_mode="sensors", sensors=sm, anchor_phases=ANCHOR_PHASES
            )
            label = "" if len(sensor_models) == 1 else f", sensors {sensors}"
            weight = [(weights[sensors], {})]
            rows.append((f"Weight estimate (sensors{label})", "sensors", ws_s, weight))
            for (kind, mode, s), members in sorted(groups.items()):
                if mode == "sensors" and s == sensors:
                    rows.append((f"{DISPLAY_NAMES[kind]} (sensors{label})", mode, ws_s, members))
        for method, mode, ws, members in rows:
            per_seed = [_score(m, ws, z_std, max_windows, batch_size) for m, _ in members]
            rec: dict[str, Any] = {
                "method": method,
                "observation_mode": mode,
                "size_cm": size,
                "windows": min(len(ws), max_windows or len(ws)),
                "seeds": [extra.get("seed") for _, extra in members],
                **{k: float(np.mean([p[k] for p in per_seed])) for k in per_seed[0]},
            }
            if len(per_seed) > 1:
                rec["per_seed"] = per_seed
            records.append(rec)
    return records


def write_sensor_table(records: list[dict[str, Any]], out: str | Path) -> dict[str, Path]:
    """``table_sensors.md`` and ``table_sensors.json`` in ``out``; their paths by name."""
    out = Path(out)
    sizes = sorted({r["size_cm"] for r in records})
    methods = list(dict.fromkeys(r["method"] for r in records))
    head = ["Method"] + [f"{s} cm water {c} (g)" for s in sizes for c in ("now", "0.64 s")]
    lines = [
        "# The retained water from what the gripper senses",
        "",
        f"Test windows anchored in the squeeze ({', '.join(f'{s} cm' for s in sizes)}: "
        + ", ".join(str(next(r["windows"] for r in records if r["size_cm"] == s)) for s in sizes)
        + " windows); water MAE now (the state a controller starts from; 0 for a model "
        "that observes it) and at 0.64 s.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for m in methods:
        cells = [m]
        for s in sizes:
            r = next((r for r in records if r["method"] == m and r["size_cm"] == s), None)
            for k in ("water_now_mae_g", f"water_mae_g@{STEP}"):
                cells.append("–" if r is None else f"{r[k]:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    seeds = [r for r in records if "per_seed" in r]
    if seeds:
        lines += ["", "Rows over several training seeds, water at 0.64 s per seed (g):", ""]
        for r in seeds:
            vals = " / ".join(f"{p[f'water_mae_g@{STEP}']:.2f}" for p in r["per_seed"])
            lines.append(f"- {r['method']}, {r['size_cm']} cm (seeds {r['seeds']}): {vals}")
    (out / "table_sensors.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (out / "table_sensors.json").write_text(
        json.dumps({"step": STEP, "anchor_phases": list(ANCHOR_PHASES), "rows": records}, indent=2)
        + "\n",
        encoding="utf-8",
    )
    return {
        "table_sensors": out / "table_sensors.md",
        "table_sensors_json": out / "table_sensors.json",
    }


__all__ = ["ANCHOR_PHASES", "sensor_records", "write_sensor_table"]
