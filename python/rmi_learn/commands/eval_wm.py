"""``rmi eval-wm``: evaluate trained world models on the test split and write the paper's
Table II (causal prediction, with the shuffled-action row and W_T), Table III-diagnostic
(Linear-ARX and AC-MLP-WM with and without shuffled chunks) and Table IV (state-group
ablation) as Markdown and JSON, at 0.64 s and also 0.16/0.32/1.28 s, per sponge size.

    rmi eval-wm --runs RUN [RUN ...] --data DATASET --out DIR [--split test]

Each run is evaluated on the sizes it was trained on (its ``--size``, or every size). A run
trained with ``--shuffle-actions`` is evaluated with shuffled test chunks as well. The
Baseline needs no run: it is always evaluated. Errors are in physical units (g, N). Runs
of one model that differ only in ``--seed`` fill one cell with the mean of their errors;
the tables then list each run's 0.64 s water error below them.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rmi_learn.commands import InputError
from rmi_learn.commands.argtypes import count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi eval-wm``."""
    parser.add_argument(
        "--runs",
        nargs="+",
        required=True,
        metavar="DIR",
        help="run directories written by `rmi train-wm`",
    )
    parser.add_argument("--data", required=True, metavar="DIR", help="built dataset directory")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for the tables")
    parser.add_argument("--split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--batch-size", type=count(1), default=256)
    parser.add_argument(
        "--max-windows",
        type=count(1),
        default=None,
        help="evaluate at most this many evenly spaced windows per size",
    )
    parser.add_argument("--threads", type=count(1), default=1, help="torch CPU threads")
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--no-latency", action="store_true", help="skip the 8 chunks x 32 steps latency benchmark"
    )


def run(args: argparse.Namespace) -> int:
    """Evaluate and write the tables; 0 on success, 2 on a user error."""
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        results = evaluate_runs(
            args.runs,
            args.data,
            split=args.split,
            batch_size=args.batch_size,
            max_windows=args.max_windows,
            device=args.device,
            latency=not args.no_latency,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    from rmi_learn.wm_eval import write_tables

    paths = write_tables(results, args.out)
    print((Path(args.out) / "table2.md").read_text(encoding="utf-8").split("## Horizon")[1])
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0


def evaluate_runs(
    runs: list[str] | list[Path],
    data: str | Path,
    *,
    split: str = "test",
    batch_size: int = 256,
    max_windows: int | None = None,
    device: str = "cpu",
    latency: bool = True,
    shuffle_seed: int = 12345,
) -> list[dict[str, Any]]:
    """One record per (run, sponge size): ``method``, ``kind``, ``state_groups``,
    ``shuffled``, ``size_cm``, ``trained_size_cm``, ``run_dir``, ``split``, ``data`` (the
    dataset directory), ``split_seed`` (its ``rmi dataset --seed``), ``params``,
    ``latency_ms_8x32`` and ``metrics`` (see :class:`rmi_learn.wm_eval.RolloutMetrics`).

    When several runs give the same (model, state groups, shuffle, size) cell, a run trained
    on that size alone wins over one trained on every size. Equally specific runs that differ
    only in their training seed are replicates: the cell's ``metrics`` are the mean of theirs
    (``metrics_per_seed``, ``seeds`` and ``run_dirs`` list them); equally specific runs that
    differ in anything else are an error. The Baseline is added for every size when no
    baseline run is given.
    """
    import numpy as np

    from rmi_learn.dataset import load_dataset
    from rmi_learn.models import DISPLAY_NAMES, BaselineWM, load
    from rmi_learn.models.common import ShuffledActions
    from rmi_learn.training import count_parameters
    from rmi_learn.wm_eval import benchmark_latency, evaluate_rollouts

    ds = load_dataset(data)
    stats = ds.stats
    sizes = sorted(int(s) for s in ds.runs["size_cm"].unique().to_list())
    chosen: dict[tuple[str, str, bool, int], tuple[bool, dict[str, Any], list[Any], Any]] = {}
    entries: list[tuple[Any, dict[str, Any], str]] = []
    for run_dir in runs:
        model, cfg = load(run_dir)
        entries.append((model, cfg, str(run_dir)))
    if not any(cfg["model"]["kind"] == "baseline" for _, cfg, _ in entries):
        entries.append((BaselineWM().eval(), {"model": {"kind": "baseline"}, "extra": {}}, ""))

    for model, cfg, run_dir in entries:
        extra = cfg.get("extra") or {}
        trained_stats = extra.get("stats")
        if trained_stats is not None:
            same = np.allclose(trained_stats["z_mean"], stats.z_mean) and np.allclose(
                trained_stats["z_std"], stats.z_std
            )
            if not same:
                raise ValueError(
                    f"{run_dir} was trained with other standardisation statistics than {data}"
                )
        kind = cfg["model"]["kind"]
        groups = cfg["model"].get("state_groups", "ALL")
        shuffled = bool(extra.get("shuffle_actions", False))
        trained_size = extra.get("size_cm")
        for s in sizes if trained_size is None else [int(trained_size)]:
            key = (kind, groups, shuffled, s)
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
                "method": DISPLAY_NAMES[kind] + (", shuffled A" if shuffled else ""),
                "kind": kind,
                "state_groups": groups,
                "shuffled": shuffled,
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

    results = []
    latency_cache: dict[int, float] = {}
    for (_, _, shuffled, s), (_, rec, members, _) in chosen.items():
        ws: Any = ds.windows(split, size_cm=s)
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
                    stats.z_std,
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
    results.sort(key=lambda r: (r["size_cm"], r["kind"], r["state_groups"], r["shuffled"]))
    return results


def _setting(cfg: dict[str, Any]) -> dict[str, Any]:
    """What a run's config says of its model and training, less the seed (and the dataset
    path: the standardisation statistics are checked against the dataset instead; and the
    loss's channel scale, measured on the training windows, which a debug run draws by seed)."""
    from rmi_learn.commands.train_wm import RESUME_LEGACY
    from rmi_learn.training import RESUME_FREE

    train = {k: v for k, v in (cfg.get("train") or {}).items() if k not in RESUME_FREE}
    train.pop("seed", None)
    extra = {**RESUME_LEGACY, **(cfg.get("extra") or {})}
    extra = {k: v for k, v in extra.items() if k not in ("seed", "data", "channel_scale")}
    return {"model": cfg.get("model"), "train": train, "extra": extra}
