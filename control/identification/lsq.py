"""Weighted least squares over joint-grouped rows, with blocked cross-validation, from Grams.

The identification problem stacks, for every joint j, the rows ``y_j = A_j x`` where the
columns come in named *groups* (the rigid base regressor touches every joint, a joint's friction
basis only its own rows, an effect term the joints it acts on). Rows are weighted per joint
(``w_j``, usually 1/σ_j of the joint's residual: the classic two-step weighted LS).

Everything is solved from Gram blocks ``A_{g1,j}ᵀ A_{g2,j}``, ``A_{g,j}ᵀ y_j`` and ``y_jᵀ y_j``
kept per *fold* (contiguous blocks of samples). So

- adding or swapping one group (a candidate effect, another q_e) costs one pass over that
  group's columns, not a refit over all data;
- the fit without fold k, and its error on fold k, come from sums of blocks: trajectory-wise
  K-fold cross-validation at the price of K small solves.

Solving: columns are scaled to unit weighted norm, then the normal equations are solved by
truncated eigen-decomposition (TSVD): directions whose singular value is below
:data:`RCOND` × the largest are dropped (minimum-norm solution). That is how near-collinear
columns (the eq. (15) ``q/R`` Fourier terms are almost constant when R ≈ 150, regressor
columns that a trajectory hardly excites) are kept from blowing up; the number of kept
directions is the effective parameter count used by BIC.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np
from scipy import linalg

#: Relative singular-value cut of the scaled design (eigenvalue cut RCOND² of the Gram).
RCOND = 1e-5


@dataclass(frozen=True)
class Solution:
    """Coefficients per group (name → (m,) array) and the effective rank of the solve."""

    coef: dict[str, np.ndarray]
    rank: int


@dataclass(frozen=True)
class Evaluation:
    """One model (set of groups) judged on the data of a :class:`BlockLS`.

    ``fit_sse`` (n,) in-sample SSE per joint of the fit on all folds [N²·m²], ``cv_sse`` (n,)
    held-out SSE per joint (each fold predicted by the fit on the others), ``rank`` the
    effective parameter count, ``n_rows`` samples per joint, ``solution`` the all-fold fit.
    """

    fit_sse: np.ndarray
    cv_sse: np.ndarray
    rank: int
    n_rows: np.ndarray  #: (n,) rows used per joint (all, unless a mask left some out)
    solution: Solution

    @property
    def cv_rms(self) -> np.ndarray:
        """Held-out RMS per joint; NaN for a joint without rows (it never slid)."""
        return _rms_of(self.cv_sse, self.n_rows)

    @property
    def fit_rms(self) -> np.ndarray:
        """In-sample RMS per joint; NaN for a joint without rows."""
        return _rms_of(self.fit_sse, self.n_rows)


def _rms_of(sse: np.ndarray, n_rows: np.ndarray) -> np.ndarray:
    sse = np.asarray(sse, dtype=float)
    out = np.full(sse.shape, np.nan)
    np.divide(sse, n_rows, out=out, where=np.asarray(n_rows) > 0)
    return np.sqrt(out)


def tsvd_solve(
    gram: np.ndarray,
    rhs: np.ndarray,
    rcond: float = RCOND,
    prior: np.ndarray | None = None,
    ridge: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Solution of ``gram x = rhs`` on the well-determined subspace; (x, rank).

    Without ``prior`` the minimum-norm one. With ``prior`` (p,) the solution closest to it:
    directions the data do not determine keep the prior's values, and columns where ``ridge``
    (p,) is non-zero are pulled towards it by that ridge in the scaled problem (unit-norm
    columns, whose Gram has unit diagonal): ``(G_s + diag(ridge)) δ = b_s - G_s x0``.
    """
    p = gram.shape[0]
    if prior is not None:
        x0 = np.asarray(prior, dtype=float)
        d = np.sqrt(np.clip(np.diag(gram), 0.0, None))
        reg = gram if ridge is None else gram + np.diag(np.asarray(ridge) * d**2)
        delta, rank = tsvd_solve(reg, rhs - gram @ x0, rcond)
        return x0 + delta, rank
    x = np.zeros(p)
    if p == 0:
        return x, 0
    d = np.sqrt(np.clip(np.diag(gram), 0.0, None))
    keep = d > 1e-150 * max(1.0, float(d.max()))
    if not keep.any():
        return x, 0
    dk = d[keep]
    gs = gram[np.ix_(keep, keep)] / np.outer(dk, dk)
    gs = 0.5 * (gs + gs.T)
    bs = rhs[keep] / dk
    xs = _solve_if_well_conditioned(gs, bs, rcond)
    if xs is not None:
        x[keep] = xs / dk
        return x, int(dk.size)
    evals, evecs = np.linalg.eigh(gs)
    good = evals > (rcond**2) * max(float(evals[-1]), 1e-300)
    v = evecs[:, good]
    xs = v @ ((v.T @ bs) / evals[good])
    x[keep] = xs / dk
    return x, int(good.sum())


def _solve_if_well_conditioned(gs: np.ndarray, bs: np.ndarray, rcond: float) -> np.ndarray | None:
    """``gs⁻¹ bs`` when no eigenvalue of the unit-diagonal Gram ``gs`` falls below the cut of
    :func:`tsvd_solve` (then its truncated solution is the plain one), else None.

    The test costs a Cholesky factorisation instead of an eigen-decomposition (about 20× less
    for a hundred columns): ``gs`` has unit diagonal, so its largest eigenvalue is at most its
    trace p, and if ``gs - rcond² p I`` is positive definite every eigenvalue exceeds
    ``rcond² p ≥ rcond² λ_max``: nothing would be cut. A matrix that fails the test, or sits
    near the cut, takes the eigen-decomposition.
    """
    p = gs.shape[0]
    try:
        linalg.cholesky(gs - (rcond**2) * p * np.eye(p), check_finite=False)
        factor = linalg.cho_factor(gs, check_finite=False)
    except linalg.LinAlgError:
        return None
    return linalg.cho_solve(factor, bs, check_finite=False)


def contiguous_folds(n_rows: int, k: int) -> list[slice]:
    """``k`` contiguous blocks covering ``range(n_rows)`` (never random samples)."""
    k = max(1, min(k, n_rows))
    edges = np.linspace(0, n_rows, k + 1).round().astype(int)
    return [slice(int(a), int(b)) for a, b in pairwise(edges)]


class BlockLS:
    """Per-joint, per-fold Gram blocks of named column groups (see the module docstring).

    ``y`` (T, n) targets; ``folds`` contiguous slices of the T rows. ``mask`` (T, n), 1 where
    joint j's row at sample t takes part in the fit and its error, 0 where it does not (a joint
    stuck in its static friction: its torque there is any value up to the breakaway level, not
    a function of the motion). ``y``, :meth:`predict` and the columns stay unmasked: only the
    Gram blocks and the error sums leave the masked rows out.
    """

    def __init__(
        self, y: np.ndarray, folds: Sequence[slice], mask: np.ndarray | None = None
    ) -> None:
        self.y = np.asarray(y, dtype=float)
        self.n_rows, self.n = self.y.shape
        self.mask = None if mask is None else np.asarray(mask, dtype=float)
        if self.mask is not None and self.mask.shape != self.y.shape:
            raise ValueError(f"mask shape {self.mask.shape} is not the targets' {self.y.shape}")
        #: rows used per joint
        self.counts = (
            np.full(self.n, float(self.n_rows)) if self.mask is None else self.mask.sum(axis=0)
        )
        self.folds = list(folds)
        self.cols: dict[str, dict[int, np.ndarray]] = {}
        self._mcols: dict[str, dict[int, np.ndarray]] = {}  #: the columns, masked
        self.sizes: dict[str, int] = {}
        self._gram: dict[tuple[str, str], dict[int, np.ndarray]] = {}
        self._xy: dict[str, dict[int, np.ndarray]] = {}
        self._ym = self._masked_y(self.y)
        self._yy = self._fold_yy(self._ym)
        #: group name → (prior values (m,), relative ridge): see :meth:`set_prior`
        self.priors: dict[str, tuple[np.ndarray, float]] = {}

    def fork(self) -> BlockLS:
        """A copy that shares this one's arrays (targets, columns, Gram blocks) but not its
        group tables: groups added to or removed from either leave the other as it was. Two
        searches can then run side by side (a worker process or thread each) from the same
        groups."""
        other = object.__new__(BlockLS)
        other.__dict__.update(self.__dict__)
        other.cols = dict(self.cols)
        other._mcols = dict(self._mcols)
        other.sizes = dict(self.sizes)
        other._gram = dict(self._gram)
        other._xy = dict(self._xy)
        other.priors = dict(self.priors)
        return other

    def export(self, names: Sequence[str]) -> dict[str, Any]:
        """Groups ``names`` with their Gram blocks against every group here, as plain dicts of
        arrays (picklable: a search run in a worker process sends them back) for
        :meth:`adopt`."""
        names = list(names)
        return {
            "names": names,
            "cols": {n: self.cols[n] for n in names},
            "mcols": {n: self._mcols[n] for n in names},
            "sizes": {n: self.sizes[n] for n in names},
            "xy": {n: self._xy[n] for n in names},
            "gram": {k: b for k, b in self._gram.items() if k[0] in names or k[1] in names},
        }

    def adopt(self, other: BlockLS | dict[str, Any], names: Sequence[str] | None = None) -> None:
        """Take groups ``names`` from ``other`` (a :meth:`fork` of this one or of its fork, or
        such a fork's :meth:`export`) with their Gram blocks against every group both hold:
        nothing is recomputed but the blocks against groups the other never saw."""
        groups = other if isinstance(other, dict) else other.export(names or [])
        names = groups["names"] if names is None else list(names)
        for name in names:
            if name in self.cols:
                self.remove(name)
            self.cols[name] = groups["cols"][name]
            self._mcols[name] = groups["mcols"][name]
            self.sizes[name] = groups["sizes"][name]
            self._xy[name] = groups["xy"][name]
        for key, blocks in groups["gram"].items():
            if (key[0] in names or key[1] in names) and key[0] in self.cols and key[1] in self.cols:
                self._gram[key] = blocks
        for name in names:
            for existing in self.cols:
                key = (name, existing) if name <= existing else (existing, name)
                shared = set(self._mcols[name]) & set(self._mcols[existing])
                if shared and key not in self._gram:
                    first, second = (name, existing) if name <= existing else (existing, name)
                    self._gram[key] = {
                        j: self._fold_products(self._mcols[first][j], self._mcols[second][j])
                        for j in shared
                    }

    def set_prior(self, name: str, values: np.ndarray, ridge: float = 0.0) -> None:
        """Solve group ``name`` as a deviation from ``values`` (:func:`tsvd_solve`): what the
        data do not determine stays at ``values`` (not at zero), and ``ridge`` × (the number of
        solved columns) pulls weakly determined directions there too."""
        self.priors[name] = (np.asarray(values, dtype=float).copy(), float(ridge))

    def _masked_y(self, y: np.ndarray) -> np.ndarray:
        return y if self.mask is None else y * self.mask

    def _masked(self, j: int, c: np.ndarray) -> np.ndarray:
        return c if self.mask is None else c * self.mask[:, j : j + 1]

    def _fold_yy(self, y: np.ndarray) -> np.ndarray:
        return np.array([np.einsum("ij,ij->j", y[s], y[s]) for s in self.folds])

    def _fold_products(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.stack([a[s].T @ b[s] for s in self.folds])

    def add(self, name: str, cols: dict[int, np.ndarray]) -> None:
        """Add group ``name``: joint index → (T, m) columns acting on that joint's rows."""
        if name in self.cols:
            self.remove(name)
        m = None
        clean: dict[int, np.ndarray] = {}
        for j, c in cols.items():
            arr = np.asarray(c, dtype=float)
            arr = arr[:, None] if arr.ndim == 1 else arr
            if arr.shape[0] != self.n_rows or (m is not None and arr.shape[1] != m):
                raise ValueError(f"group {name}: columns of joint {j} have shape {arr.shape}")
            m = arr.shape[1]
            clean[int(j)] = arr
        if m is None:
            raise ValueError(f"group {name} has no columns")
        masked = {j: self._masked(j, c) for j, c in clean.items()}
        self.cols[name] = clean
        self._mcols[name] = masked
        self.sizes[name] = m
        self._xy[name] = {
            j: self._fold_products(c, self._ym[:, j : j + 1])[:, :, 0] for j, c in masked.items()
        }
        for other, ocols in self._mcols.items():
            shared = set(masked) & set(ocols)
            if not shared:
                continue
            key = (name, other) if name <= other else (other, name)
            first, second = (masked, ocols) if name <= other else (ocols, masked)
            self._gram[key] = {j: self._fold_products(first[j], second[j]) for j in shared}

    def remove(self, name: str) -> None:
        self.cols.pop(name)
        self._mcols.pop(name)
        self.sizes.pop(name)
        self._xy.pop(name)
        for key in [k for k in self._gram if name in k]:
            del self._gram[key]

    def set_y(self, y: np.ndarray) -> None:
        """Replace the targets (e.g. torques shifted by a delay); Gram blocks are kept."""
        self.y = np.asarray(y, dtype=float)
        self._ym = self._masked_y(self.y)
        self._yy = self._fold_yy(self._ym)
        for name, cols in self._mcols.items():
            self._xy[name] = {
                j: self._fold_products(c, self._ym[:, j : j + 1])[:, :, 0] for j, c in cols.items()
            }

    def _offsets(self, names: Sequence[str]) -> dict[str, slice]:
        out, k = {}, 0
        for name in names:
            out[name] = slice(k, k + self.sizes[name])
            k += self.sizes[name]
        return out

    def _normal(
        self, names: Sequence[str], weights: np.ndarray, fold_weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        grams, rhss = self._fold_normals(names, weights)
        fw = np.asarray(fold_weights, dtype=float)
        return np.tensordot(fw, grams, axes=1), fw @ rhss

    def _fold_normals(
        self, names: Sequence[str], weights: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The weighted normal equations of each fold apart, (K, p, p) and (K, p): a fit on any
        set of folds is their sum (one pass over the Gram blocks for all K held-out fits)."""
        off = self._offsets(names)
        p = sum(self.sizes[n] for n in names)
        k = len(self.folds)
        gram = np.zeros((k, p, p))
        rhs = np.zeros((k, p))
        w2 = np.asarray(weights, dtype=float) ** 2
        for a in names:
            for j, xy in self._xy[a].items():
                rhs[:, off[a]] += w2[j] * xy
        for i, a in enumerate(names):
            for b in names[i:]:
                key = (a, b) if a <= b else (b, a)
                blocks = self._gram.get(key)
                if not blocks:
                    continue
                total = sum(w2[j] * g for j, g in blocks.items())
                block = total if a <= b else np.swapaxes(total, 1, 2)
                gram[:, off[a], off[b]] += block
                if a != b:
                    gram[:, off[b], off[a]] += np.swapaxes(block, 1, 2)
        return gram, rhs

    def solve(
        self,
        names: Sequence[str],
        weights: np.ndarray,
        exclude_fold: int | None = None,
        rcond: float = RCOND,
    ) -> Solution:
        """Weighted LS fit of the groups ``names`` on all folds but ``exclude_fold``."""
        fw = np.ones(len(self.folds))
        if exclude_fold is not None:
            fw[exclude_fold] = 0.0
        gram, rhs = self._normal(list(names), weights, fw)
        return self._solve_normal(names, gram, rhs, rcond)

    def _solve_normal(
        self, names: Sequence[str], gram: np.ndarray, rhs: np.ndarray, rcond: float = RCOND
    ) -> Solution:
        off = self._offsets(names)
        prior = ridge = None
        if any(n in self.priors for n in names):
            prior = np.zeros(gram.shape[0])
            ridge = np.zeros(gram.shape[0])
            for n in names:
                if n in self.priors:
                    prior[off[n]] = self.priors[n][0]
                    ridge[off[n]] = self.priors[n][1] * gram.shape[0]
        x, rank = tsvd_solve(gram, rhs, rcond, prior, ridge)
        return Solution({n: x[off[n]] for n in names}, rank)

    def excitation(self, name: str, weights: np.ndarray) -> np.ndarray:
        """Per column of group ``name``, how well the data excite it apart from the group's
        other columns: ``sqrt(VIF)``, the square root of the variance inflation factor of the
        weighted, unit-scaled columns (1: orthogonal to the others; ∞: a combination of them)
        over all folds and joints."""
        gram, _ = self._normal([name], weights, np.ones(len(self.folds)))
        d = np.sqrt(np.clip(np.diag(gram), 0.0, None))
        out = np.full(d.size, np.inf)
        live = d > 1e-150 * max(1.0, float(d.max(initial=0.0)))
        if not live.any():
            return out
        gs = gram[np.ix_(live, live)] / np.outer(d[live], d[live])
        evals, evecs = np.linalg.eigh(0.5 * (gs + gs.T))
        floor = 1e-300
        inv_diag = (evecs**2 / np.maximum(evals, floor)).sum(axis=1)
        out[live] = np.sqrt(np.maximum(inv_diag, 1.0))
        return out

    def fold_sse(self, sol: Solution, fold: int | None = None) -> np.ndarray:
        """SSE of ``sol`` per fold and joint, shape (K, n); of fold ``fold`` only, (1, n)."""
        at = slice(None) if fold is None else slice(fold, fold + 1)
        out = self._yy[at].copy()
        names = list(sol.coef)
        for a in names:
            xa = sol.coef[a]
            for j, xy in self._xy[a].items():
                out[:, j] -= 2.0 * xy[at] @ xa
        for i, a in enumerate(names):
            for b in names[i:]:
                key = (a, b) if a <= b else (b, a)
                blocks = self._gram.get(key)
                if not blocks:
                    continue
                xa, xb = sol.coef[a], sol.coef[b]
                for j, g_all in blocks.items():
                    g = g_all[at]
                    quad = (
                        np.einsum("kij,i,j->k", g, xa, xb)
                        if a <= b
                        else np.einsum("kij,i,j->k", g, xb, xa)
                    )
                    out[:, j] += quad if a == b else 2.0 * quad
        return np.maximum(out, 0.0)

    def evaluate(self, names: Sequence[str], weights: np.ndarray) -> Evaluation:
        """All-fold fit (in-sample SSE) and K-fold held-out SSE per joint of groups ``names``."""
        names = list(names)
        full = self.solve(names, weights) if names else Solution({}, 0)
        fit_sse = self.fold_sse(full).sum(axis=0)
        cv = fit_sse.copy() if len(self.folds) < 2 or not names else self.cv_sse(names, weights)
        return Evaluation(fit_sse, cv, full.rank, self.counts, full)

    def cv_sse(self, names: Sequence[str], weights: np.ndarray) -> np.ndarray:
        """K-fold held-out SSE per joint of groups ``names`` (each fold predicted by the fit on
        the others), (n,): :meth:`evaluate` without the all-fold fit, for searches that
        compare candidates by held-out error alone."""
        names = list(names)
        if len(self.folds) < 2 or not names:
            return self.evaluate(names, weights).cv_sse
        return self.cv_fold_sse(names, weights).sum(axis=0)

    def cv_fold_sse(self, names: Sequence[str], weights: np.ndarray) -> np.ndarray:
        """:meth:`cv_sse` fold by fold, (K, n): each fold's SSE per joint predicted by the fit
        on the other folds (at least two folds)."""
        out = np.zeros((len(self.folds), self.n))
        for k, sol in self._held_out_fits(names, weights):
            out[k] = self.fold_sse(sol, k)[0]
        return out

    def _held_out_fits(
        self, names: Sequence[str], weights: np.ndarray
    ) -> Iterator[tuple[int, Solution]]:
        """Each fold k with the fit of ``names`` on the other folds (at least two folds)."""
        names = list(names)
        if len(self.folds) < 2 or not names:
            raise ValueError("held-out errors per fold need at least two folds and one group")
        grams, rhss = self._fold_normals(names, weights)
        gram, rhs = grams.sum(axis=0), rhss.sum(axis=0)
        for k in range(len(self.folds)):
            yield k, self._solve_normal(names, gram - grams[k], rhs - rhss[k])

    def cv_joint(
        self, names: Sequence[str], weights: np.ndarray, j: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`cv_fold_sse` (K, n) and joint ``j``'s held-out prediction (T,) (each fold's
        rows from the fit on the other folds), from the same K fits."""
        out = np.zeros((len(self.folds), self.n))
        pred = np.zeros(self.n_rows)
        for k, sol in self._held_out_fits(names, weights):
            s = self.folds[k]
            out[k] = self.fold_sse(sol, k)[0]
            for name, x in sol.coef.items():
                c = self.cols[name].get(j)
                if c is not None:
                    pred[s] += c[s] @ x
        return out, pred

    def predict(self, sol: Solution, rows: slice | None = None) -> np.ndarray:
        """Model output of ``sol`` on this object's rows (or a slice), shape (T, n)."""
        s = rows if rows is not None else slice(0, self.n_rows)
        t = len(range(*s.indices(self.n_rows)))
        out = np.zeros((t, self.n))
        for name, x in sol.coef.items():
            for j, c in self.cols[name].items():
                out[:, j] += c[s] @ x
        return out

    def cv_predict(self, names: Sequence[str], weights: np.ndarray) -> np.ndarray:
        """Held-out predictions: each fold's rows from the fit on the other folds, (T, n)."""
        out = np.zeros((self.n_rows, self.n))
        if not names:
            return out
        for k, s in enumerate(self.folds):
            out[s] = self.predict(self.solve(names, weights, exclude_fold=k), s)
        return out
