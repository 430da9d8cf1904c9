"""Run by an interpreter that has ``lerobot`` installed (tests/data/test_export_lerobot_v30.py):
open an export with ``LeRobotDataset``, read one item with ``delta_timestamps``, iterate one
DataLoader epoch, and print what it saw as one JSON line."""

import json
import sys

import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

root = sys.argv[1]
deltas = {"observation.state": [-0.04, -0.02, 0.0], "action": [0.0, 0.02, 0.04, 0.06]}
ds = LeRobotDataset("rmi/export", root=root, delta_timestamps=deltas)
item = ds[len(ds) // 2]
loader = torch.utils.data.DataLoader(ds, batch_size=64, shuffle=True, num_workers=0)
seen = sum(batch["observation.state"].shape[0] for batch in loader)
print(
    json.dumps(
        {
            "frames": len(ds),
            "episodes": ds.num_episodes,
            "epoch_frames": int(seen),
            "state": list(item["observation.state"].shape),
            "action": list(item["action"].shape),
            "task": item["task"],
            "action_mean": [float(v) for v in ds.meta.stats["action"]["mean"]],
        }
    )
)
