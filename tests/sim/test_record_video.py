"""gymnasium's RecordVideo writes the environment's rendered episodes through moviepy (the
``video`` extra)."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import rmi_learn.sim.env  # noqa: F401 (registers the ids)
from tiny_trial import tiny_config

pytest.importorskip("moviepy")


def test_record_video_writes_an_mp4_of_each_recorded_episode(tmp_path: Path) -> None:
    env = gym.make(
        "rmi/SpongeSqueeze-v0",
        config=tiny_config(),
        goal=0.5,
        render_mode="rgb_array",
        render_shape=(96, 128),
        max_episode_steps=6,
    )
    videos_dir = tmp_path / "videos"  # a new folder: RecordVideo warns about an existing one
    env = gym.wrappers.RecordVideo(env, str(videos_dir), episode_trigger=lambda k: True)
    for seed in (0, 1):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, term, trunc, _ = env.step(np.array([30.0], np.float32))
            done = term or trunc
    env.close()
    videos = sorted(videos_dir.glob("*.mp4"))
    assert len(videos) == 2 and all(v.stat().st_size > 1000 for v in videos)
