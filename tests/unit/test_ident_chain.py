"""The torque channel's gain and offset (control/identification/chain.py), on a bench of
least-squares groups made to measure: shared "rigid" columns, one friction pair and one
constant per joint, each joint read through its own gain and offset."""

from __future__ import annotations

import numpy as np

from control.identification.chain import estimate
from control.identification.effects import NoiseFloor
from control.identification.lsq import BlockLS, contiguous_folds

T = 6000
SIGMA_NM = 0.02


def _bench(gain: np.ndarray, offset: np.ndarray, shared: np.ndarray, seed: int = 0):
    """Targets ``k (A_j β + F_j φ_j) + b + noise`` for len(gain) joints; joint j's rigid columns
    are scaled by ``shared[j]`` (0: its row has no rigid part, so nothing ties its gain)."""
    rng = np.random.default_rng(seed)
    n = gain.size
    t = np.linspace(0.0, 60.0, T)
    beta = np.array([3.0, -2.0, 1.5, 1.0])
    ls_cols, fr_cols, y = {}, {}, np.zeros((T, n))
    for j in range(n):
        f = rng.uniform(0.1, 0.6, 4)
        ph = rng.uniform(0, 2 * np.pi, 4)
        a = shared[j] * np.sin(2 * np.pi * f * t[:, None] + ph)
        dq = np.cos(2 * np.pi * 0.3 * t + j)
        fr = np.column_stack([np.tanh(dq / 0.05), dq])
        ls_cols[j], fr_cols[j] = a, fr
        physical = a @ beta + fr @ np.array([0.4, 0.3])
        y[:, j] = gain[j] * physical + offset[j] + SIGMA_NM * rng.standard_normal(T)
    ls = BlockLS(y, contiguous_folds(T, 5))
    ls.add("rigid", ls_cols)
    names = ["rigid"]
    for j in range(n):
        ls.add(f"friction:{j}", {j: fr_cols[j]})
        ls.add(f"offset:{j}", {j: np.ones((T, 1))})
        names += [f"friction:{j}", f"offset:{j}"]
    offsets = {j: (f"offset:{j}", 0) for j in range(n)}
    noise = NoiseFloor(np.full(n, SIGMA_NM), np.full(n, SIGMA_NM**2))
    return ls, names, offsets, noise, y


def test_relative_gains_and_offsets_are_recovered_and_the_targets_restored() -> None:
    gain = np.array([1.0, 1.04, 0.96, 1.02])
    offset = np.array([0.05, -0.03, 0.0, 0.02])
    ls, names, offsets, noise, y = _bench(gain, offset, np.ones(4))
    chain = estimate(ls, names, np.full(4, 1 / SIGMA_NM), offsets, noise, alpha=0.01)
    # one joint stays the reference; the others are measured against it
    assert chain.free.sum() == 3
    ref = int(np.flatnonzero(~chain.free)[0])
    np.testing.assert_allclose(chain.gain / chain.gain[ref], gain / gain[ref], atol=2e-3)
    # an offset is read in the channel's own units: the same whatever the common scale
    np.testing.assert_allclose(chain.offset_nm, offset, atol=5e-3)
    np.testing.assert_array_equal(ls.y, y)  # the targets are given back as they were
    # the chain undone gives the torque behind the readings, on the reference's scale
    physical = chain.to_physical(y)
    np.testing.assert_allclose(chain.to_measured(physical), y, atol=1e-12)


def test_a_gain_nothing_ties_stays_one_and_no_chain_is_found_where_there_is_none() -> None:
    gain = np.array([1.0, 1.03, 0.97])
    ls, names, offsets, noise, _ = _bench(gain, np.zeros(3), np.array([1.0, 1.0, 0.0]))
    chain = estimate(ls, names, np.full(3, 1 / SIGMA_NM), offsets, noise, alpha=0.01)
    # joint 3 has no rigid-body part: its gain and its friction trade freely, nothing to see
    assert not chain.free[2] and chain.gain[2] == 1.0
    exact, names, offsets, noise, _ = _bench(np.ones(3), np.zeros(3), np.ones(3), seed=1)
    none = estimate(exact, names, np.full(3, 1 / SIGMA_NM), offsets, noise, alpha=0.01)
    assert not none.free.any()
    np.testing.assert_array_equal(none.gain, np.ones(3))
