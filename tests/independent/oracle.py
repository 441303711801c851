"""The referee's oracle: least squares of the generating model itself (the hard world,
:mod:`.world`).

Per joint j, on the rows analyze sees (train.csv and test.csv), unweighted least squares of the
measured torque on the columns of the model that generated it:

- the *generating* URDF's joint-torque regressor row (``pin.computeJointTorqueRegressor``),
  reduced to its base columns by QR with column pivoting on random states (as
  :func:`.baseline.base_columns`), on the true kinematics the torque sees (the true motion at
  the stamps, shifted by the true delay when there is one; ddq the true acceleration);
- the joint's friction law with its true nonlinear shape (:meth:`.friction_laws.FrictionLaw.
  columns`: the law's torque with a free scale, the viscous term, both Coulomb levels of the
  asymmetric law), LuGre/Dahl bristle states as simulated over the session;
- each effect's columns with its true nonlinear parameters (:mod:`.world_effects`);
- a constant (the chain's offset b_j); the chain's gain k_j scales every column's coefficient.

The fit predicts the holdout rows; its residual is scored on the same rows as the product's.
It predicts them from the holdout file as the product must (``from_file``, the default): a
LuGre/Dahl bristle state starts at 0 at the file's first row (:attr:`.world.World.
holdout_from_file`: what a resting joint holds there depends on the motion before the file).
With ``from_file=False`` it carries the session's state, which only the generator knows; on
noise-free data it then reproduces the holdout to rounding: it is the generating model.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from .baseline import base_columns, regressor

CHUNK = 4000


def design(world, run: str, model=None, cols=None, from_file: bool = False) -> list[np.ndarray]:
    """Per joint the oracle's columns (T, m_j) on run ``run`` of ``world`` (``from_file``:
    the holdout's friction and effect columns as its file alone determines them)."""
    model = pin.buildModelFromXML(world.truth_urdf) if model is None else model
    cols = base_columns(model) if cols is None else cols
    n = model.nv
    q, dq, ddq = world.seen[run]
    blocks: list[list[np.ndarray]] = [[] for _ in range(n)]
    for s in range(0, q.shape[0], CHUNK):
        sl = slice(s, s + CHUNK)
        y = regressor(model, q[sl], dq[sl], ddq[sl])
        for j in range(n):
            blocks[j].append(y[:, j, cols[j]])
    out = []
    for j in range(n):
        ones = np.ones((q.shape[0], 1))
        law = world.holdout_from_file[j] if from_file and run == "holdout" else None
        law = world.columns[run][j] if law is None else law
        out.append(np.column_stack([np.vstack(blocks[j]), law, ones]))
    return out


def fit_predict(
    world, tau: dict[str, np.ndarray] | None = None, from_file: bool = True
) -> np.ndarray:
    """The oracle fitted on train + test, its prediction of the holdout (T, n) [N·m] from the
    holdout's file (``from_file``) or with the session's bristle states (module docstring);
    ``tau`` per run name replaces the measured torque (tests: noise-free data)."""
    d = world.draw
    tau = tau or {"train": d.train.tau, "test": d.test.tau}
    model = pin.buildModelFromXML(world.truth_urdf)
    cols = base_columns(model)
    a = {r: design(world, r, model, cols, from_file) for r in ("train", "test", "holdout")}
    pred = np.empty((d.holdout.t.size, world.n))
    for j in range(world.n):
        x = np.vstack([a["train"][j], a["test"][j]])
        y = np.concatenate([tau["train"][:, j], tau["test"][:, j]])
        scale = np.linalg.norm(x, axis=0)
        scale[scale == 0] = 1.0
        theta = np.linalg.lstsq(x / scale, y, rcond=None)[0] / scale
        pred[:, j] = a["holdout"][j] @ theta
    return pred
