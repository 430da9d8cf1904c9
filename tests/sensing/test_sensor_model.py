"""The sensors' noise and latency (rmi_learn.sensing): deterministic for a seed, the same bits
online and offline, the true values when noiseless, the configured spread, and one clear
line for a bad setting."""

from __future__ import annotations

import numpy as np
import pytest

from rmi_learn.errors import InputError
from rmi_learn.sensing import (
    OBSERVATION_MODES,
    SENSOR_NAMES,
    SensorModel,
    SensorStream,
    check_observation_mode,
    observation_names,
    observe_rows,
)
from rmi_learn.sensing.sensor_model import NOISE_OF, true_row


def _rows(n: int = 40) -> np.ndarray:
    rng = np.random.default_rng(0)
    rows = rng.uniform(0.0, 50.0, size=(n, len(SENSOR_NAMES)))
    f = SENSOR_NAMES.index
    rows[:, f("F_meas")] = 0.5 * (rows[:, f("F_L")] + rows[:, f("F_R")])
    return rows


def test_the_sensor_mode_shows_no_simulator_only_quantity() -> None:
    assert set(OBSERVATION_MODES) == {"privileged", "sensors"}
    names = observation_names("sensors")
    assert not {"M_L", "S", "V_pore", "V_sponge"} & set(names)
    assert {"w", "F_L", "F_R", "W_x", "W_y", "W_z"} <= set(names)
    assert observation_names("privileged")[0] == "M_L"


def test_an_unknown_mode_is_one_line_naming_the_field() -> None:
    with pytest.raises(InputError, match="observation_mode must be one of privileged, sensors"):
        check_observation_mode("camera")


def test_stream_and_batch_give_the_same_bits_and_a_seed_fixes_them() -> None:
    rows, model = _rows(), SensorModel()
    stream = SensorStream(model, (3, 4))
    online = np.stack([stream.observe(r) for r in rows])
    assert np.array_equal(online, observe_rows(rows, model, (3, 4)))
    assert np.array_equal(observe_rows(rows, model, (3, 4)), observe_rows(rows, model, (3, 4)))
    assert not np.array_equal(observe_rows(rows, model, (3, 5)), online)
    assert not np.array_equal(observe_rows(rows, SensorModel(seed=1), (3, 4)), online)


def test_noiseless_without_latency_reports_the_true_values() -> None:
    rows = _rows()
    assert np.array_equal(observe_rows(rows, SensorModel.noiseless(), (0,)), rows)


def test_latency_delays_every_channel_by_whole_control_steps() -> None:
    rows = _rows()
    out = observe_rows(rows, SensorModel.noiseless(latency_ticks=2), (0,))
    assert np.array_equal(out[2:], rows[:-2])
    assert np.array_equal(out[0], rows[0]) and np.array_equal(out[1], rows[0])


def test_the_noise_has_the_configured_spread_and_flags_are_exact() -> None:
    model = SensorModel(latency_ticks=0)
    rows = np.zeros((4000, len(SENSOR_NAMES)))
    out = observe_rows(rows, model, (1,))
    std = out.std(axis=0)
    for i, name in enumerate(SENSOR_NAMES):
        want = getattr(model, NOISE_OF[name]) if name in NOISE_OF else 0.0
        if name == "F_meas":  # the mean of two independent pad loads
            want = model.pad_force_N / np.sqrt(2.0)
        assert std[i] == pytest.approx(want, rel=0.06, abs=1e-12), name


def test_true_row_reads_an_engine_record_by_name() -> None:
    rec = {n: float(i) for i, n in enumerate(SENSOR_NAMES)} | {"M_L": 9.0}
    assert np.array_equal(true_row(rec), np.arange(len(SENSOR_NAMES), dtype=float))


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"wrist_N": -0.1}, r"sensors.wrist_N must be in \[0, 10.0\]"),
        ({"pad_force_N": float("nan")}, "sensors.pad_force_N must be a number"),
        ({"latency_ticks": 26}, r"sensors.latency_ticks must be an integer in \[0, 25\]"),
        ({"latency_ticks": True}, "sensors.latency_ticks must be an integer"),
        ({"seed": -1}, "sensors.seed must be an integer"),
    ],
)
def test_a_bad_setting_is_one_line_naming_the_field_and_range(kw: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        SensorModel(**kw)


def test_unknown_fields_and_a_latency_beyond_the_history_are_refused() -> None:
    with pytest.raises(InputError, match="sensors has unknown field 'wrist'"):
        SensorModel.from_mapping({"wrist": 0.1})
    with pytest.raises(InputError, match="not shorter than the history of 2 control steps"):
        SensorModel(latency_ticks=2).check_history(2)
    SensorModel(latency_ticks=1).check_history(2)
