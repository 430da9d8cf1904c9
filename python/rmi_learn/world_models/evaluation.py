"""Evaluation of the world models (``rmi eval-wm``): forecast metrics in physical units and
the paper's Tables II-IV.

Metrics at horizons of 0.16/0.32/0.64/1.28 s (steps 8/16/32/64 at 20 ms), from free rollouts
on one window set: water MAE in grams (M_L is stored in kg), force MAE in newtons (F_meas),
balanced accuracy over the four friction classes and over contact. Errors are averaged over
windows whose target at that step is valid. Balanced accuracy is the mean per-class recall over
the classes present in the targets.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from rmi_learn.data.dataset import Dataset, Stats, load_dataset
from rmi_learn.data.schema import SPONGE_SIZES_CM
from rmi_learn.errors import input_errors
from rmi_learn.sensing import SensorModel
from rmi_learn.trainer import RESUME_FREE, count_parameters
from rmi_learn.world_models.baseline import BaselineWM, SetpointReadoutWM
from rmi_learn.world_models.common import FORCE, N_FRIC, N_U, WATER, ShuffledActions
from rmi_learn.world_models.findings import lookup
from rmi_learn.world_models.horizons import HORIZON_STEPS, MAIN_STEP, horizon_label
from rmi_learn.world_models.registry import DISPLAY_NAMES, load
from rmi_learn.world_models.training_settings import RESUME_LEGACY


def _std(stats: Any, name: str) -> np.ndarray:
    v = getattr(stats, name) if not isinstance(stats, dict) else stats[name]
    return np.asarray(v, dtype=np.float64)


def balanced_accuracy(confusion: np.ndarray) -> float:
    """Mean recall over the classes that occur (rows: true class, columns: predicted)."""
    support = confusion.sum(axis=1)
    present = support > 0
    if not present.any():
        return float("nan")
    recall = np.diag(confusion)[present] / support[present]
    return float(recall.mean())


class RolloutMetrics:
    """Accumulates absolute errors and confusion matrices over batches of rollouts."""

    def __init__(self, z_std: np.ndarray, steps: Sequence[int] = HORIZON_STEPS) -> None:
        self.steps = tuple(steps)
        self.water_scale = float(z_std[WATER]) * 1000.0  # standardised -> g
        self.force_scale = float(z_std[FORCE])  # standardised -> N
        k = len(self.steps)
        self.water_sum = np.zeros(k)
        self.water_n = np.zeros(k)
        self.force_sum = np.zeros(k)
        self.force_n = np.zeros(k)
        self.fric = np.zeros((k, N_FRIC, N_FRIC), dtype=np.int64)
        self.contact = np.zeros((k, 2, 2), dtype=np.int64)
        self.windows = 0

    def update(self, out: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]) -> None:
        """Add one batch: ``out`` from a model's forward, ``batch`` from a window set."""
        z = out["z"].detach().float().cpu().numpy()
        h = z.shape[1]
        tgt = batch["target"][:, :h].float().cpu().numpy()
        msk = batch["target_mask"][:, :h].float().cpu().numpy()
        c_pred = (out["contact_logit"].detach().cpu().numpy() > 0).astype(np.int64)
        f_pred = out["friction_logit"].detach().cpu().numpy().argmax(-1)
        c_true = batch["target_c"][:, :h].cpu().numpy().round().astype(np.int64)
        f_true = batch["target_r"][:, :h].cpu().numpy().astype(np.int64)
        self.windows += z.shape[0]
        for i, s in enumerate(self.steps):
            if s > h:
                continue
            j = s - 1
            for ch, scale, acc, cnt in (
                (WATER, self.water_scale, self.water_sum, self.water_n),
                (FORCE, self.force_scale, self.force_sum, self.force_n),
            ):
                m = msk[:, j, ch] > 0
                acc[i] += np.abs(z[m, j, ch] - tgt[m, j, ch]).sum() * scale
                cnt[i] += m.sum()
            np.add.at(self.fric[i], (f_true[:, j], f_pred[:, j]), 1)
            np.add.at(self.contact[i], (c_true[:, j], c_pred[:, j]), 1)

    def result(self) -> dict[str, float]:
        """``water_mae_g@k``, ``force_mae_n@k``, ``fric_bacc@k``, ``contact_bacc@k`` per step
        k, ``water_mae_g_mean`` over the steps, and ``windows``."""
        r: dict[str, float] = {"windows": float(self.windows)}
        for i, s in enumerate(self.steps):
            nan = float("nan")
            r[f"water_mae_g@{s}"] = self.water_sum[i] / self.water_n[i] if self.water_n[i] else nan
            r[f"force_mae_n@{s}"] = self.force_sum[i] / self.force_n[i] if self.force_n[i] else nan
            r[f"fric_bacc@{s}"] = balanced_accuracy(self.fric[i])
            r[f"contact_bacc@{s}"] = balanced_accuracy(self.contact[i])
        vals = [r[f"water_mae_g@{s}"] for s in self.steps]
        r["water_mae_g_mean"] = float(np.mean(vals))
        return {k: float(v) for k, v in r.items()}


def evenly_spaced(n: int, max_windows: int | None) -> np.ndarray:
    """Indices of the windows an evaluation of at most ``max_windows`` of ``n`` scores:
    all of them, or that many evenly spaced."""
    if max_windows is not None and n > max_windows:
        return np.linspace(0, n - 1, max_windows).round().astype(np.int64)
    return np.arange(n)


@torch.no_grad()
def evaluate_rollouts(
    model: torch.nn.Module,
    data: Any,
    z_std: Any,
    *,
    batch_size: int = 256,
    max_windows: int | None = None,
    steps: Sequence[int] = HORIZON_STEPS,
    device: str = "cpu",
    loss: Callable[[dict[str, torch.Tensor], dict[str, torch.Tensor]], torch.Tensor] | None = None,
) -> dict[str, float]:
    """Free-rollout metrics of ``model`` over the windows of ``data`` (``batch(indices)``).

    ``z_std`` (18,) is the training standard deviation of z in SI units (Dataset.stats.z_std).
    ``max_windows`` evaluates an evenly spaced subset (for quick validation). ``loss``
    (``(out, batch) -> scalar``, e.g. the training loss) adds ``"loss"``: its mean over the
    batches, weighted by their window counts, from the same free rollouts.
    """
    was = model.training
    model.eval()
    acc = RolloutMetrics(np.asarray(z_std, dtype=np.float64), steps)
    idx_all = evenly_spaced(len(data), max_windows)
    loss_sum, loss_n = 0.0, 0
    for s in range(0, len(idx_all), batch_size):
        batch = data.batch(idx_all[s : s + batch_size])
        batch = {k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
        out = model(batch["hist"], batch["hist_mask"], batch["actions"])
        acc.update(out, batch)
        if loss is not None:
            n = int(batch["hist"].shape[0])
            loss_sum += float(loss(out, batch)) * n
            loss_n += n
    model.train(was)
    result = acc.result()
    if loss is not None:
        result["loss"] = loss_sum / loss_n if loss_n else float("nan")
    return result


def latency_inputs(
    model: torch.nn.Module, n_chunks: int = 8, horizon: int = 32, history: int = 16
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random ``(hist, hist_mask, actions)`` for timing ``n_chunks`` chunks against one
    history: the history once for models that share it across chunks (``shares_history``),
    repeated per chunk for the others; lookahead models get their fixed horizon."""
    fixed = getattr(model, "fixed_horizon", None)
    h = fixed if fixed is not None else horizon
    n_hist = 1 if getattr(model, "shares_history", False) else n_chunks
    c = int(getattr(model, "n_inputs", 23))
    return (
        torch.randn(n_hist, history, c),
        torch.ones(n_hist, history, c),
        torch.randn(n_chunks, h, N_U),
    )


@torch.no_grad()
def benchmark_latency(
    model: torch.nn.Module,
    n_chunks: int = 8,
    horizon: int = 32,
    history: int = 16,
    repeats: int = 50,
) -> float:
    """Median wall time (ms) of one forward pass scoring ``n_chunks`` action chunks of
    ``horizon`` steps for one history, on the current torch thread setting. Models that
    share one history encoding across chunks (``shares_history``) get the history once, as
    the planner passes it; the others get it repeated per chunk."""
    model.eval()
    hist, mask, actions = latency_inputs(model, n_chunks, horizon, history)
    for _ in range(5):
        model(hist, mask, actions)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model(hist, mask, actions)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


# ----------------------------------------------------------------------------- tables

SIZES: tuple[int, ...] = SPONGE_SIZES_CM


def _fmt(v: float | None, digits: int = 2) -> str:
    if v is None or not np.isfinite(v):
        return "–"
    return f"{v:.{digits}f}"


def _metric(rec: dict[str, Any] | None, name: str) -> float | None:
    if rec is None:
        return None
    v = rec["metrics"].get(name)
    return None if v is None else float(v)


def table_rows(
    results: list[dict[str, Any]],
    rows: Sequence[tuple[str, dict[str, Any]]],
    metrics: Sequence[tuple[str, str]],
    step: int,
    sizes: Sequence[int] = SIZES,
) -> list[dict[str, Any]]:
    """JSON rows: ``{"method", "<size>cm": {column: value}}`` for one horizon step."""
    out = []
    for label, key in rows:
        row: dict[str, Any] = {"method": label}
        for s in sizes:
            rec = lookup(results, size_cm=s, **key)
            row[f"{s}cm"] = {col: _metric(rec, f"{m}@{step}") for col, m in metrics}
        out.append(row)
    return out


def markdown_table(
    rows: list[dict[str, Any]],
    metrics: Sequence[tuple[str, str]],
    sizes: Sequence[int] = SIZES,
) -> str:
    """Render :func:`table_rows` output as a Markdown table."""
    head = ["Method"] + [f"{s} cm {col}" for s in sizes for col, _ in metrics]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["method"]]
        for s in sizes:
            for col, _ in metrics:
                cells.append(_fmt(row[f"{s}cm"][col]))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


TABLE2_METRICS = (
    ("water (g)", "water_mae_g"),
    ("force (N)", "force_mae_n"),
    ("fric.", "fric_bacc"),
)
TABLE3_METRICS = (("water (g)", "water_mae_g"), ("force (N)", "force_mae_n"))
TABLE4_METRICS = (("water (g)", "water_mae_g"),)

TABLE2_ROWS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("Baseline", {"kind": "baseline"}),
    ("Setpoint readout", {"kind": "setpoint-readout"}),
    ("State-GRU-WM", {"kind": "state-gru", "state_groups": "ALL", "shuffled": False}),
    ("AC-GRU-WM", {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False}),
    ("AC-GRU-WM, shuffled A", {"kind": "ac-gru", "state_groups": "ALL", "shuffled": True}),
    ("Transformer W_T", {"kind": "transformer", "state_groups": "ALL", "shuffled": False}),
)
#: Rows of the models that read the sensors instead of y_t (Table II's layout, toward the
#: same targets), shown when such a run is evaluated.
SENSOR_ROWS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("State-GRU-WM (sensors)", {"kind": "state-gru", "observation_mode": "sensors"}),
    ("AC-GRU-WM (sensors)", {"kind": "ac-gru", "observation_mode": "sensors"}),
)
TABLE3_ROWS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("Linear-ARX", {"kind": "arx", "shuffled": False}),
    ("Linear-ARX, shuffled A", {"kind": "arx", "shuffled": True}),
    ("AC-MLP-WM", {"kind": "ac-mlp", "state_groups": "ALL", "shuffled": False}),
    ("AC-MLP-WM, shuffled A", {"kind": "ac-mlp", "state_groups": "ALL", "shuffled": True}),
)
TABLE4_ROWS: tuple[tuple[str, dict[str, Any]], ...] = tuple(
    (g, {"kind": "ac-gru", "state_groups": g, "shuffled": False})
    for g in ("LS", "LS+G", "LS+G+C", "ALL")
)


def reduction_vs_baseline(results: list[dict[str, Any]], step: int = MAIN_STEP) -> dict[str, Any]:
    """Relative water-error reduction of AC-GRU-WM against the Baseline per size (fraction;
    0.6 = 60 % lower error), at ``step``."""
    out: dict[str, Any] = {}
    for s in SIZES:
        base = _metric(lookup(results, size_cm=s, kind="baseline"), f"water_mae_g@{step}")
        ac = _metric(
            lookup(results, size_cm=s, kind="ac-gru", state_groups="ALL", shuffled=False),
            f"water_mae_g@{step}",
        )
        out[f"{s}cm"] = (1.0 - ac / base) if (base and ac is not None and base > 0) else None
    return out


def _seed_notes(
    results: list[dict[str, Any]], rows: Sequence[tuple[str, dict[str, Any]]]
) -> list[str]:
    """Markdown lines naming the rows whose cells are means over training seeds, with the
    per-seed water error at 0.64 s (the spread that one training run can move a cell)."""
    lines = []
    for label, key in rows:
        parts = []
        for s in SIZES:
            rec = lookup(results, size_cm=s, **key)
            if rec is None or "metrics_per_seed" not in rec:
                continue
            seeds = ", ".join(str(x) for x in rec["seeds"])
            vals = " / ".join(_fmt(m[f"water_mae_g@{MAIN_STEP}"]) for m in rec["metrics_per_seed"])
            parts.append(f"{s} cm (seeds {seeds}) {vals}")
        if parts:
            lines += [
                f"{label}: mean over training runs that differ only in the seed; water (g) at "
                f"{horizon_label(MAIN_STEP)} per run: {'; '.join(parts)}.",
                "",
            ]
    return lines


def write_tables(results: list[dict[str, Any]], out_dir: str | Path) -> dict[str, Path]:
    """Write table2/table3/table4 as .md and .json (all horizons; 0.64 s first) plus
    results.json with every record. Returns the written paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    steps = (MAIN_STEP,) + tuple(s for s in HORIZON_STEPS if s != MAIN_STEP)
    sensing = any(r.get("observation_mode") == "sensors" for r in results)
    specs = {
        "table2": (
            "Table II: causal world-model prediction on the test split",
            TABLE2_ROWS + (SENSOR_ROWS if sensing else ()),
            TABLE2_METRICS,
        ),
        "table3": (
            "Table III (diagnostic): the complete future chunk is visible",
            TABLE3_ROWS,
            TABLE3_METRICS,
        ),
        "table4": (
            "Table IV: state ablation of AC-GRU-WM (water MAE)",
            TABLE4_ROWS,
            TABLE4_METRICS,
        ),
    }
    paths: dict[str, Path] = {}
    for name, (title, rows, metrics) in specs.items():
        md = [f"# {title}", ""]
        js: dict[str, Any] = {"title": title, "horizons": {}}
        for step in steps:
            trows = table_rows(results, rows, metrics, step)
            js["horizons"][horizon_label(step)] = trows
            md += [f"## Horizon {horizon_label(step)} (step {step})", ""]
            md += [markdown_table(trows, metrics), ""]
            if name == "table2":
                red = reduction_vs_baseline(results, step)
                js.setdefault("ac_gru_water_reduction_vs_baseline", {})[horizon_label(step)] = red
                txt = ", ".join(
                    f"{k}: {'–' if v is None else f'{100 * v:.0f} %'}" for k, v in red.items()
                )
                md += [f"AC-GRU-WM water error reduction vs Baseline: {txt}", ""]
        md += _seed_notes(results, rows)
        md += [
            "Water MAE in grams, force MAE in newtons, fric. = balanced accuracy over the four "
            "friction classes; '–' = no run for that cell. Shuffled-A rows were trained and "
            "evaluated with each history paired with a chunk from another run.",
            "",
        ]
        if sensing and name == "table2":
            md += [
                "(sensors) rows read what the gripper's sensors report (width, pad loads, "
                "tactile contact and shear, wrist load; noise and latency of each run's "
                "`sensors` in results.json) and the dry sponge's mass instead of y_t, and "
                "forecast the same y_t.",
                "",
            ]
        (out / f"{name}.md").write_text("\n".join(md), encoding="utf-8")
        (out / f"{name}.json").write_text(json.dumps(js, indent=2) + "\n", encoding="utf-8")
        paths[name] = out / f"{name}.md"
        paths[f"{name}_json"] = out / f"{name}.json"
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    paths["results"] = out / "results.json"
    return paths


#: The seed of the shuffled-command rows' pairing of histories and chunks.
SHUFFLE_SEED = 12345

#: A cell of the tables: (model kind, state groups, shuffled actions, sponge size,
#: observation mode).
CellKey = tuple[str, str, bool, int, str]
#: A cell's choice: (trained on that size alone, its record, the member models, a config).
Cell = tuple[bool, dict[str, Any], list[Any], dict[str, Any]]


def evaluate_runs(
    runs: Sequence[str | Path],
    data: str | Path,
    *,
    split: str = "test",
    batch_size: int = 256,
    max_windows: int | None = None,
    device: str = "cpu",
    latency: bool = True,
    shuffle_seed: int = SHUFFLE_SEED,
) -> list[dict[str, Any]]:
    """One record per (run, sponge size): ``method``, ``kind``, ``state_groups``,
    ``shuffled``, ``size_cm``, ``trained_size_cm``, ``run_dir``, ``split``, ``data`` (the
    dataset directory), ``split_seed`` (its ``rmi dataset --seed``), ``params``,
    ``latency_ms_8x32`` and ``metrics`` (see :class:`RolloutMetrics`).

    When several runs give the same (model, state groups, shuffle, size) cell, a run trained
    on that size alone wins over one trained on every size. Equally specific runs that differ
    only in their training seed are replicates: the cell's ``metrics`` are the mean of theirs
    (``metrics_per_seed``, ``seeds`` and ``run_dirs`` list them); equally specific runs that
    differ in anything else are an error (``ValueError``). The Baseline is added for every
    size when no baseline run is given, and so is the setpoint readout (persistence with
    the measured force read off the chunk's setpoints, built from the dataset's statistics).
    """
    ds = load_dataset(data)
    entries = _entries(runs, ds.stats)
    return _evaluate_entries(
        entries, ds, data, split, batch_size, max_windows, device, latency, shuffle_seed
    )


def _evaluate_entries(
    entries: list[tuple[Any, dict[str, Any], str]],
    ds: Dataset,
    data: str | Path,
    split: str,
    batch_size: int,
    max_windows: int | None,
    device: str,
    latency: bool,
    shuffle_seed: int,
) -> list[dict[str, Any]]:
    """:func:`evaluate_runs` of the loaded ``entries`` (see :func:`_entries`)."""
    sizes = sorted(int(s) for s in ds.runs["size_cm"].unique().to_list())
    chosen: dict[CellKey, Cell] = {}
    for model, cfg, run_dir in entries:
        _check_stats(cfg, ds.stats, run_dir, data)
        _add_to_cells(chosen, model, cfg, run_dir, sizes, ds, split, data)
    results = _evaluate_cells(
        chosen, ds, split, batch_size, max_windows, device, latency, shuffle_seed
    )
    results.sort(key=lambda r: (r["size_cm"], r["kind"], r["state_groups"], r["shuffled"]))
    return results


def _entries(runs: Sequence[str | Path], stats: Stats) -> list[tuple[Any, dict[str, Any], str]]:
    """(model, config, run directory) of every run, then the Baseline and the setpoint
    readout unless a run gives them."""
    entries: list[tuple[Any, dict[str, Any], str]] = []
    for run_dir in runs:
        model, cfg = load(run_dir)
        entries.append((model, cfg, str(run_dir)))
    if not any(cfg["model"]["kind"] == "baseline" for _, cfg, _ in entries):
        entries.append((BaselineWM().eval(), {"model": {"kind": "baseline"}, "extra": {}}, ""))
    if not any(cfg["model"]["kind"] == "setpoint-readout" for _, cfg, _ in entries):
        readout = SetpointReadoutWM.from_stats(stats).eval()
        entries.append((readout, {"model": readout.config(), "extra": {}}, ""))
    return entries


def _check_stats(cfg: dict[str, Any], stats: Stats, run_dir: str, data: str | Path) -> None:
    """ValueError when the run was trained with other standardisation statistics than the
    dataset's."""
    trained_stats = (cfg.get("extra") or {}).get("stats")
    if trained_stats is not None:
        same = np.allclose(trained_stats["z_mean"], stats.z_mean) and np.allclose(
            trained_stats["z_std"], stats.z_std
        )
        if not same:
            raise ValueError(
                f"{run_dir} was trained with other standardisation statistics than {data}"
            )


def _add_to_cells(
    chosen: dict[CellKey, Cell],
    model: Any,
    cfg: dict[str, Any],
    run_dir: str,
    sizes: Sequence[int],
    ds: Dataset,
    split: str,
    data: str | Path,
) -> None:
    """Enter the run in the cells of the sizes it predicts: a new cell, a replicate of an
    equally specific run (another seed), or nothing when a more specific run holds it."""
    extra = cfg.get("extra") or {}
    kind = cfg["model"]["kind"]
    groups = cfg["model"].get("state_groups", "ALL")
    shuffled = bool(extra.get("shuffle_actions", False))
    trained_size = extra.get("size_cm")
    mode = str(extra.get("observation_mode") or "privileged")
    for s in sizes if trained_size is None else [int(trained_size)]:
        key = (kind, groups, shuffled, s, mode)
        specific = trained_size is not None
        if key in chosen:
            old_specific, old_rec, members, old_cfg = chosen[key]
            if old_specific == specific:
                if _setting(old_cfg) != _setting(cfg):
                    raise ValueError(
                        f"two runs for {key}: {old_rec['run_dir']} and {run_dir} differ "
                        "in more than the training seed; pass one"
                    )
                if extra.get("seed") in old_rec["seeds"]:
                    raise ValueError(
                        f"two runs for {key} with seed {extra.get('seed')}: "
                        f"{old_rec['run_dir']} and {run_dir}; pass one"
                    )
                old_rec["run_dirs"].append(run_dir)
                old_rec["seeds"].append(extra.get("seed"))
                members.append(model)
                continue
            if old_specific:
                continue
        rec = {
            "method": DISPLAY_NAMES[kind]
            + (", shuffled A" if shuffled else "")
            + (" (sensors)" if mode == "sensors" else ""),
            "kind": kind,
            "state_groups": groups,
            "shuffled": shuffled,
            "observation_mode": mode,
            "sensors": extra.get("sensors"),
            "size_cm": s,
            "trained_size_cm": trained_size,
            "run_dir": run_dir,
            "run_dirs": [run_dir],
            "seeds": [extra.get("seed")],
            "split": split,
            "data": str(data),
            "split_seed": ds.info.get("seed"),
            "params": count_parameters(model),
        }
        chosen[key] = (specific, rec, [model], cfg)


def _evaluate_cells(
    chosen: dict[CellKey, Cell],
    ds: Dataset,
    split: str,
    batch_size: int,
    max_windows: int | None,
    device: str,
    latency: bool,
    shuffle_seed: int,
) -> list[dict[str, Any]]:
    """The records of the cells with windows of ``split``, each with the mean metrics of
    its member runs (and theirs per seed) and, on the CPU, the first member's latency."""
    results = []
    latency_cache: dict[int, float] = {}
    for (_, _, shuffled, s, mode), (_, rec, members, _) in chosen.items():
        sensors = SensorModel.from_mapping(rec["sensors"]) if mode == "sensors" else None
        ws: Any = ds.windows(split, size_cm=s, observation_mode=mode, sensors=sensors)
        if len(ws) == 0:
            continue
        if shuffled:
            ws = ShuffledActions(ws, seed=shuffle_seed)
        per_seed = []
        for model in members:
            model.to(device)
            per_seed.append(
                evaluate_rollouts(
                    model,
                    ws,
                    ds.stats.z_std,
                    batch_size=batch_size,
                    max_windows=max_windows,
                    device=device,
                )
            )
        rec["metrics"] = {k: float(np.mean([m[k] for m in per_seed])) for k in per_seed[0]}
        if len(per_seed) > 1:
            rec["metrics_per_seed"] = per_seed
        model = members[0]
        if latency and device == "cpu":
            if id(model) not in latency_cache:
                latency_cache[id(model)] = benchmark_latency(model)
            rec["latency_ms_8x32"] = latency_cache[id(model)]
        results.append(rec)
    return results


def _setting(cfg: dict[str, Any]) -> dict[str, Any]:
    """What a run's config says of its model and training, less the seed (and the dataset
    path: the standardisation statistics are checked against the dataset instead; and the
    loss's channel scale and the model's delta scale, measured on the training windows, which
    a debug run draws by seed)."""
    model = {k: v for k, v in (cfg.get("model") or {}).items() if k != "delta_scale"}
    train = {k: v for k, v in (cfg.get("train") or {}).items() if k not in RESUME_FREE}
    train.pop("seed", None)
    extra = {**RESUME_LEGACY, **(cfg.get("extra") or {})}
    extra = {k: v for k, v in extra.items() if k not in ("seed", "data", "channel_scale")}
    return {"model": model, "train": train, "extra": extra}


def eval_wm(
    runs: Sequence[str | Path],
    data: str | Path,
    out: str | Path,
    *,
    split: str = "test",
    batch_size: int = 256,
    max_windows: int | None = None,
    device: str = "cpu",
    latency: bool = True,
) -> dict[str, Path]:
    """``rmi eval-wm``: evaluate the runs (:func:`evaluate_runs`) and write the tables into
    ``out`` (:func:`write_tables`); returns the written files by name. Runs that cannot be
    evaluated together raise :class:`~rmi_learn.errors.InputError`."""
    with input_errors(ValueError):
        ds = load_dataset(data)
        entries = _entries(list(runs), ds.stats)
        results = _evaluate_entries(
            entries, ds, data, split, batch_size, max_windows, device, latency, SHUFFLE_SEED
        )
    paths = write_tables(results, out)
    if any(r.get("observation_mode") == "sensors" for r in results):
        from rmi_learn.world_models.sensor_table import sensor_records, write_sensor_table

        with input_errors(ValueError):
            records = sensor_records(
                [(m, cfg) for m, cfg, _ in entries], ds, split, batch_size, max_windows
            )
        paths.update(write_sensor_table(records, out))
    return paths
