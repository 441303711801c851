"""Stage 4 of ``leadthrough analyze`` (:mod:`.analyze`): rigid body + friction fitted on the
training files.

The eq. (14), eq. (15) and simple friction families are each fitted (:func:`.fit.
fit_rigid_friction`, side by side in worker processes, :mod:`.parallel`) and, with
``--friction auto`` (the default), the one with the lowest held-out (contiguous K-fold) error
on the *training* files is kept (:func:`choose_family`) — never chosen on the test files. The
assist cylinders' force, fitted along, is then judged and settled (:mod:`.cylinders`). The
rigid-body base parameters are pulled towards the URDF's nominal values where the training
motion hardly excites them (:data:`RIGID_PRIOR_RIDGE`); :func:`_excitation_report` says how
well it excites each.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from control.identification import cylinders as cyl
from control.identification.fit import FrictionFit, fit_rigid_friction, model_from_solution
from control.identification.friction_law import FRICTION_PARAM_NAMES
from control.identification.lsq import BlockLS
from control.identification.model import IdentifiedModel
from control.identification.parallel import map_forked
from control.identification.rigid import RobotRegressor
from control.identification.stages import AUTO, _Clock, _Run
from control.identification.terms import Context, RigidTerm
from control.identification.validate import rms

#: Ridge that pulls the rigid-body base parameters towards the URDF's nominal values, per
#: column of the scaled problem (:meth:`.lsq.BlockLS.set_prior`): directions the training
#: motion excites less than about 1/1000 of the best (sqrt(VIF) above ~10³) keep the URDF's
#: values instead of whatever noise and mismatch make of them, which would then be
#: extrapolated outside the training envelope; well-excited ones are not moved.
RIGID_PRIOR_RIDGE = 1e-6
#: sqrt(VIF) above which a base parameter counts as not identified by the training motion.
NOT_IDENTIFIED_SQRT_VIF = 1e3


def _predict(
    reg: RobotRegressor,
    ctx: Context,
    fit: FrictionFit,
    urdf: str,
    meta: dict[str, Any],
    cyl_cols: dict[int, np.ndarray] | None = None,
) -> tuple[IdentifiedModel, np.ndarray]:
    """The model of ``fit`` and what it predicts on ``ctx``; a fit with the cylinder columns
    (:mod:`.cylinders`) adds their part, on ``cyl_cols`` (those of ``ctx``'s rows)."""
    model = model_from_solution(reg, fit, fit.evaluation.solution, [], urdf, meta)
    pred = model.torque_from_context(ctx)
    coef = fit.evaluation.solution.coef.get(cyl.GROUP)
    if coef is not None and cyl_cols is not None:
        pred = pred + cyl.contribution(cyl_cols, np.asarray(coef, dtype=float), reg.n)
    return model, pred


def _settle_cylinders(
    ls: BlockLS, run: _Run, fit: FrictionFit
) -> tuple[FrictionFit, cyl.Calibration]:
    """The cylinder columns of ``fit`` judged (:func:`.cylinders.judge`) and taken out of the
    fit: kept, their part is taken out of the training and test targets as measured cylinder
    torque (``run.train``, ``run.test`` and ``ls`` get the corrected torque), refused, the
    targets stay; either way ``fit`` comes back without them, solved again, and
    ``run.meta["cylinders"]`` says what was done (the model file carries it)."""
    assert run.cyl_train is not None and run.cyl_test is not None and run.desc is not None
    names = [name for name in fit.names if name != cyl.GROUP]
    without = ls.evaluate(names, fit.weights)
    coef = np.asarray(fit.evaluation.solution.coef[cyl.GROUP], dtype=float)
    cal = cyl.judge(run.desc, coef, fit.evaluation.cv_rms, without.cv_rms)
    ls.remove(cyl.GROUP)
    evaluation = without
    if cal.any_kept:
        n = run.reg.n
        run.train = run.train.with_tau(run.train.tau - cyl.contribution(run.cyl_train, cal.coef, n))
        run.test = run.test.with_tau(run.test.tau - cyl.contribution(run.cyl_test, cal.coef, n))
        ls.set_y(run.train.tau)
        evaluation = ls.evaluate(names, fit.weights)
    run.meta["cylinders"] = cal.to_json()
    for j, s, why in zip(cal.joints, cal.scale, cal.reasons, strict=True):
        run.clock.say(f"cylinder on J{j + 1}: force scale {s:.4g}, {why}")
    return replace(fit, evaluation=evaluation, extra=()), cal


def _fit_families(
    ls: BlockLS,
    run: _Run,
    kinds: Sequence[str],
    ratios: np.ndarray,
    while_waiting: Callable[[], None] | None = None,
) -> tuple[dict[str, FrictionFit], dict[str, Any]]:
    """Each friction family fitted on ``ls`` (groups left there) and its figures;
    ``while_waiting()`` runs in this process while workers fit them."""
    fits: dict[str, FrictionFit] = {}
    comparison: dict[str, Any] = {}

    if "rigid" not in ls.cols:
        ls.add("rigid", RigidTerm().columns(run.ctx_train))
    extra = [cyl.GROUP] if cyl.GROUP in ls.cols else []

    def fit_one(kind: str) -> tuple[FrictionFit, dict[str, Any], list[str]]:
        lines: list[str] = []
        own = ls.fork()
        fit = fit_rigid_friction(
            own, run.ctx_train, kind, ratios, progress=lines.append, extra=extra
        )
        return fit, own.export([t.key for t in fit.terms]), lines

    # the families are independent searches: side by side on a fork of ``ls`` each, in worker
    # processes (:mod:`.parallel`); the costliest first. This process meanwhile imports what
    # the plots will need.
    order = sorted(kinds, key=lambda k: -len(FRICTION_PARAM_NAMES[k]))
    done = dict(zip(order, map_forked(fit_one, order, while_waiting=while_waiting), strict=True))
    for kind in kinds:
        fit, groups, lines = done[kind]
        for line in lines:
            run.clock.say(line)
        ls.adopt(groups)
        fits[kind] = fit
        _, pred = _predict(run.reg, run.ctx_test, fit, str(run.urdf), run.meta, run.cyl_test)
        comparison[kind] = {
            "rms_train": fit.evaluation.fit_rms.tolist(),
            "rms_train_cv": fit.evaluation.cv_rms.tolist(),
            "rms_test": rms(run.test.tau - pred).tolist(),
            "q_e_rad_s": [t.q_e_rad_s for t in fit.terms],
            "sign_width_rad_s": [t.sign_width_rad_s for t in fit.terms],
        }
    return fits, comparison


def _keep_family(ls: BlockLS, fits: dict[str, FrictionFit], friction: str, clock: _Clock) -> str:
    """The family kept (``--friction``, or :func:`choose_family` for auto); the others' groups
    leave ``ls``."""
    kind = choose_family(fits) if friction == AUTO else friction
    if friction == AUTO:
        clock.say(f"friction family {kind}: lowest held-out error on the training files")
    for other, fit in fits.items():
        if other != kind:
            for term in fit.terms:
                ls.remove(term.key)
    return kind


def choose_family(fits: dict[str, FrictionFit]) -> str:
    """The friction family with the lowest held-out error on the training files.

    Joints carry torques of very different size, so each joint's held-out MSE is divided by
    the best family's on that joint before summing: a family is judged by how much worse than
    the best it does, joint by joint, not by the largest joint alone. A joint without rows
    (it never slid) has no say.
    """
    mse = {k: f.evaluation.cv_rms**2 for k, f in fits.items()}
    judged = np.isfinite(np.array(list(mse.values()))).all(axis=0)
    best = np.min(np.array(list(mse.values()))[:, judged], axis=0)
    scale = np.where(best > 0, best, 1.0)
    return min(mse, key=lambda k: float(np.sum(mse[k][judged] / scale)))


def _excitation_report(
    reg: RobotRegressor, ls: BlockLS, fit: FrictionFit, evaluation: Any
) -> dict[str, Any]:
    """The base parameters: how many are rigid-body and armature, how well the training data
    excite each (sqrt(VIF), :meth:`.lsq.BlockLS.excitation`), the fitted and the URDF's
    nominal value, and which ones the data could not identify (kept near nominal)."""
    base = reg.base
    names = base.base_names
    armature = [n.endswith(".armature") for n in names]
    sqrt_vif = ls.excitation("rigid", fit.weights)
    nominal = base.base_values(reg.parameters())
    fitted = evaluation.solution.coef["rigid"]
    rows = [
        {
            "name": name,
            "definition": definition,
            "sqrt_vif": float(v) if np.isfinite(v) else None,
            "fitted": float(b),
            "nominal_urdf": float(b0),
        }
        for name, definition, v, b, b0 in zip(
            names, base.definitions(), sqrt_vif, fitted, nominal, strict=True
        )
    ]
    return {
        "count": base.n_base,
        "rigid_body": int(base.n_base - sum(armature)),
        "armature": int(sum(armature)),
        "computed_from": "pivoted QR of the regressor over random configurations within the "
        "URDF's joint limits (not the recorded data)",
        "not_identified": [
            r["name"]
            for r in rows
            if r["sqrt_vif"] is None or r["sqrt_vif"] > NOT_IDENTIFIED_SQRT_VIF
        ],
        "not_identified_rule": f"sqrt(VIF) > {NOT_IDENTIFIED_SQRT_VIF:g} on the weighted "
        "training data; such directions stay near the URDF's nominal values (ridge "
        f"{RIGID_PRIOR_RIDGE:g} per scaled column)",
        "parameters": rows,
    }
