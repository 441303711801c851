"""A search over q_e computes a joint's friction columns that do not depend on q_e once
(:func:`control.identification.friction_law.qe_columns`, :meth:`.terms.FrictionTerm.columns`):
the columns it then returns are the ones a fresh computation gives, to the last bit, for every
family, sign width, memory and Stribeck rise, with the velocity noise, the sub-sample mean and
the torque filter on."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from control.identification.friction_law import friction_basis, qe_columns, qe_part
from control.identification.terms import Context, FrictionTerm

RATE_HZ = 250.0
Q_E_VALUES = (0.002, 0.02, 0.2)


def _motion(rows: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two joints: a slow sine that reverses and rests, and a faster one; noisy velocities."""
    rng = np.random.default_rng(7)
    t = np.arange(rows) / RATE_HZ
    q = np.column_stack([0.3 * np.sin(0.4 * t) ** 3, 0.8 * np.sin(1.3 * t + 0.5)])
    dq = np.gradient(q, 1.0 / RATE_HZ, axis=0) + 1e-3 * rng.standard_normal(q.shape)
    ddq = np.gradient(dq, 1.0 / RATE_HZ, axis=0)
    return q, dq, ddq


def _context() -> Context:
    q, dq, ddq = _motion()
    sos = butter(4, 20.0, fs=RATE_HZ, output="sos")
    rows = q.shape[0]
    return Context(
        q,
        dq,
        ddq,
        lowpass=lambda x: sosfiltfilt(sos, x, axis=0),
        sample_hz=np.full(rows, RATE_HZ),
        raw_hz=np.full(rows, 2 * RATE_HZ),  # each kept sample stands for two recorded ones
        dq_noise=np.array([1e-3, 1e-3]),
    )


@pytest.mark.parametrize(
    ("kind", "sign_width", "presliding"),
    [
        ("eq15", 0.005, None),
        ("eq15", None, 1e-3),
        ("eq15", 0.005, 1e-3),
        ("eq14", None, None),
        ("eq14", None, 1e-3),
        ("simple", None, None),
        ("simple", None, 1e-3),
    ],
)
def test_the_q_e_part_is_those_columns_of_the_whole_basis(kind, sign_width, presliding):
    q, dq, _ = _motion(500)
    direction = None if presliding is None else np.tanh(dq[:, 0] / 0.01)
    moving = qe_columns(kind, sign_width, direction is not None)
    assert moving is not None
    for q_e in Q_E_VALUES:
        whole = friction_basis(kind, q[:, 0], dq[:, 0], q_e, 100.0, sign_width, direction)
        part = qe_part(kind, dq[:, 0], q_e, sign_width, direction)
        assert part.shape == (500, len(moving))
        np.testing.assert_array_equal(part, whole[:, list(moving)])
        fixed = [c for c in range(whole.shape[1]) if c not in moving]
        other = friction_basis(kind, q[:, 0], dq[:, 0], 0.05, 100.0, sign_width, direction)
        np.testing.assert_array_equal(other[:, fixed], whole[:, fixed])


def test_eq15_with_its_sign_tied_to_q_e_has_no_part_apart():
    assert qe_columns("eq15", None, False) is None
    with pytest.raises(ValueError, match="tied to q_e"):
        qe_part("eq15", np.zeros(3), 0.01)
    with pytest.raises(ValueError, match="q_e_rad_s"):
        qe_part("eq14", np.zeros(3), 0.0)


@pytest.mark.parametrize(
    ("kind", "sign_width", "presliding", "stribeck"),
    [
        ("eq15", 0.005, None, None),
        ("eq15", None, None, None),
        ("eq15", 0.01, 1e-3, 0.02),
        ("eq14", None, None, 0.02),
        ("simple", None, 3e-4, None),
    ],
)
def test_a_q_e_search_gets_the_columns_a_fresh_context_computes(
    kind, sign_width, presliding, stribeck
):
    searched = _context()
    terms = [
        FrictionTerm(j, kind, q_e, 100.0, sign_width, presliding, stribeck)
        for j, q_e in itertools.product((0, 1), Q_E_VALUES)
    ]
    # what else keys the columns kept, each right after the term it differs from by that alone
    others = []
    for term in terms[:3]:
        others += [term, replace(term, presliding_rad=5e-4), term, replace(term, gear_ratio=50.0)]
        if sign_width is not None:
            others += [term, replace(term, sign_width_rad_s=0.02)]
    # the search's order: one joint's q_e values, then the other's, then back, then the others
    for term in [*terms, *terms[:2], *others]:
        got = term.columns(searched)[term.joint]
        fresh = term.columns(_context())[term.joint]
        np.testing.assert_array_equal(got, fresh)
        # the search's q_e reaches the columns (simple friction with memory has no q_e)
        other = replace(term, q_e_rad_s=0.07).columns(_context())[term.joint]
        assert np.array_equal(got, other) == (qe_columns(kind, sign_width, bool(presliding)) == ())
