"""The rest hold (control/rt/src/law/rest_hold.rs): a weightless joint with a static model error
stays where it was left, an operator who pushes past the band moves it against the band only,
and the hold's torque has no step."""

from __future__ import annotations

import numpy as np
import pytest

from control._rt import RestHold, hold_band_nm
from control.config import ControlConfig
from gateway.errors import ConfigError

DT = 0.004


def drag(
    hold: RestHold, push_nm, seconds: float, inertia: float = 1.2, damping: float = 20.0
) -> dict[str, np.ndarray]:
    """One joint (``inertia`` kg·m², ``damping`` N·m·s/rad) under an unbalanced torque
    ``push_nm(t)`` (a static model error, or a hand) and the hold, applied one cycle late as
    the drive does; explicit Euler at 1 kHz inside each 4 ms cycle."""
    q = dq = 0.0
    applied = 0.0
    rows = []
    for k in range(round(seconds / DT)):
        t = k * DT
        h = hold.torque_nm([q])[0]
        for _ in range(4):
            ddq = (push_nm(t) + applied - damping * dq) / inertia
            dq += ddq * DT / 4
            q += dq * DT / 4
        applied = h
        rows.append((t, q, dq, h))
    arr = np.array(rows)
    return {name: arr[:, i] for i, name in enumerate(("t", "q", "dq", "hold"))}


def test_a_static_error_below_the_band_leaves_the_joint_where_it_was():
    run = drag(RestHold([0.34], 1e-3), lambda t: 0.2, 5.0)
    assert np.max(np.abs(run["q"])) < 1e-3  # at most the deflection: 0.2/0.34 mrad
    assert abs(run["dq"][-1]) < 1e-5
    assert run["hold"][-1] == pytest.approx(-0.2, abs=1e-3)


def test_without_the_hold_the_same_error_creeps():
    run = drag(RestHold([0.0], 1e-3), lambda t: 0.2, 5.0)
    assert run["q"][-1] > 0.04  # 0.2 N·m over 20 N·m·s/rad: 10 mrad/s


def test_a_push_past_the_band_moves_the_joint_against_the_band_only():
    run = drag(RestHold([0.34], 1e-3), lambda t: 0.2 if t < 1.0 else 2.0, 3.0)
    late = run["t"] > 2.0
    np.testing.assert_allclose(run["dq"][late], (2.0 - 0.34) / 20.0, rtol=1e-3)
    np.testing.assert_allclose(run["hold"][late], -0.34)
    assert np.max(np.abs(run["hold"])) <= 0.34 + 1e-9
    assert np.all(np.abs(np.diff(run["hold"])) < 0.05), "the hold's torque steps"


def test_the_joint_stops_where_the_operator_leaves_it():
    run = drag(RestHold([0.34], 1e-3), lambda t: 2.0 if t < 0.5 else 0.2, 6.0)
    stopped = run["t"] > 2.0
    assert np.ptp(run["q"][stopped]) < 1e-3, "the error creeps on after the operator let go"
    assert abs(run["dq"][-1]) < 1e-5
    let_go = np.searchsorted(run["t"], 0.5)
    assert run["q"][-1] - run["q"][let_go] < 0.01  # within a few milliradians


def test_reset_anchors_where_the_joint_is_now():
    hold = RestHold([1.0, 0.0], 1e-3)
    assert hold.torque_nm([0.0, 0.0]) == [0.0, 0.0]
    assert hold.torque_nm([0.0005, 0.3]) == pytest.approx([-0.5, 0.0])
    hold.reset()
    assert hold.torque_nm([0.2, 0.3]) == [0.0, 0.0]
    assert not RestHold([0.0], 1e-3).active


def test_band_from_the_model_rms_with_a_floor():
    assert hold_band_nm([0.5, 0.0], 2.0, [0.1, 0.4]) == [0.5, 0.8]
    assert hold_band_nm([0.5, 0.0], 2.0, None) == [0.5, 0.0]
    with pytest.raises(ValueError, match="2 joints, not 3"):
        hold_band_nm([0.0] * 3, 2.0, [0.1, 0.2])


@pytest.mark.parametrize(
    "args", [([-1.0], 1e-3), ([float("nan")], 1e-3), ([1.0], 0.0), ([1.0], float("inf"))]
)
def test_bad_settings_are_refused(args):
    with pytest.raises(ValueError, match="rest hold"):
        RestHold(*args)


def test_config_checks_the_rest_hold_settings():
    base = dict(max_offset_rad=(0.02,) * 2, max_velocity_rad_s=(1.0,) * 2,
                damping_nm_s_per_rad=(1.0,) * 2, omega_adaptation_per_s=0.0)  # fmt: skip
    with pytest.raises(ConfigError, match="rest_hold_nm"):
        ControlConfig(**base, rest_hold_nm=(1.0,))
    with pytest.raises(ConfigError, match="rest_hold_deflection_rad"):
        ControlConfig(**base, rest_hold_deflection_rad=0.0)
    with pytest.raises(ConfigError, match="rest_hold_rms_factor"):
        ControlConfig(**base, rest_hold_rms_factor=-1.0)
