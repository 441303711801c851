"""The current sensors' zero (drivers/can/current_zero.py): the mean of the newest cycles
reported with the servo power off, after the settle cycles, frozen while powered."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.current_zero import (
    CurrentZero,
    StoredZeroError,
    read_stored_zero,
    write_stored_zero,
)


def test_the_zero_is_the_mean_of_the_newest_unpowered_cycles_after_settling():
    z = CurrentZero(2, window=3, settle=1)
    z.update(np.array([5.0, 5.0]), servo_power=False)  # settling: the filter's powered ticks
    assert z.samples == 0 and not z.offset_a.any()
    for v in (1.0, 2.0, 3.0, 4.0):
        z.update(np.array([v, -v]), servo_power=False)
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])  # the newest three
    z.update(np.array([100.0, 100.0]), servo_power=True)
    np.testing.assert_allclose(z.correct(np.array([10.0, 0.0])), [7.0, 3.0])
    z.update(np.array([100.0, 100.0]), servo_power=False)  # settling again after power-off
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])
    z.update(np.array([np.nan, 0.0]), servo_power=False)  # a NaN never enters the mean
    np.testing.assert_allclose(z.offset_a, [3.0, -3.0])


def test_a_zero_window_disables_it_and_negative_sizes_are_refused():
    z = CurrentZero(1, window=0, settle=0)
    z.update(np.array([0.5]), servo_power=False)
    assert z.samples == 0 and z.correct(np.array([1.0]))[0] == 1.0
    with pytest.raises(ValueError, match="window"):
        CurrentZero(1, window=-1, settle=0)


def test_the_commissioning_zero_is_used_at_once_and_a_fresh_one_only_watches_it():
    stored = (np.array([0.1, -0.2]), 250, np.array([0.02, 0.02]))
    z = CurrentZero(2, window=4, settle=0, stored=stored)
    assert z.ready and z.source == "commissioning"
    np.testing.assert_allclose(z.correct(np.array([1.0, 1.0])), [0.9, 1.2])
    rng = np.random.default_rng(3)
    for _ in range(4):  # the same offsets again, measured with noise
        z.update(np.array([0.1, -0.2]) + 0.02 * rng.standard_normal(2), servo_power=False)
    np.testing.assert_allclose(z.offset_a, [0.1, -0.2])  # still the commissioning's
    assert z.drift_a is not None and np.all(np.abs(z.drift_a) < 0.06)
    assert not z.drift_significant()
    for _ in range(4):  # the sensors changed: 0.1 A more on joint 2
        z.update(np.array([0.1, -0.1]) + 0.002 * rng.standard_normal(2), servo_power=False)
    np.testing.assert_allclose(z.measured_a, [0.1, -0.1], atol=0.01)
    np.testing.assert_allclose(z.offset_a, [0.1, -0.2])
    assert z.drift_significant()


def test_a_measured_zero_has_no_drift_and_an_off_zero_says_so():
    z = CurrentZero(1, window=2, settle=0)
    assert z.source == "measured" and not z.ready and z.drift_a is None
    z.update(np.array([0.3]), servo_power=False)
    z.update(np.array([0.5]), servo_power=False)
    assert z.ready and z.drift_a is None and not z.drift_significant()
    np.testing.assert_allclose(z.noise_a(), [np.std([0.3, 0.5], ddof=1)])
    assert CurrentZero(1, window=0, settle=0).source == "off"


def test_stored_zero_round_trip(tmp_path):
    path = tmp_path / "current_zero.json"
    write_stored_zero(path, np.array([0.07, -0.21]), 250, np.array([0.011, 0.012]))
    zero, samples, noise = read_stored_zero(path, 2)
    np.testing.assert_allclose(zero, [0.07, -0.21])
    np.testing.assert_allclose(noise, [0.011, 0.012])
    assert samples == 250 and not (tmp_path / "current_zero.json.tmp").exists()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not json", "not JSON"),
        ('{"format": "other"}', "not a leadthrough-current-zero file"),
        ('{"format": "leadthrough-current-zero", "version": 9}', "version 9"),
        (
            '{"format": "leadthrough-current-zero", "version": 1, "current_zero_a": [0.1],'
            ' "noise_a": [0.0, 0.0], "samples": 5}',
            "current_zero_a must be 2 finite numbers",
        ),
        (
            '{"format": "leadthrough-current-zero", "version": 1, "current_zero_a": [0.1, NaN],'
            ' "noise_a": [0.0, 0.0], "samples": 5}',
            "current_zero_a must be 2 finite numbers",
        ),
        (
            '{"format": "leadthrough-current-zero", "version": 1, "current_zero_a": [0.1, 0.2],'
            ' "noise_a": [0.0, 0.0], "samples": 0}',
            "samples must be a whole number",
        ),
    ],
)
def test_a_bad_stored_zero_is_refused_naming_the_file(tmp_path, text, match):
    path = tmp_path / "zero.json"
    path.write_text(text)
    with pytest.raises(StoredZeroError, match=match) as err:
        read_stored_zero(path, 2)
    assert str(path) in str(err.value)
    with pytest.raises(StoredZeroError, match="cannot read"):
        read_stored_zero(tmp_path / "missing.json", 2)


def test_the_driver_refuses_to_start_on_a_bad_zero_file(tmp_path):
    from drivers.can.config import load_can_config
    from drivers.can.driver import CanDriver
    from gateway.errors import ConfigError

    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "zero.json").write_text('{"format": "other"}')
    cell = tmp_path / "cell.toml"
    cell.write_text('[can]\nadapter = "ltc_dbc"\njoints = 6\ncurrent_zero_file = "cal/zero.json"\n')
    can_cfg, bus_cfg = load_can_config(cell)
    assert can_cfg.current_zero_file == str(tmp_path / "cal" / "zero.json")  # beside the config
    with pytest.raises(ConfigError, match=r"current_zero_file: .*zero.json: not a"):
        CanDriver(can_cfg, bus_cfg)


def test_identify_reads_the_zero_from_the_drivers_health_by_its_name():
    from control.identification.on_cell import CAN_DRIVER
    from drivers.can.driver import PROCESS_NAME

    assert CAN_DRIVER == PROCESS_NAME
