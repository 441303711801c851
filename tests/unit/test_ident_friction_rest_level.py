"""A friction with memory holds at rest the level its contacts were loaded to over the last
presliding travel (issue 46, session 108): a joint that stops from speed holds its sliding
level, one that crept to rest its static level. The level was the static one at every rest,
whatever came before: the Stribeck rise's full height off at each pause of a teaching motion."""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.friction_law import friction_memory
from control.identification.terms import Context, FrictionTerm

RATE_HZ = 500.0
SIGMA_DQ = 1e-4  # rad/s: the velocity noise that friction is taken in expectation over
X_C = 2e-4  # rad: presliding travel


def _stop(
    speed_rad_s: float, rest_s: float = 1.0, move_s: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """``move_s`` at ``speed_rad_s`` then at rest: (q, dq) sampled at RATE_HZ."""
    move, rest = int(move_s * RATE_HZ), int(rest_s * RATE_HZ)
    dq = np.r_[np.full(move, speed_rad_s), np.zeros(rest)]
    q = np.cumsum(dq) / RATE_HZ
    return q, dq


def test_the_held_speed_is_the_speed_of_the_last_presliding_travel():
    q, dq = _stop(0.1)
    z, w = friction_memory(q, dq, 0.0, X_C)
    assert w[int(0.4 * RATE_HZ)] == pytest.approx(0.1, rel=1e-6)  # sliding: the speed itself
    np.testing.assert_allclose(w[int(0.5 * RATE_HZ) :], w[int(0.5 * RATE_HZ) - 1])  # held
    assert w[-1] == pytest.approx(0.1, rel=1e-6)
    assert z[-1] == pytest.approx(1.0, abs=1e-9)  # the direction of the motion, held
    creep_q, creep_dq = _stop(0.002)  # 1 mrad of creep: five presliding travels
    assert friction_memory(creep_q, creep_dq, 0.0, X_C)[1][-1] == pytest.approx(0.002, rel=1e-2)


def test_a_motion_cut_in_pieces_carries_the_held_speed():
    rng = np.random.default_rng(5)
    dq = np.repeat(rng.uniform(-0.05, 0.05, 40), 50) * (rng.uniform(size=2000) > 0.3)
    q = np.cumsum(dq) / RATE_HZ
    z, w = friction_memory(q, dq, SIGMA_DQ, X_C)
    z1, w1 = friction_memory(q[:900], dq[:900], SIGMA_DQ, X_C)
    z2, w2 = friction_memory(q[900:], dq[900:], SIGMA_DQ, X_C, z1[-1], q[899], start_speed=w1[-1])
    np.testing.assert_allclose(np.r_[z1, z2], z, atol=1e-12)
    np.testing.assert_allclose(np.r_[w1, w2], w, atol=1e-12)


@pytest.mark.parametrize("kind", ["eq15", "eq14", "simple"])
def test_a_joint_stopped_from_speed_holds_its_sliding_level_and_a_creeping_one_its_static(kind):
    """The friction columns of a memory joint at rest, with a Stribeck rise (the family's own
    for eq. 15 and eq. 14, the Gaussian one beside it for all three), times coefficients that
    put 1 N·m of Coulomb and 0.5 N·m of each rise: after a stop from 0.1 rad/s (far above
    q_e and v_s) the joint holds 1 N·m, after creeping to rest at 0.5 mrad/s (far below, 5 σ of
    the velocity noise, over 7.5 presliding travels) 1 N·m plus the rises."""
    q_e, v_s = 0.005, 0.01
    term = FrictionTerm(0, kind, q_e, 100.0, presliding_rad=X_C, stribeck_rad_s=v_s)
    names = term.parameter_names
    coulomb = {"eq15": "tau_c_nm", "eq14": "f_c_nm", "simple": "coulomb_nm"}[kind]
    rises = {"eq15": ["tau_s_nm"], "eq14": ["f_s_nm"], "simple": []}[kind] + ["gauss_stribeck_nm"]
    coef = np.zeros(len(names))
    coef[names.index(coulomb)] = 1.0
    for name in rises:
        coef[names.index(name)] = 0.5
    held = {}
    for speed, move_s in ((0.1, 0.5), (0.0005, 3.0)):
        q, dq = _stop(speed, rest_s=0.5, move_s=move_s)
        rest = int(move_s * RATE_HZ) + 50  # 0.1 s into the rest
        ctx = Context(q[:, None], dq[:, None], np.zeros((q.size, 1)), dq_noise=np.array([SIGMA_DQ]))
        held[speed] = float(term.columns(ctx)[0][rest] @ coef)
    expected_rise = 0.5 * len(rises)
    assert held[0.1] == pytest.approx(1.0, abs=0.02)
    assert held[0.0005] == pytest.approx(1.0 + expected_rise, abs=0.1)
