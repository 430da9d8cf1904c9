"""The binding under adversarial input: self-referencing and deep configs, special files,
huge integers, corrupt or foreign states, concurrent saves, and bit-identical continuation
through every way of saving a trial."""

from __future__ import annotations

import os
import pickle
import random
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

import rmi_sph
from rmi_sph import engine


def tiny(**overrides: object) -> dict:
    """The 8 cm sponge at r = 10 mm (about 230 particles)."""
    return rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=3, **overrides)


def run_python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    """Runs `code` in a fresh interpreter (a crash there fails the test, not the session)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=dict(os.environ, **env),
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_cyclic_deep_and_self_converting_configs_are_config_errors() -> None:
    proc = run_python(
        """
        import rmi_sph
        from rmi_sph import engine

        def deep(n):
            d = {}
            for _ in range(n):
                d = {"x": d}
            return d

        class Odd:
            def tolist(self):
                return Odd()

        l = []
        l.append(l)
        calls = [
            lambda: rmi_sph.validate_config({"size": l}),
            lambda: rmi_sph.validate_config({"material": deep(15000)}),
            lambda: rmi_sph.Trial({"gate": deep(15000)}),
            lambda: rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, material=deep(15000)),
            lambda: engine.Simulation({"scene": deep(15000)}),
            lambda: engine.validate_config({"fluid": deep(15000)}),
            lambda: rmi_sph.validate_config({"size": Odd()}),
        ]
        for call in calls:
            try:
                call()
            except rmi_sph.ConfigError as e:
                print("ConfigError", e.field, "|", e)
        """
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 7, proc.stdout + proc.stderr
    assert "contains itself" in lines[0] and "ConfigError size" in lines[0]
    for line in lines[1:]:
        assert "nesting deeper than 64" in line, line


@pytest.mark.parametrize(
    "load",
    [rmi_sph.validate_config, engine.validate_config, rmi_sph.Trial.load, engine.Simulation.load],
)
def test_special_files_are_refused_without_reading_them(load: object) -> None:
    with pytest.raises(OSError, match="/dev/zero"):
        load("/dev/zero")  # type: ignore[operator]


@pytest.mark.parametrize(
    ("patch", "field"),
    [
        ({"record_every": 2**32}, "record_every"),
        ({"controller": {"k_contact": 2**32}}, "controller.k_contact"),
        ({"gate": {"k_stable": 2**40}}, "gate.k_stable"),
        ({"pressure": {"min_iterations": 2**32}}, "pressure.min_iterations"),
        ({"wall_layer": "floating"}, "wall_layer"),
        ({"material": {"porosity": -1.0}}, "material.porosity"),
        ({"material": {"porosity": 1e300}}, "material.porosity"),
    ],
)
def test_config_errors_name_the_field(patch: dict, field: str) -> None:
    with pytest.raises(rmi_sph.ConfigError) as err:
        rmi_sph.validate_config(patch)
    assert err.value.field == field


def test_engine_config_errors_name_the_field() -> None:
    with pytest.raises(rmi_sph.ConfigError) as err:
        engine.validate_config({"pressure": {"max_iterations": 2**33}})
    assert err.value.field == "pressure.max_iterations"


def test_material_porosity_follows_porosity() -> None:
    cfg = rmi_sph.validate_config({"porosity": 0.4, "material": {"porosity": 0.7}})
    assert cfg["material"]["porosity"] == cfg["porosity"] == 0.4


def test_integer_arguments_of_any_size_are_range_checked() -> None:
    assert rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=2**63 - 1)["seed"] == 2**63 - 1
    for call, field in [
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=2**63), "seed"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=2**64), "seed"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=-(2**200)), "seed"),
        (lambda: rmi_sph.Trial(tiny(), num_threads=2**63), "num_threads"),
        (lambda: rmi_sph.run_trial(tiny(), record_every=2**64), "record_every"),
    ]:
        with pytest.raises(rmi_sph.ConfigError) as err:
            call()
        assert err.value.field == field
    t = rmi_sph.Trial(tiny(), num_threads=1)
    with pytest.raises(rmi_sph.ConfigError) as err:
        t.step(2**64)
    assert err.value.field == "n"


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda seed: rmi_sph.trial_config(8, 0.6, 20, 40, 0.01, seed=seed), "seed"),
        (lambda seed: rmi_sph.validate_config({"seed": seed}), "seed"),
        (lambda seed: rmi_sph.Trial({**tiny(), "seed": seed}, num_threads=1), "seed"),
        (
            lambda seed: rmi_sph.validate_config(
                {"controller": {"perturbation": {"enabled": True, "seed": seed}}}
            ),
            "controller.perturbation.seed",
        ),
        (lambda seed: engine.validate_config({"scene": {"seed": seed}}), "scene.seed"),
    ],
    ids=["trial_config", "validate_config", "Trial", "perturbation", "engine"],
)
def test_every_seed_is_in_one_range(make: object, field: str) -> None:
    assert rmi_sph.SEED_MAX == 2**63 - 1  # what run files can store (Int64)
    make(rmi_sph.SEED_MAX)  # type: ignore[operator]
    for seed in (rmi_sph.SEED_MAX + 1, 2**64 - 1):
        with pytest.raises(rmi_sph.ConfigError) as err:
            make(seed)  # type: ignore[operator]
        assert err.value.field == field
        assert err.value.expected == f"an integer in [0, {rmi_sph.SEED_MAX}]"
        assert "\n" not in str(err.value)


def test_invalid_rmi_num_threads_is_refused() -> None:
    proc = run_python(
        """
        import rmi_sph
        try:
            rmi_sph.Trial(rmi_sph.trial_config(8, 0.6, 20, 40, 0.01))
        except rmi_sph.ConfigError as e:
            print(e.field)
        """,
        RMI_NUM_THREADS="lots",
    )
    assert proc.stdout.strip() == "RMI_NUM_THREADS", proc.stdout + proc.stderr


def test_set_state_refuses_another_config_and_changes_nothing() -> None:
    a = rmi_sph.Trial(tiny(), num_threads=1)
    b = rmi_sph.Trial(tiny(jitter=0.1), num_threads=1)
    a.step(3)
    before = a.get_state()
    with pytest.raises(rmi_sph.StateError, match="jitter"):
        a.set_state(b.get_state())
    with pytest.raises(rmi_sph.StateError):
        a.set_state(before[:-1])
    assert a.get_state() == before
    c = rmi_sph.Trial.from_state(b.get_state(), num_threads=1)
    assert c.config["jitter"] == 0.1


def test_flipped_bits_of_a_trial_state_are_refused() -> None:
    state = rmi_sph.Trial(tiny(), num_threads=1).get_state()
    rng = random.Random(5)
    json_at = state.index(b'"hold_force"')
    for bit in [8 * json_at + 3] + [rng.randrange(8 * len(state)) for _ in range(200)]:
        bad = bytearray(state)
        bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(rmi_sph.StateError):
            rmi_sph.Trial.from_state(bytes(bad), num_threads=1)


def test_concurrent_saves_and_special_paths(tmp_path: Path) -> None:
    trials = [rmi_sph.Trial(tiny(jitter=j), num_threads=1) for j in (0.05, 0.1)]
    paths = [tmp_path / "ck.a", tmp_path / "ck.b"]

    def save(t: rmi_sph.Trial, p: Path) -> None:
        for _ in range(30):
            t.save(p)

    threads = [threading.Thread(target=save, args=tp) for tp in zip(trials, paths, strict=True)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for t, p in zip(trials, paths, strict=True):
        assert rmi_sph.Trial.load(p).get_state() == t.get_state()
    assert sorted(os.listdir(tmp_path)) == ["ck.a", "ck.b"]
    link = tmp_path / "link"
    link.symlink_to(paths[0])
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for p in (link, fifo):
        with pytest.raises(OSError, match=str(p)):
            trials[1].save(p)
    assert rmi_sph.Trial.load(paths[0]).get_state() == trials[0].get_state()


def test_continuation_from_the_first_ramp_step_is_bit_identical(tmp_path: Path) -> None:
    a = rmi_sph.Trial(tiny(), num_threads=1)
    while a.phase != "ramp":
        a.step()
    a.step()
    state = a.get_state()
    path = tmp_path / "ramp.state"
    a.save(path)
    b = rmi_sph.Trial.from_state(state, num_threads=2)
    c = rmi_sph.Trial(tiny(), num_threads=1)
    c.set_state(state)
    d = rmi_sph.Trial.load(path)
    e = pickle.loads(pickle.dumps(a))
    a.step(100)
    x = a.particles("solid")["positions"]
    for t in (b, c, d, e):
        t.step(100)
        assert np.array_equal(t.particles("solid")["positions"], x)
        assert t.get_state() == a.get_state()
