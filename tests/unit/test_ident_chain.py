"""The torque channel's gain and offset (control/identification/chain.py), on a bench of
least-squares groups made to measure: shared "rigid" columns, one friction pair and one
constant per joint, each joint read through its own gain and offset."""

from __future__ import annotations

import numpy as np

from control.identification.chain import estimate, leading_halves
from control.identification.effect_rules import NoiseFloor
from control.identification.lsq import BlockLS, contiguous_folds

T = 6000
SIGMA_NM = 0.02


def _bench(
    gain: np.ndarray,
    offset: np.ndarray,
    shared: np.ndarray,
    seed: int = 0,
    sigma: np.ndarray | None = None,
    beta: np.ndarray | None = None,
):
    """Targets ``k (A_j β_j + F_j φ_j) + b + noise`` for len(offset) joints; joint j's rigid
    columns are scaled by ``shared[j]`` (0: its row has no rigid part, so nothing ties its gain;
    a row (4,) of them: per column). ``gain`` (n,), or (T, n) for a gain that changes during
    the run; ``sigma`` (n,) the noise [N·m] (default :data:`SIGMA_NM`); ``beta`` (n, 4) each
    joint's own rigid parameters (default: the same for all)."""
    rng = np.random.default_rng(seed)
    n = offset.size
    gain = np.broadcast_to(gain, (T, n))
    sigma = np.full(n, SIGMA_NM) if sigma is None else sigma
    t = np.linspace(0.0, 60.0, T)
    beta = np.tile([3.0, -2.0, 1.5, 1.0], (n, 1)) if beta is None else beta
    ls_cols, fr_cols, y = {}, {}, np.zeros((T, n))
    for j in range(n):
        f = rng.uniform(0.1, 0.6, 4)
        ph = rng.uniform(0, 2 * np.pi, 4)
        a = shared[j] * np.sin(2 * np.pi * f * t[:, None] + ph)
        dq = np.cos(2 * np.pi * 0.3 * t + j)
        fr = np.column_stack([np.tanh(dq / 0.05), dq])
        ls_cols[j], fr_cols[j] = a, fr
        physical = a @ beta[j] + fr @ np.array([0.4, 0.3])
        y[:, j] = gain[:, j] * physical + offset[j] + sigma[j] * rng.standard_normal(T)
    ls = BlockLS(y, contiguous_folds(T, 5))
    ls.add("rigid", ls_cols)
    names = ["rigid"]
    for j in range(n):
        ls.add(f"friction:{j}", {j: fr_cols[j]})
        ls.add(f"offset:{j}", {j: np.ones((T, 1))})
        names += [f"friction:{j}", f"offset:{j}"]
    offsets = {j: (f"offset:{j}", 0) for j in range(n)}
    noise = NoiseFloor(sigma, sigma**2)
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


def test_a_gain_is_freed_only_where_its_own_joint_gains_not_where_the_others_do() -> None:
    """Joint 1 sees only the first rigid parameter and is measured far more precisely than the
    others, so it sets that parameter; joint 3's row wants another value of it (a mismatch,
    no gain anywhere). Freeing joint 1's gain lets the parameter follow joint 3 while joint 1's
    own held-out error stays where it was (its gain trades with the parameter): a drop on
    joint 3, not on joint 1. Summed over joints (the rule before) it freed joint 1 at
    0.91; a gain is a property of its own joint's channel and is freed on its evidence alone."""
    sees = np.array([[1.0, 0, 0, 0], [0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0]])
    beta = np.tile([3.0, -2.0, 1.5, 1.0], (3, 1))
    beta[2, 0] += 0.3
    sigma = np.array([1e-5, SIGMA_NM, SIGMA_NM])
    for seed in range(3):
        ls, names, offsets, noise, _ = _bench(np.ones(3), np.zeros(3), sees, seed, sigma, beta)
        chain = estimate(ls, names, 1 / sigma, offsets, noise, alpha=0.01)
        assert not chain.free[0] and chain.gain[0] == 1.0


def test_a_gain_that_does_not_hold_forward_in_time_stays_one() -> None:
    """Joint 2's channel reads 5 % high in the second half of the run only: a gain column
    lowers its K-fold held-out error far beyond noise (it splits the difference), but fitted
    on the first half it predicts nothing of the second (rule (iv) of .effect_rules). The rule
    before freed it at 1.025; a datasheet constant's error holds all run long."""
    gain = np.ones((T, 3))
    gain[T // 2 :, 1] = 1.05
    said: list[str] = []
    for seed in range(3):
        ls, names, offsets, noise, y = _bench(gain, np.zeros(3), np.ones(3), seed)
        chain = estimate(
            ls, names, np.full(3, 1 / SIGMA_NM), offsets, noise, 0.01, None, said.append
        )
        assert not chain.free.any()
        np.testing.assert_array_equal(chain.gain, np.ones(3))
        np.testing.assert_array_equal(ls.y, y)
    assert any(
        "gain of joint 2 kept at 1" in line and "does not hold forward" in line for line in said
    )


def test_a_gain_is_scored_on_the_second_half_of_every_recording() -> None:
    """Training files are different motions in turn: the forward test fits on the first half
    of each (friction sweeps and multi-sines alike) and scores on the rest of each."""
    segment = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 2])
    first = leading_halves(segment)
    np.testing.assert_array_equal(first, [1, 1, 0, 0, 1, 0, 0, 1, 1, 0, 0, 0])


def test_an_offset_larger_than_any_sensor_zero_is_left_out() -> None:
    """Joint 2 carries a constant torque of 40 % of what its channel reads, which the model's
    columns lack (as a mass's gravity looks within a narrow range of motion): a constant
    column takes it and lowers the held-out error far beyond noise, but no sensor's zero is
    that large (chain.MAX_OFFSET_SHARE), so the chain leaves it out and says why. Joint 3's
    true offset of 2.5 noise σ is kept."""
    said: list[str] = []
    for seed in range(3):
        offset = np.array([0.0, 0.0, 0.05])
        ls, names, offsets, noise, y = _bench(np.ones(3), offset, np.ones(3), seed)
        reach = np.max(np.abs(y[:, 1]))
        lacked = np.zeros_like(y)
        lacked[:, 1] = 0.4 / 0.6 * reach  # 40 % of the new reach
        ls.set_y(y + lacked)
        chain = estimate(
            ls, names, np.full(3, 1 / SIGMA_NM), offsets, noise, 0.01, lambda j: True,
            said.append,
        )  # fmt: skip
        assert chain.offset_nm[1] == 0.0
        assert abs(chain.offset_nm[2] - 0.05) < 5e-3
        np.testing.assert_array_equal(ls.y, y + lacked)
    assert any("offset of joint 2 left out" in line for line in said)
