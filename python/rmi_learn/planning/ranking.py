"""The ranking stage (``rmi rank``): world-model ranking of policy samples (paper Sec. IV.C)
over a dataset split, and the tables it gives (Tables III, V and S1).

For every window, K = 8 chunks are drawn from the policy in one batch and ranked by the
causal world model W_T with the paper's cost (:mod:`rmi_learn.planning.cost`,
:class:`~rmi_learn.planning.planner.Planner`). :func:`rank` runs the planner over every
window of a dataset split (per sponge size; the goal g is the collected M_L at t + 32) for
each given policy and writes to its output directory:

- ``table3_ranking.{md,json}``: the scorer's predicted terminal water error |M_hat - g| in
  grams for the original chunk, the first sample and the selected sample, per size and
  objective. The paper's scorer is W_T; another world model run given as the scorer names
  the rows and titles instead (``scorer_name`` in the JSON).
- ``table5_imitation.{md,json}``: force MAE of the first sample against the original chunk and
  its mean absolute force change per step (smooth_F), in N.
- ``tableS1_cost.{md,json}``: combined predicted cost J.
- ``chunks_<objective>.npz``: per window the run, anchor row, goal, the original, first and
  selected chunks in physical units (N), the selected index and every sample's J, for
  closed-loop execution.

All errors are the scorer's own predictions (biased toward the scorer that selected the
chunk); closed-loop execution in the simulator gives the real error.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from rmi_learn import world_models as models
from rmi_learn.data.dataset import load_dataset
from rmi_learn.data.schema import FORCE_LIMIT_N, SPONGE_SIZES_CM
from rmi_learn.errors import InputError
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.scorers import world_model_scorer
from rmi_learn.planning.standardiser import Standardiser, stats_close
from rmi_learn.policies.checkpoint import goal_from_batch, load_policy

#: Sponge sizes of the tables (cm) and the tables' names of the objectives.
SIZES: tuple[int, ...] = SPONGE_SIZES_CM
LABELS = {"diffusion": "Diffusion policy", "flow": "Flow matching"}


def scorer_name(kind: str) -> str:
    """The tables' name of a scoring world model of ``kind``: the paper's ``W_T`` for the
    Transformer, else the model's table name (``AC-GRU-WM``, ``Linear-ARX``, ...)."""
    return "W_T" if kind == "transformer" else models.DISPLAY_NAMES.get(kind, kind)


#: Per size, the per-window arrays of one policy's ranking (costs and force measures).
PerSize = dict[int, dict[str, np.ndarray]]


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def _markdown(title: str, header: list[str], rows: list[list[str]]) -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join(["---"] + [":---:"] * (len(header) - 1)) + "|")
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _write(out: Path, stem: str, md: str, payload: dict[str, Any]) -> None:
    (out / f"{stem}.md").write_text(md, encoding="utf-8")
    (out / f"{stem}.json").write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")


def _load_inputs(
    data: str | Path, wm: str | Path, policies: Mapping[str, Any], weights: str, device: str
) -> tuple[Any, Any, dict[str, Any], dict[str, Any]]:
    """The dataset, the world model and its config, and the loaded policies; a world model
    whose horizon does not fit a policy's chunks is an input error."""
    # Every input is loaded and checked before --out exists: a wrong directory, model kind
    # or horizon is a one-line error, not a traceback after half the work.
    try:
        ds = load_dataset(data)
        wm_net, wm_cfg = models.load(wm, observation_mode="privileged")
        loaded = {n: load_policy(p, weights, device) for n, p in policies.items()}
        for name, (net, _, _) in loaded.items():
            h = net.config.horizon
            try:
                wm_net.check_horizon_length(h)
            except ValueError:
                fixed, longest = wm_net.fixed_horizon, wm_net.max_horizon
                takes = f"exactly {fixed}" if fixed is not None else f"at most {longest}"
                raise ValueError(
                    f"--wm {wm}: the {wm_net.kind} world model scores chunks of {takes} "
                    f"steps, the --{name} policy's have {h}"
                ) from None
    except ValueError as exc:
        raise InputError(exc) from exc
    return ds, wm_net, wm_cfg, loaded


def _standardiser(ds: Any, wm_cfg: Mapping[str, Any], device: str) -> Standardiser:
    """The dataset's standardisation on ``device``, checked against the world model's."""
    wm_stats = (wm_cfg.get("extra") or {}).get("stats")
    if wm_stats is not None and not stats_close(ds.stats, wm_stats):
        raise InputError("--wm was trained with other standardisation statistics")
    std = Standardiser.from_stats(ds.stats)
    return Standardiser(*(x.to(device) for x in (std.z_mean, std.z_std, std.u_mean, std.u_std)))


def _window_index(n: int, max_windows: int) -> np.ndarray:
    """All ``n`` windows, or ``max_windows`` evenly spaced ones."""
    idx = np.arange(n)
    if max_windows and n > max_windows:
        idx = np.unique(np.linspace(0, n - 1, max_windows).round()).astype(np.int64)
    return idx


def _rank_batch(
    planner: Planner,
    b: dict[str, torch.Tensor],
    gen: torch.Generator,
    std: Standardiser,
    size: int,
    acc: dict[str, list[np.ndarray]],
    chunks: dict[str, list[np.ndarray]],
) -> None:
    """Plan one batch of windows and append its measures to ``acc`` and its chunks to
    ``chunks``."""
    g_std, _ = goal_from_batch(b)
    res = planner.plan(b["hist"], b["hist_mask"], g_std, b["water_now"], b["actions"], gen)
    assert res.original is not None
    first, sel, orig = res.first, res.selected, res.original
    cols: dict[str, torch.Tensor] = {
        "orig_JM": res.original_costs["J_M"],
        "orig_J": res.original_costs["J"],
        "first_JM": res.first_costs()["J_M"],
        "first_J": res.first_costs()["J"],
        "sel_JM": res.selected_costs()["J_M"],
        "sel_J": res.selected_costs()["J"],
        "mae_F": (first[..., 0] - orig[..., 0]).abs().mean(-1),
        "smooth_F": first[..., 0].diff(dim=-1).abs().mean(-1),
        "orig_smooth_F": orig[..., 0].diff(dim=-1).abs().mean(-1),
        "sel_mae_F": (sel[..., 0] - orig[..., 0]).abs().mean(-1),
    }
    for key, v in cols.items():
        acc.setdefault(key, []).append(v.cpu().numpy())
    water_now_kg = std.water_to_kg(b["water_now"])
    for key, v in {
        "size_cm": torch.full_like(res.goal_kg, float(size)),
        "run": b["run"],
        "t": b["t"],
        "goal_kg": res.goal_kg,
        "water_now_kg": water_now_kg,
        "original": orig,
        "first": first,
        "selected": sel,
        "index": res.index,
        "J_samples": res.costs["J"],
        "J_M_samples": res.costs["J_M"],
    }.items():
        chunks.setdefault(key, []).append(v.cpu().numpy())


def _rank_policy(
    planner: Planner,
    ds: Any,
    split: str,
    sizes: Sequence[int],
    history: int,
    max_windows: int,
    batch_size: int,
    seed: int,
    device: str,
    n_windows: dict[int, int],
) -> tuple[PerSize, dict[str, list[np.ndarray]]]:
    """Rank one policy's samples over every window (or ``max_windows`` per size) of
    ``split``: the per-size measures and the chunks of every window; ``n_windows`` gets the
    windows ranked per size."""
    per: PerSize = {}
    chunks: dict[str, list[np.ndarray]] = {}
    horizon = planner.policy.config.horizon
    for size in sizes:
        ws = ds.windows(split, size, history=history, horizon=horizon)
        idx = _window_index(len(ws), max_windows)
        n_windows[size] = int(idx.size)
        gen = torch.Generator().manual_seed(seed * 1000 + size)
        acc: dict[str, list[np.ndarray]] = {}
        for start in range(0, idx.size, batch_size):
            b = ws.batch(idx[start : start + batch_size])
            b = {n: v.to(device) for n, v in b.items()}
            _rank_batch(planner, b, gen, planner.std, size, acc, chunks)
        per[size] = {key: np.concatenate(v) for key, v in acc.items()}
    return per, chunks


def _write_chunks(
    out: Path, objective: str, chunks: Mapping[str, list[np.ndarray]], ds: Any
) -> None:
    """``chunks_<objective>.npz`` for closed-loop execution."""
    arrays = {key: np.concatenate(v) for key, v in chunks.items()}
    arrays["size_cm"] = arrays["size_cm"].astype(np.int64)
    arrays["run_id"] = np.asarray([ds.run_ids[int(r)] for r in arrays["run"]])
    np.savez_compressed(out / f"chunks_{objective}.npz", **arrays)  # type: ignore[arg-type]


class _Tables:
    """Tables III, V and S1 from the per-size measures of every policy."""

    def __init__(
        self, out: Path, per: Mapping[str, PerSize], policies: Sequence[str], common: dict
    ) -> None:
        self.out, self.per, self.policies, self.common = out, per, list(policies), common
        self.scorer = str(common["scorer_name"])
        self.first_obj = self.policies[0]
        self.header = ["Method"] + [f"{s} cm" for s in SIZES]

    def mean(self, obj: str, size: int, key: str) -> float | None:
        d = self.per.get(obj, {}).get(size)
        return None if d is None or d[key].size == 0 else float(d[key].mean())

    def row(self, label: str, obj: str, key: str) -> tuple[list[str], dict[str, Any]]:
        vals = {str(s): self.mean(obj, s, key) for s in SIZES}
        return [label] + [_fmt(vals[str(s)]) for s in SIZES], {"method": label, **vals}

    def source_rows(self, metric: str) -> tuple[list[list[str]], list[dict[str, Any]]]:
        """Rows of one metric for the original action, each first sample and each selection
        (Tables III and S1 share this layout)."""
        sources = [("Original controller action", self.first_obj, f"orig_{metric}")] + [
            item
            for o in self.policies
            for item in (
                (f"{LABELS[o]}, first sample", o, f"first_{metric}"),
                (f"{LABELS[o]} + {self.scorer}", o, f"sel_{metric}"),
            )
        ]
        built = [self.row(label, obj, key) for label, obj, key in sources]
        return [m for m, _ in built], [j for _, j in built]

    def table3(self, k: int, split: str) -> None:
        md_rows, js_rows = self.source_rows("JM")
        _write(
            self.out,
            "table3_ranking",
            _markdown(
                f"Table III. {self.scorer}-predicted terminal water error |M_hat - g| (g), "
                f"K = {k}, {split} split",
                self.header,
                md_rows,
            ),
            {"table": "III", "unit": "g", "rows": js_rows, **self.common},
        )

    def table5(self) -> None:
        quantities = ("MAE_F", "smooth_F")
        header5 = ["Method"] + [f"{s} cm {q}" for s in SIZES for q in ("MAE_F (N)", "smooth_F (N)")]
        md5, js5 = [], []
        for o in self.policies:
            vals = {
                str(s): {"MAE_F": self.mean(o, s, "mae_F"), "smooth_F": self.mean(o, s, "smooth_F")}
                for s in SIZES
            }
            md5.append([LABELS[o]] + [_fmt(vals[str(s)][q]) for s in SIZES for q in quantities])
            js5.append({"method": LABELS[o], **vals})
        ref = {
            str(s): {"MAE_F": 0.0, "smooth_F": self.mean(self.first_obj, s, "orig_smooth_F")}
            for s in SIZES
        }
        md5.append(
            ["Original controller action (reference)"]
            + [_fmt(ref[str(s)][q]) if q == "smooth_F" else "-" for s in SIZES for q in quantities]
        )
        js5.append({"method": "Original controller action (reference)", **ref})
        _write(
            self.out,
            "table5_imitation",
            _markdown(
                "Table V. Force MAE of one policy sample against the collected command and its "
                "mean absolute force change per step (N)",
                header5,
                md5,
            ),
            {"table": "V", "unit": "N", "rows": js5, **self.common},
        )

    def table_s1(self) -> None:
        mds, jss = self.source_rows("J")
        _write(
            self.out,
            "tableS1_cost",
            _markdown(
                "Table S1. Combined predicted cost J = J_M + 1e-4 J_F + 0.05 J_S + 0.1 J_U",
                self.header,
                mds,
            ),
            {"table": "S1", "unit": "-", "rows": jss, **self.common},
        )


def rank(
    data: str | Path,
    wm: str | Path,
    out: str | Path,
    *,
    diffusion: str | Path | None = None,
    flow: str | Path | None = None,
    split: str = "test",
    k: int = 8,
    max_windows: int = 0,
    batch_size: int = 64,
    seed: int = 0,
    force_limit: float = FORCE_LIMIT_N,
    weights: str = "model.ema",
    device: str = "cpu",
) -> dict[str, Any]:
    """``rmi rank``: rank ``k`` samples of each given policy run (``diffusion``, ``flow``)
    per window of ``split`` with the world model run ``wm`` and write Tables III, V, S1 and
    the ranked chunks into ``out`` (see the module docstring). ``max_windows``: per size,
    an evenly spaced subset (0: all); ``force_limit`` (N) clips the samples; ``weights``
    names the policy weights file stem. Returns ``{"out", "n_windows", "seconds"}``.

    Every input is checked before ``out`` is created: a missing policy, a world model whose
    horizon does not fit the policies' chunks or statistics that differ from the dataset's
    raise :class:`~rmi_learn.errors.InputError`.
    """
    out = Path(out)
    policies = {n: p for n, p in (("diffusion", diffusion), ("flow", flow)) if p}
    if not policies:
        raise InputError("give --diffusion and/or --flow")
    ds, wm_net, wm_cfg, loaded = _load_inputs(data, wm, policies, weights, device)
    wm_net = wm_net.to(device)
    std = _standardiser(ds, wm_cfg, device)
    scorer = world_model_scorer(wm_net)
    out.mkdir(parents=True, exist_ok=True)
    sizes = [s for s in SIZES if len(ds.split_runs(split, s)) > 0]

    per: dict[str, PerSize] = {}
    n_windows: dict[int, int] = {}
    timing: dict[str, float] = {}
    for obj_name, (net, objective, pcfg) in loaded.items():
        planner = Planner(net, objective, scorer, std, k=k, force_limit=force_limit)
        t0 = time.perf_counter()
        per[obj_name], chunks = _rank_policy(
            planner, ds, split, sizes, int(pcfg["model"]["history"]), max_windows,
            batch_size, seed, device, n_windows,
        )  # fmt: skip
        timing[obj_name] = time.perf_counter() - t0
        _write_chunks(out, obj_name, chunks, ds)

    name = scorer_name(str(wm_cfg["model"]["kind"]))
    common = {
        "split": split,
        "k": k,
        "n_windows": {str(s): n_windows.get(s, 0) for s in SIZES},
        "scorer": str(wm),
        "scorer_name": name,
        "policies": {n: str(v) for n, v in policies.items()},
        "note": f"predicted by the scorer {name} that selects the chunk (biased toward it)",
    }
    tables = _Tables(out, per, list(policies), common)
    tables.table3(k, split)
    tables.table5()
    tables.table_s1()
    return {"out": str(out), "n_windows": common["n_windows"], "seconds": timing}


__all__ = ["LABELS", "SIZES", "rank", "scorer_name"]
