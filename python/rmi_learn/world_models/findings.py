"""The paper's qualitative world-model findings checked on an evaluation's records: whether
the action-conditioned model forecasts retained water better than persistence, than the same
network without the command, and than itself given another run's commands (paper Sec. V,
Table II). Each comparison is per sponge size on the test split, with the spread over the
training seeds where a cell holds several runs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from rmi_learn.data.schema import SPONGE_SIZES_CM
from rmi_learn.world_models.horizons import MAIN_STEP

#: (finding, the row that should be lower, the row it is compared with): record keys.
COMPARISONS: tuple[tuple[str, dict[str, Any], dict[str, Any]], ...] = (
    (
        "AC-GRU-WM below the Baseline (persistence)",
        {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False},
        {"kind": "baseline"},
    ),
    (
        "AC-GRU-WM below State-GRU-WM (the command helps)",
        {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False},
        {"kind": "state-gru", "state_groups": "ALL", "shuffled": False},
    ),
    (
        "AC-GRU-WM below itself with shuffled commands",
        {"kind": "ac-gru", "state_groups": "ALL", "shuffled": False},
        {"kind": "ac-gru", "state_groups": "ALL", "shuffled": True},
    ),
)


def lookup(results: list[dict[str, Any]], **key: Any) -> dict[str, Any] | None:
    """The first record of ``results`` whose fields equal ``key`` (e.g. ``size_cm=8,
    kind="baseline"``), or None. A record's observation mode is ``privileged`` unless it
    says otherwise, and so is the key's: a model that reads the sensors is found only by
    asking for it."""
    key = {"observation_mode": "privileged", **key}
    for r in results:
        rec = {"observation_mode": "privileged", **r}
        if all(rec.get(k) == v for k, v in key.items()):
            return r
    return None


@dataclass(frozen=True)
class Finding:
    """One comparison on one sponge size: water MAE (g) at the step compared of the row that
    should be lower (``ours``) and of the row it is compared with (``other``), each a mean
    over its training seeds with every seed's value."""

    finding: str
    size_cm: int
    ours: float
    other: float
    ours_per_seed: tuple[float, ...]
    other_per_seed: tuple[float, ...]

    @property
    def holds(self) -> bool:
        """The mean of ``ours`` is below that of ``other``."""
        return self.ours < self.other

    @property
    def seeds_agree(self) -> bool:
        """Every training seed of ``ours`` is below every one of ``other``."""
        return max(self.ours_per_seed) < min(self.other_per_seed)


def _water(rec: dict[str, Any], step: int) -> tuple[float, tuple[float, ...]]:
    name = f"water_mae_g@{step}"
    per_seed = [m[name] for m in rec.get("metrics_per_seed", [rec["metrics"]])]
    return float(rec["metrics"][name]), tuple(float(v) for v in per_seed)


def paper_findings(
    results: list[dict[str, Any]], step: int = MAIN_STEP, sizes: Sequence[int] = SPONGE_SIZES_CM
) -> list[Finding]:
    """The comparisons of :data:`COMPARISONS` that both rows of ``results`` (the records of
    :func:`rmi_learn.world_models.evaluation.evaluate_runs`) have for a size, at ``step``."""
    out = []
    for text, ours_key, other_key in COMPARISONS:
        for s in sizes:
            ours = lookup(results, size_cm=s, **ours_key)
            other = lookup(results, size_cm=s, **other_key)
            name = f"water_mae_g@{step}"
            if ours is None or other is None:
                continue
            if name not in ours["metrics"] or name not in other["metrics"]:
                continue
            (o, o_seeds), (r, r_seeds) = _water(ours, step), _water(other, step)
            out.append(Finding(text, s, o, r, o_seeds, r_seeds))
    return out
