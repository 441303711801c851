"""Plain least squares: the textbook identification the product has to beat.

Per joint j, on the training samples: the joint's row of pinocchio's joint-torque regressor
(``pin.computeJointTorqueRegressor``, 10 inertial parameters per link, stacked over samples),
reduced to its base columns, plus a Coulomb column ``sgn(dq_j)`` and a viscous column ``dq_j``;
unweighted least squares; the fit predicts the test samples and the held-out RMS [N·m] per
joint is reported. Inputs are what the measurement files hold (t, q, dq, tau); ddq is the
central difference of dq (``np.gradient``). No filtering, no friction beyond Coulomb + viscous.

Base columns (per joint row): QR with column pivoting of the row's regressor over random
states (structural, independent of the data); the first ``rank`` pivots are kept, the others
are linear combinations of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.linalg

RANK_TOL = 1e-9


def regressor(model, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """Joint-torque regressor per sample, shape (T, n, 10 n); gravity of ``model``."""
    data = model.createData()
    out = np.empty((q.shape[0], model.nv, 10 * (model.njoints - 1)))
    for i in range(q.shape[0]):
        out[i] = pin.computeJointTorqueRegressor(model, data, q[i], dq[i], ddq[i])
    return out


def base_columns(model, n_states: int = 400, seed: int = 5) -> list[np.ndarray]:
    """Per joint row, the indices of its base columns (QR with column pivoting on random
    states: q uniform in ±π, dq in ±2 rad/s, ddq in ±5 rad/s²)."""
    rng = np.random.default_rng(seed)
    n = model.nv
    y = regressor(
        model,
        rng.uniform(-np.pi, np.pi, (n_states, n)),
        rng.uniform(-2.0, 2.0, (n_states, n)),
        rng.uniform(-5.0, 5.0, (n_states, n)),
    )
    out = []
    for j in range(n):
        w = y[:, j, :]
        _, r, piv = scipy.linalg.qr(w, mode="economic", pivoting=True)
        d = np.abs(np.diag(r))
        rank = int(np.sum(d > RANK_TOL * d[0])) if d.size and d[0] > 0 else 0
        out.append(np.sort(piv[:rank]))
    return out


@dataclass(frozen=True)
class PlainLS:
    """Result: held-out RMS ``rms_test`` and in-sample ``rms_train`` [N·m] per joint, the
    number of base columns per joint ``n_base``, the fitted Coulomb [N·m] and viscous
    [N·m·s/rad] coefficients per joint, and the held-out residual ``residual_test`` (T, n)
    [N·m] (measured minus predicted test torque)."""

    rms_test: np.ndarray
    rms_train: np.ndarray
    n_base: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray
    residual_test: np.ndarray


def _design(
    model, cols: list[np.ndarray], d: dict[str, np.ndarray], offset: bool, chunk: int
) -> list[np.ndarray]:
    """Per joint the plain-LS columns of one run: its base regressor columns, ``sgn dq_j``,
    ``dq_j`` (and ``1`` with ``offset``); ddq = ``np.gradient`` of the measured dq. The
    regressor is built ``chunk`` samples at a time (all of it at once is T × n × 10 n)."""
    ddq = np.gradient(d["dq"], d["t"], axis=0)
    n = model.nv
    blocks: list[list[np.ndarray]] = [[] for _ in range(n)]
    for s in range(0, d["t"].size, chunk):
        sl = slice(s, s + chunk)
        y = regressor(model, d["q"][sl], d["dq"][sl], ddq[sl])
        for j in range(n):
            blocks[j].append(y[:, j, cols[j]])
    out = []
    for j in range(n):
        dq = d["dq"][:, j]
        extra = [np.ones_like(dq)] if offset else []
        out.append(np.column_stack([np.vstack(blocks[j]), np.sign(dq), dq, *extra]))
    return out


def plain_ls(
    urdf_xml: str,
    train: dict[str, np.ndarray],
    test: dict[str, np.ndarray],
    offset: bool = False,
    chunk: int = 4000,
):
    """Fit on ``train``, judge on ``test``; each a dict with ``t`` [s] (T,), ``q`` [rad],
    ``dq`` [rad/s], ``tau`` [N·m] (T, n) (as :func:`.generator.read_csv` returns, or built
    from a :class:`.generator.Run`). ``offset`` adds a constant column per joint. Returns a
    :class:`PlainLS`."""
    model = pin.buildModelFromXML(urdf_xml)
    cols = base_columns(model)
    a_tr, a_te = (_design(model, cols, d, offset, chunk) for d in (train, test))
    tau_tr, tau_te = train["tau"], test["tau"]
    n = model.nv
    rms_test, rms_train = np.zeros(n), np.zeros(n)
    coulomb, viscous = np.zeros(n), np.zeros(n)
    residual = np.zeros_like(tau_te)
    k = 3 if offset else 2  # Coulomb and viscous are the k-th and (k-1)-th last columns
    for j in range(n):
        a = a_tr[j]
        scale = np.linalg.norm(a, axis=0)
        scale[scale == 0] = 1.0
        theta = np.linalg.lstsq(a / scale, tau_tr[:, j], rcond=None)[0] / scale
        rms_train[j] = np.sqrt(np.mean((tau_tr[:, j] - a @ theta) ** 2))
        residual[:, j] = tau_te[:, j] - a_te[j] @ theta
        rms_test[j] = np.sqrt(np.mean(residual[:, j] ** 2))
        coulomb[j], viscous[j] = theta[-k], theta[-k + 1]
    n_base = np.array([c.size for c in cols])
    return PlainLS(rms_test, rms_train, n_base, coulomb, viscous, residual)


def run_arrays(run) -> dict[str, np.ndarray]:
    """The measured columns of a :class:`.generator.Run` as :func:`plain_ls` takes them."""
    return {"t": run.t, "q": run.q, "dq": run.dq, "tau": run.tau}
