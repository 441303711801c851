"""The current sensors' zero of the commissioning (gateway/current_zero_file.py): its file,
and the driver refusing a bad one. The zero the driver measures (the mean of the newest cycles
reported with the servo power off) is drivers/can/rt/src/current_zero.rs, tested there."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.current_zero_file import StoredZeroError, read_stored_zero, write_stored_zero


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
