"""The guard's plain least squares (control/identification/guard.py plain_least_squares) keeps
friction dissipative: a joint whose free fit takes a negative viscous coefficient (or Coulomb
level) is refitted with it held at 0; a joint whose friction is physical keeps its free fit."""

from __future__ import annotations

import numpy as np

from control.identification.fit import make_context
from control.identification.guard import plain_least_squares
from control.identification.lsq import contiguous_folds
from control.identification.model import PlainJoint, plain_key
from control.identification.preprocess import prepare
from control.identification.rigid import RobotRegressor
from tests.unit.test_ident_guard import ARM, _run


def test_a_negative_viscous_coefficient_is_held_at_zero_and_a_physical_one_is_kept():
    m = _run()  # J1 Coulomb 3 N·m, J2 1 N·m, no viscous
    m.tau[:, 1] -= 2.0 * m.dq[:, 1]  # J2's torque falls with speed: no friction does that
    data = prepare(m, 200.0, 10.0, 40.0)
    ctx = make_context(RobotRegressor(ARM), data)
    ev = plain_least_squares(ctx, data.tau, contiguous_folds(data.n_samples, 5))
    j1, j2 = (PlainJoint.from_coef(j, ev.solution.coef[plain_key(j)]) for j in (0, 1))
    assert j2.viscous_nm_s_per_rad == 0.0 and j2.coulomb_nm >= 0.0
    assert abs(j1.coulomb_nm - 3.0) < 0.1 and j1.viscous_nm_s_per_rad > -1e-9
    assert np.all(np.isfinite(ev.cv_sse)) and ev.solution.coef[plain_key(1)].size == j2.coef.size
