"""The guard of ``analyze`` (:func:`control.identification.guard.guard_joints`): a joint whose
model does worse on held-out training folds than plain least squares, the URDF's nominal rigid
body with Coulomb/viscous friction, or zero falls back to the best of them; the choice is in
the model file."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from control.identification.datafile import Measurements
from control.identification.fit import make_context
from control.identification.folds import CONTIGUOUS, Scheme
from control.identification.guard import GuardFolds, guard_joints
from control.identification.lsq import BlockLS, Evaluation, contiguous_folds
from control.identification.model import IdentifiedModel
from control.identification.preprocess import prepare
from control.identification.rigid import RobotRegressor
from control.identification.stages import AnalyzeOptions
from control.identification.terms import FrictionTerm, RigidTerm

ARM = """<robot name="two">
  <link name="base"/>
  <link name="l1"><inertial><origin xyz="0.3 0 0"/><mass value="12"/>
    <inertia ixx="0.05" ixy="0" ixz="0" iyy="0.4" iyz="0" izz="0.4"/></inertial></link>
  <link name="l2"><inertial><origin xyz="0.2 0 0.05"/><mass value="4"/>
    <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="500" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.6 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="500" velocity="2"/></joint>
</robot>"""


def _run() -> Measurements:
    rng = np.random.default_rng(5)
    t = np.arange(12_000) / 200.0
    w = 2 * np.pi * np.array([[0.13, 0.29], [0.17, 0.41]])
    q = np.column_stack([0.7 * np.sin(w[j, 0] * t) + 0.3 * np.sin(w[j, 1] * t + j) for j in (0, 1)])
    dq = np.column_stack(
        [
            0.7 * w[j, 0] * np.cos(w[j, 0] * t) + 0.3 * w[j, 1] * np.cos(w[j, 1] * t + j)
            for j in (0, 1)
        ]
    )
    ddq = np.gradient(dq, t, axis=0)
    model = pin.buildModelFromXML(ARM)
    data = model.createData()
    tau = np.array([pin.rnea(model, data, a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)])
    tau += np.array([3.0, 1.0]) * np.sign(dq) + 0.2 * rng.standard_normal(tau.shape)
    return Measurements(t, q, dq, tau, None, source="two.csv")


def test_a_joint_worse_than_its_fallbacks_gets_the_best_one():
    reg = RobotRegressor(ARM)
    data = prepare(_run(), 200.0, 10.0, 40.0)
    ctx = make_context(reg, data)
    folds = contiguous_folds(data.n_samples, 5)
    ls = BlockLS(data.tau, folds)
    ls.add("rigid", RigidTerm().columns(ctx))
    names = ["rigid"]
    for j in range(2):
        term = FrictionTerm(j, "simple", 0.002, 1.0)
        ls.add(term.key, term.columns(ctx))
        names.append(term.key)
    good = ls.evaluate(names, np.ones(2))
    # the same model, its joint-1 held-out error pretended 100x worse, joint 2's better
    sse = good.cv_sse * [1e4, 0.5]
    bad = Evaluation(good.fit_sse, sse, good.rank, good.n_rows, good.solution)
    guard = guard_joints(
        reg,
        ctx,
        data.tau,
        None,
        [GuardFolds(Scheme(CONTIGUOUS, folds, None, 0.0, 1.0), bad)],
        AnalyzeOptions(),
    )
    assert guard[1].fallback is None
    fallback = guard[0].fallback
    # the data are the URDF's own rigid body + Coulomb: the nominal fallback fits them best
    assert fallback is not None and fallback.kind == "nominal"
    np.testing.assert_allclose(fallback.beta, reg.base.base_values(reg.parameters()))
    assert abs(fallback.coulomb_nm - 3.0) < 0.2
    cv = guard[0].cv_rms
    assert cv["nominal"] < cv["plain_ls"] < cv["zero"] and cv["nominal"] < cv["model"]
    assert guard[0].to_json()["kept"] == "nominal"
    assert guard[0].reason.endswith("nominal kept")


def test_fallback_kind_is_saved_and_loaded(tmp_path):
    from control.identification.analyze import analyze
    from control.identification.datafile import write_measurements

    m = _run()
    half = m.t.size // 2
    for name, rows in (("train", slice(0, half)), ("test", slice(half, None))):
        write_measurements(
            tmp_path / f"{name}.csv",
            Measurements(m.t[rows], m.q[rows], m.dq[rows], m.tau[rows], None, source=name),
        )
    (tmp_path / "two.urdf").write_text(ARM)
    summary = analyze(
        tmp_path / "two.urdf",
        [tmp_path / "train.csv"],
        [tmp_path / "test.csv"],
        tmp_path / "out",
        AnalyzeOptions(plots=False, find_effects=False),
        progress=lambda _line: None,
    )
    kept = [g["kept"] for g in summary["guard"]["joints"]]
    assert set(kept) <= {"model", "plain_ls", "nominal", "zero"} and len(kept) == 2
    model = IdentifiedModel.load(tmp_path / "out" / "model.json")
    saved = {j + 1: pj.kind for j, pj in model.plain_joints.items()}
    assert saved == {int(j): kind for j, kind in summary["fallback_joints"].items()}
    # what the training guard gave a fallback keeps one (the second look may add others)
    trained = {g["joint"]: g["kept"] for g in summary["guard"]["joints"] if g["kept"] != "model"}
    assert set(trained) <= set(saved)


def test_the_second_look_on_the_test_run_keeps_what_extrapolates_best():
    """On the raw rows of the test run's leading part a joint keeps the lowest error of what
    the training guard kept, plain least squares and zero, every row counted; ties keep the
    training guard's choice; a row one model declines counts for none; too few rows that all
    answer decide nothing."""
    from control.identification.guard import TEST_GUARD_MIN_ROWS, guard_on_test

    rng = np.random.default_rng(2)
    t = 2 * TEST_GUARD_MIN_ROWS
    tau = rng.standard_normal((t, 3)) * [10.0, 1.0, 0.01]
    chosen = rng.standard_normal((t, 3)) * [0.1, 3.0, 0.0]  # residuals: measured - predicted
    plain = rng.standard_normal((t, 3)) * [1.0, 0.5, 0.0]
    errors = {"chosen": chosen, "plain_ls": plain, "zero": tau}
    g = guard_on_test(errors, (0, 100), ["model", "nominal", "model"])
    assert g is not None and g.kept == ["model", "plain_ls", "model"]  # joint 3: a tie
    assert g.rms[1]["nominal"] > g.rms[1]["plain_ls"]
    assert g.to_json()["joints"][1]["kept"] == "plain_ls" and g.to_json()["rows"] == [0, 100]
    zero_wins = guard_on_test(
        {"chosen": 5 * tau, "plain_ls": 3 * tau, "zero": tau}, (0, 1), ["model"] * 3
    )
    assert zero_wins is not None and zero_wins.kept == ["zero"] * 3
    # joint 2's plain least squares, best where it moves, misses a stop by 20 N·m: counted,
    # that stop hands the joint to zero (1 N·m off everywhere)
    plain[: TEST_GUARD_MIN_ROWS // 4, 1] += 20.0
    assert guard_on_test(errors, (0, 100), ["model"] * 3).kept[1] == "zero"
    declined = plain.copy()
    declined[: t - TEST_GUARD_MIN_ROWS + 1, 0] = np.nan
    assert guard_on_test({**errors, "plain_ls": declined}, (0, 100), ["model"] * 3) is None


def test_the_second_look_judges_each_fallback_with_the_load_that_appeared_between_the_runs():
    """An effect fitted between the runs (a tool mounted) weighs on a joint whatever predicts
    the rest of its torque: the second look compares whole models that each carry it. A
    plain fit of the arm alone that is better than the model then wins on that joint; judged
    without the tool it would lose, and the joint would keep the model."""
    from control.identification.guard import TEST_GUARD_MIN_ROWS, guard_on_test

    rng = np.random.default_rng(3)
    t = 3 * TEST_GUARD_MIN_ROWS
    rigid = rng.standard_normal((t, 2)) * [10.0, 1.0]
    tool = np.column_stack([np.full(t, 30.0), np.zeros(t)])  # [N·m] on joint 1 only
    tau = rigid + tool + 0.1 * rng.standard_normal((t, 2))
    plain_arm = rigid + 0.2 * rng.standard_normal((t, 2))  # a better fit of the arm alone
    model = rigid + tool + 1.0 * rng.standard_normal((t, 2))  # the model, tool included
    with_tool = {"chosen": tau - model, "plain_ls": tau - plain_arm - tool, "zero": tau - tool}
    blind = {**with_tool, "plain_ls": tau - plain_arm, "zero": tau}
    assert guard_on_test(blind, (0, t), ["model"] * 2).kept == ["model", "plain_ls"]
    g = guard_on_test(with_tool, (0, t), ["model"] * 2)
    assert g is not None and g.kept == ["plain_ls", "plain_ls"]
    assert 0.15 < g.rms[0]["plain_ls"] < 0.3  # about its own 0.2 once the tool is carried
    assert g.rms[0]["zero"] > 5.0  # zero carries the tool too, not the arm's own torque
