"""The world models the pipeline trains: one :class:`ModelRun` per run directory of
``OUT/wm``, for the main tables, the chunk scorers and the ablations."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from rmi_learn.pipeline.calls import Arg, keyword


@dataclass(frozen=True)
class ModelRun:
    """One world model a stage trains: the model, the ablation settings of its run, the
    fixed horizon of a lookahead model trained on windows of that length (None: its
    default), and for Linear-ARX whether each step is fitted on the setpoints up to it only
    (``causal``)."""

    model: str
    shuffle_actions: bool = False
    state_groups: str = "ALL"
    horizon: int | None = None
    causal: bool = False
    #: The training seed of a replicate (None: the preset's ``world_models.seed``).
    seed: int | None = None

    def args(self) -> list[Arg]:
        """The arguments of ``rmi train-wm`` (:func:`rmi_learn.world_models.training.train`)
        that set this run."""
        groups = ["--state-groups", self.state_groups] if self.state_groups != "ALL" else []
        model_args = self.model_args()
        spelled = [
            word
            for key, value in (model_args or {}).items()
            for word in ("--model-arg", f"{key}={json.dumps(value)}")
        ]
        seed = [] if self.seed is None else [keyword("seed", self.seed)]
        return [
            keyword("model", self.model, ["--model", self.model]),
            keyword("shuffle_actions", self.shuffle_actions),
            keyword("state_groups", self.state_groups, groups),
            keyword("model_args", model_args, spelled),
            *seed,
        ]

    def model_args(self) -> dict[str, Any] | None:
        """Constructor overrides of this run."""
        args: dict[str, Any] = {"horizon": self.horizon} if self.horizon is not None else {}
        args.update({"causal": True} if self.causal else {})
        return args or None


#: The world models of Tables II and the lookahead diagnostic, by run directory name.
MAIN_MODELS: dict[str, ModelRun] = {
    name: ModelRun(name) for name in ("state-gru", "ac-gru", "arx", "ac-mlp", "transformer")
}
#: Scorers of the policies' 32-step chunks for ranking (``rmi control-bench``): Linear-ARX
#: fitted on 32-step windows, whose forecasts order the executed outcomes of policy samples
#: best among the trained models, and its causal fit, whose forecasts inside the chunk do
#: not lean on later setpoints, for re-planning toward a goal time inside the chunk
#: (docs/control.md).
SCORER_MODELS: dict[str, ModelRun] = {
    "arx-32": ModelRun("arx", horizon=32),
    "arx-32c": ModelRun("arx", horizon=32, causal=True),
}
#: Ablations: shuffled action chunks (Table II last row, diagnostic) and state groups (Table IV).
ABLATION_MODELS: dict[str, ModelRun] = {
    "ac-gru-shuffled": ModelRun("ac-gru", shuffle_actions=True),
    "arx-shuffled": ModelRun("arx", shuffle_actions=True),
    "ac-mlp-shuffled": ModelRun("ac-mlp", shuffle_actions=True),
    "ac-gru-LS": ModelRun("ac-gru", state_groups="LS"),
    "ac-gru-LS+G": ModelRun("ac-gru", state_groups="LS+G"),
    "ac-gru-LS+G+C": ModelRun("ac-gru", state_groups="LS+G+C"),
}

#: The learned models of Table II whose findings the report states (action conditioning
#: against persistence, against the same network without the command, against shuffled
#: commands): a preset's ``seeds`` trains each that many times.
REPLICATED: tuple[str, ...] = ("state-gru", "ac-gru", "ac-gru-shuffled")


def with_replicates(
    models: Mapping[str, ModelRun], seeds: int, first_seed: int
) -> dict[str, ModelRun]:
    """``models`` and, for each of :data:`REPLICATED` among them, ``seeds - 1`` more runs
    that differ only in the training seed (``first_seed + k``), in directories named
    ``NAME-seedK``; the evaluation averages the runs of one cell."""
    out = dict(models)
    for name in REPLICATED:
        if name in models:
            for k in range(1, seeds):
                run = replace(models[name], seed=first_seed + k)
                out[f"{name}-seed{first_seed + k}"] = run
    return out
