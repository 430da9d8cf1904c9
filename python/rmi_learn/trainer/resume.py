"""Whether a run directory may be resumed with the settings of this call: the model
configuration, the training settings (less :data:`RESUME_FREE`) and the named extra settings
must repeat the first call's."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rmi_learn.trainer.config import TrainConfig
from rmi_learn.trainer.run_files import read_config

#: TrainConfig fields that may differ between the first call and a resume.
RESUME_FREE = {"progress", "device", "log_every"}


def check_resume_config(
    out_dir: Path,
    new: dict[str, Any],
    resume_fixed: Sequence[str],
    resume_legacy: dict[str, Any],
) -> None:
    """Raise ValueError unless ``new`` (the ``config.json`` content this call would write)
    agrees with the one in ``out_dir``: the same model, the same training settings and the
    same values of the ``resume_fixed`` extra settings (``resume_legacy`` gives those a first
    call did not record)."""
    old = read_config(out_dir)
    defaults = TrainConfig().to_json()
    old_train = {**defaults, **(old.get("train") or {})}
    old_t = {k: v for k, v in old_train.items() if k not in RESUME_FREE}
    new_t = {k: v for k, v in new["train"].items() if k not in RESUME_FREE}
    if old_t != json.loads(json.dumps(new_t)):
        diff = sorted(k for k in set(old_t) | set(new_t) if old_t.get(k) != new_t.get(k))
        raise ValueError(f"cannot resume {out_dir}: training settings differ in {diff}")
    old_extra = {**resume_legacy, **(old.get("extra") or {})}
    for key in resume_fixed:
        if key in old_extra and old_extra[key] != new["extra"][key]:
            raise ValueError(
                f"cannot resume {out_dir}: {key} was {old_extra[key]!r} in the first "
                f"call, now {new['extra'][key]!r}"
            )
    # After the settings a user gives: a model measured on other data (its delta scale)
    # differs because of them, and the setting names the cause.
    if old.get("model") != json.loads(json.dumps(new["model"])):
        raise ValueError(
            f"cannot resume {out_dir}: the model configuration differs "
            f"({old.get('model')} vs {new['model']})"
        )
