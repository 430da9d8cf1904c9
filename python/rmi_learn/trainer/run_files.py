"""The files of a run directory by name, its ``config.json`` read back (:func:`read_config`)
and JSON written atomically (:func:`write_json`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from rmi_learn.data.runs import json_kind
from rmi_learn.errors import InputError

STATE_FILE = "train_state.pt"
CONFIG_FILE = "config.json"
SUMMARY_FILE = "summary.json"
BEST_WEIGHTS = "model.safetensors"
LAST_WEIGHTS = "last.safetensors"


def read_config(out_dir: str | Path) -> dict[str, Any]:
    """The ``config.json`` of a run directory (FileNotFoundError naming the directory when
    it is not one)."""
    path = Path(out_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{out_dir} is not a training run directory (no {CONFIG_FILE})")
    config = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(config, dict) or not isinstance(config.get("model"), dict):
        got = json_kind(config.get("model") if isinstance(config, dict) else config)
        raise InputError(
            f"{path}: a training run's config is a JSON object whose 'model' is an object, "
            f"got {got}"
        )
    return config


def write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON with sorted keys (atomically: a temporary file, then
    rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)
