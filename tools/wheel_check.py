"""Print what a build of ``rmi_sph`` computes, so that two builds can be compared line by line
(``make wheel-check``): the hash of a small trial's final state and of an environment
episode's observations. With ``--installed``, first check that the module comes from an
installed wheel (not the source tree) and that torch is absent, as on a simulator-only
install."""

from __future__ import annotations

import argparse
import hashlib
import importlib.util

import numpy as np

import rmi_sph
from rmi_learn.sim.env import SpongeSqueezeEnv

#: The 8 cm sponge at r = 1 cm with short phases: a trial of a few seconds.
CONFIG = rmi_sph.trial_config(
    8, 0.8, 20.0, 150.0, 0.01, dt=2e-3, settle_time=0.05, ramp_time=0.1, hold_time=0.1,
    wait_time=0.05, squeeze_ramp_time=0.1, squeeze_hold_time=0.1,
    material={"permeability": 1e-9},
)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--installed", action="store_true", help="require an installed wheel")
    args = parser.parse_args()
    if args.installed:
        assert "site-packages" in (rmi_sph.__file__ or ""), rmi_sph.__file__
        assert importlib.util.find_spec("torch") is None, "torch is installed"
    trial = rmi_sph.Trial(CONFIG, num_threads=1)
    while not trial.finished:
        trial.step()
    print("trial", hashlib.sha256(bytes(trial.get_state())).hexdigest())
    env = SpongeSqueezeEnv(CONFIG, goal=0.5)
    obs, _ = env.reset(seed=3)
    seen = [obs]
    for force in (200.0, 100.0, 300.0):
        seen.append(env.step(np.array([force], np.float32))[0])
    print("env", hashlib.sha256(np.stack(seen).tobytes()).hexdigest())


if __name__ == "__main__":
    main()
