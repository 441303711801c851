"""The weighted least squares of identification: the truncated solve's fast path and forks of
the Gram store (``control/identification/lsq.py``)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from control.identification import lsq
from control.identification.lsq import BlockLS, contiguous_folds, tsvd_solve


def _design(cond: float, rows: int = 400, cols: int = 20, seed: int = 0):
    rng = np.random.default_rng(seed)
    u, _, vt = np.linalg.svd(rng.standard_normal((rows, cols)), full_matrices=False)
    a = (u * np.geomspace(1.0, 1.0 / np.sqrt(cond), cols)) @ vt
    a *= rng.uniform(0.1, 100.0, cols)  # columns of very different scale
    return a.T @ a, a.T @ rng.standard_normal(rows)


def _eigen_only(gram, rhs, monkeypatch):
    monkeypatch.setattr(lsq, "_solve_if_well_conditioned", lambda *_: None)
    try:
        return tsvd_solve(gram, rhs)
    finally:
        monkeypatch.undo()


@pytest.mark.parametrize("cond", [1.0, 1e4, 1e8, 1e9, 1e11, 1e13])
def test_the_fast_path_gives_the_truncated_solution(cond, monkeypatch):
    gram, rhs = _design(cond)
    x, rank = tsvd_solve(gram, rhs)
    x_ref, rank_ref = _eigen_only(gram, rhs, monkeypatch)
    assert rank == rank_ref
    assert np.allclose(x, x_ref, rtol=1e-6, atol=1e-9 * np.abs(x_ref).max())


def test_directions_below_the_cut_are_still_dropped():
    gram, rhs = _design(1e13)  # squared singular values down to 1e-13 of the largest
    _, rank = tsvd_solve(gram, rhs)
    assert rank < gram.shape[0]


def _store(seed: int = 3) -> tuple[BlockLS, dict[str, dict[int, np.ndarray]]]:
    rng = np.random.default_rng(seed)
    t, n = 600, 3
    groups = {
        "rigid": {j: rng.standard_normal((t, 4)) for j in range(n)},
        "f0": {0: rng.standard_normal((t, 2))},
        "f1": {1: rng.standard_normal((t, 2))},
        "e": {0: rng.standard_normal((t, 1)), 2: rng.standard_normal((t, 1))},
    }
    y = rng.standard_normal((t, n))
    return BlockLS(y, contiguous_folds(t, 5)), groups


def test_a_fork_searches_without_touching_its_parent():
    ls, groups = _store()
    ls.add("rigid", groups["rigid"])
    fork = ls.fork()
    fork.add("f0", groups["f0"])
    fork.remove("rigid")
    assert list(ls.cols) == ["rigid"] and set(ls._gram) == {("rigid", "rigid")}
    assert list(fork.cols) == ["f0"]


def test_adopted_groups_solve_as_if_added_directly():
    direct, groups = _store()
    for name in ("rigid", "f0", "f1", "e"):
        direct.add(name, groups[name])
    parent, _ = _store()
    parent.add("rigid", groups["rigid"])
    parent.add("e", groups["e"])  # a group the fork never saw
    fork = parent.fork()
    fork.add("f0", groups["f0"])
    fork.add("f1", groups["f1"])
    parent.adopt(fork, ["f0", "f1"])
    w = np.ones(3)
    names = ["rigid", "f0", "f1", "e"]
    a, b = direct.evaluate(names, w), parent.evaluate(names, w)
    assert np.allclose(a.cv_sse, b.cv_sse) and np.allclose(a.fit_sse, b.fit_sse)
    for name in names:
        assert np.allclose(a.solution.coef[name], b.solution.coef[name])
    assert np.allclose(direct.cv_sse(names, w), a.cv_sse)


def test_groups_exported_through_pickle_solve_as_if_added_directly():
    """What a worker process sends back (:meth:`BlockLS.export`, pickled) is adopted like a
    fork's groups."""
    direct, groups = _store()
    for name in ("rigid", "f0", "e"):
        direct.add(name, groups[name])
    parent, _ = _store()
    parent.add("rigid", groups["rigid"])
    parent.add("e", groups["e"])
    fork = parent.fork()
    fork.add("f0", groups["f0"])
    parent.adopt(pickle.loads(pickle.dumps(fork.export(["f0"]))))
    w = np.ones(3)
    names = ["rigid", "f0", "e"]
    a, b = direct.evaluate(names, w), parent.evaluate(names, w)
    assert np.array_equal(a.cv_sse, b.cv_sse) and np.array_equal(a.fit_sse, b.fit_sse)


def test_the_held_out_error_of_one_fold_is_that_fold_of_all():
    ls, groups = _store()
    for name in ("rigid", "f0", "e"):
        ls.add(name, groups[name])
    sol = ls.solve(["rigid", "f0", "e"], np.ones(3))
    every = ls.fold_sse(sol)
    for k in range(len(ls.folds)):
        assert np.allclose(ls.fold_sse(sol, k)[0], every[k], rtol=1e-12, atol=0.0)
