"""Fit, model file, cylinders, preprocessing and the command line of `leadthrough analyze`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from cylinder_recordings import RATE_HZ, write_recordings

from control.identification.analyze import analyze
from control.identification.cli import cli_main, configure_parser
from control.identification.datafile import Measurements, read_measurements, write_measurements
from control.identification.dh_urdf import PANDA_DH_ROWS, urdf_from_dh
from control.identification.fit import remove_cylinders
from control.identification.model import IdentifiedModel
from control.identification.preprocess import (
    DEFAULT_STICK_VELOCITY_RAD_S,
    prepare,
    sliding_mask,
)
from control.identification.rigid import RobotRegressor
from control.identification.stages import AnalyzeOptions
from control.identification.synthetic import GR630ST_NOISE_NM
from gateway.errors import ConfigError, DataFileError
from gateway.robot.description import load_description


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure_parser(p)
    return p.parse_args(argv)


@pytest.fixture(scope="module")
def cylinder_run(tmp_path_factory) -> dict:
    """GR630ST recordings with assist cylinders (pressures wander ±15 %) analysed by the CLI."""
    root = tmp_path_factory.mktemp("ident_fit")
    desc = load_description()
    urdf, paths = write_recordings(root, desc, desc)
    reg = RobotRegressor(urdf.read_text())
    out = root / "out"
    code = cli_main(
        _parse(
            [
                "--urdf",
                str(urdf),
                "--train",
                str(paths["train"]),
                "--test",
                str(paths["test"]),
                "--out",
                str(out),
                "--no-effects",
            ]
        )
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    return {
        "root": root,
        "urdf": urdf,
        "paths": paths,
        "out": out,
        "summary": summary,
        "desc": desc,
        "reg": reg,
    }


def test_cylinder_torque_is_taken_out_before_fitting(cylinder_run):
    s = cylinder_run["summary"]
    assert s["cylinders_removed"] is True
    floor = np.asarray(GR630ST_NOISE_NM) * np.sqrt(2 * 40.0 / RATE_HZ)
    before = np.asarray(s["rms_before"])
    # the test run is faster than the training run on some joints; there the friction is
    # held at the training envelope's edge (bounded extrapolation), which costs accuracy
    inside = np.asarray(s["test_outside_envelope"]["per_joint"]) < 0.05
    assert np.all(before[inside] < 1.5 * floor[inside]), before
    assert np.all(before < 2.0 * floor), before
    # no effects: "after" differs from "before" only where the guard gave a joint a fallback
    after = np.asarray(s["rms_after"])
    moved = [j + 1 for j in np.flatnonzero(np.abs(after - before) > 1e-12 * before)]
    assert set(moved) <= {int(j) for j in s["fallback_joints"]}
    assert np.all(after <= before * (1 + 1e-12))
    assert set(s["friction_comparison"]) == {"eq14", "eq15", "simple"}
    assert {"read", "preprocess", "regressor", "fit", "effects", "validate", "total"} <= set(
        s["timing_s"]
    )
    for png in s["plots"]:
        assert (cylinder_run["out"] / png).stat().st_size > 0


def test_the_raw_held_out_error_is_raw_torque_minus_leadthrough_predict(cylinder_run):
    """raw.rms_after: the measured torque of the test file, unfiltered, minus what `leadthrough
    predict` writes for it, over every row it answers from where the figures start (after the
    test rows the guard's second look used, when it switched a joint), and it is that of a
    model at the noise: within what the analysis target's bound on the filtered floor allows
    the model's error, added to the raw noise in quadrature."""
    from control.identification.predict_cli import cli_main as predict_main
    from control.identification.predict_cli import configure_parser as predict_parser

    p = argparse.ArgumentParser()
    predict_parser(p)
    out = cylinder_run["root"] / "pred.csv"
    test_csv = cylinder_run["paths"]["test"]
    args = ["--model", str(cylinder_run["out"] / "model.json"), "--data", str(test_csv)]
    assert predict_main(p.parse_args([*args, "--out", str(out)])) == 0
    # the arithmetic done here on the two files as text, not with the product's reader
    pred = np.genfromtxt(out, delimiter=",", names=True)
    raw = np.genfromtxt(test_csv, delimiter=",", names=True)
    s = cylinder_run["summary"]
    rows = raw["t"] >= s["test_time_scored_s"][0] - 1e-9
    names = [f"tau{j}" for j in range(1, 7)]
    err = np.column_stack([raw[c] - pred[c] for c in names])[rows]
    assert np.isfinite(err).all()
    rms = np.sqrt(np.mean(err**2, axis=0))
    np.testing.assert_allclose(rms, s["raw"]["rms_after"], rtol=1e-9)
    assert s["raw"]["rows_scored"] == err.shape[0] and s["raw"]["rows_declined"] == 0
    # as test_cylinder_torque_is_taken_out_before_fitting: 1.5 x the filtered floor where the
    # test run stays inside the training envelope, 2 x elsewhere (bounded extrapolation)
    noise = np.asarray(GR630ST_NOISE_NM)
    filtered = noise * np.sqrt(2 * 40.0 / RATE_HZ)
    inside = np.asarray(s["test_outside_envelope"]["per_joint"]) < 0.05
    k = np.where(inside, 1.5, 2.0)
    assert np.all(rms < np.sqrt(noise**2 + (k**2 - 1) * filtered**2)), rms


def test_model_file_reproduces_the_analysis_target_figures(cylinder_run):
    model = IdentifiedModel.load(cylinder_run["out"] / "model.json")
    assert model.joint_names == ("j1", "j2", "j3", "j4", "j5", "j6")
    assert model.friction_kind == "eq15"
    test = model.prepare(read_measurements(cylinder_run["paths"]["test"]))
    # the cylinders as the identification measured them (control/identification/cylinders.py)
    desc = model.with_measured_cylinders(cylinder_run["desc"])
    test = remove_cylinders(test, model.regressor, desc)
    error = test.tau - model.predict_measured(test)
    window_s = 1.0 / model.metadata["torque_cutoff_hz"]
    on = sliding_mask(test, DEFAULT_STICK_VELOCITY_RAD_S, window_s)
    scored = slice(*cylinder_run["summary"]["test_rows_scored"])  # the rows the figures cover
    error, on = error[scored], on[scored]
    rms = np.sqrt(np.mean(error**2, axis=0))
    np.testing.assert_allclose(rms, cylinder_run["summary"]["rms_after_all_samples"], rtol=1e-9)
    # rms_after: the rows where each joint slides (preprocess.sliding_mask)
    assert 0.5 < on.mean() < 1.0, "the run has stuck rows, and mostly sliding ones"
    sliding = np.sqrt((error**2 * on).sum(axis=0) / on.sum(axis=0))
    np.testing.assert_allclose(sliding, cylinder_run["summary"]["rms_after"], rtol=1e-9)


def test_model_evaluation_is_vectorised_and_consistent(cylinder_run):
    model = IdentifiedModel.load(cylinder_run["out"] / "model.json")
    rng = np.random.default_rng(9)
    q = rng.uniform(-0.5, 0.5, size=(5, 6))
    dq = rng.uniform(-0.5, 0.5, size=(5, 6))
    ddq = rng.uniform(-1, 1, size=(5, 6))
    batch = model.torque_nm(q, dq, ddq)
    assert batch.shape == (5, 6)
    np.testing.assert_allclose(model.torque_nm(q[2], dq[2], ddq[2]), batch[2])
    np.testing.assert_allclose(batch, model.rigid_nm(q, dq, ddq) + model.friction_nm(q, dq))
    # eq. (15) friction vanishes at rest, so the torque at rest is the gravity torque (on a
    # joint the guard gave plain least squares, plus that fit's constant offset)
    offset = np.zeros(6)
    for j, pj in model.plain_joints.items():
        offset[j] = pj.offset_nm
    np.testing.assert_allclose(
        model.gravity_nm(q) + offset, model.torque_nm(q, 0 * q, 0 * q), atol=1e-9
    )
    # and the identified gravity is the URDF's (the synthetic data came from it)
    reg = cylinder_run["reg"]
    true_g = reg.rnea(q, 0 * q, 0 * q)
    assert np.max(np.abs(model.gravity_nm(q) - true_g)) < 0.01 * np.max(np.abs(true_g))


def test_model_file_is_versioned(cylinder_run, tmp_path):
    doc = json.loads((cylinder_run["out"] / "model.json").read_text())
    assert doc["format"] == "leadthrough-model" and doc["version"] == 6
    assert len(doc["base_parameters"]["columns"]) == len(doc["base_parameters"]["values"]) == 40
    assert doc["friction"]["model"] == "eq15" and len(doc["friction"]["joints"]) == 6
    # a friction with memory is read back; a presliding travel that is not > 0 is refused
    memory = json.loads(json.dumps(doc))
    memory["friction"]["joints"][1]["presliding_rad"] = 3e-4
    (tmp_path / "memory.json").write_text(json.dumps(memory))
    loaded = IdentifiedModel.load(tmp_path / "memory.json")
    assert [t.presliding_rad for t in loaded.friction_terms][:3] == [None, 3e-4, None]
    memory["friction"]["joints"][1]["presliding_rad"] = -1.0
    (tmp_path / "memory.json").write_text(json.dumps(memory))
    with pytest.raises(DataFileError, match="joint 2: presliding_rad"):
        IdentifiedModel.load(tmp_path / "memory.json")
    doc["version"] = 1
    bad = tmp_path / "old.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(DataFileError, match="version"):
        IdentifiedModel.load(bad)
    (tmp_path / "junk.json").write_text("{")
    with pytest.raises(DataFileError, match=r"junk\.json"):
        IdentifiedModel.load(tmp_path / "junk.json")


def test_the_model_file_carries_the_measurement_chain_and_older_files_read_as_none(
    cylinder_run, tmp_path
):
    doc = json.loads((cylinder_run["out"] / "model.json").read_text())
    mc = doc["measurement_chain"]
    assert len(mc["torque_gain"]) == len(mc["torque_offset_nm"]) == 6
    model = IdentifiedModel.load(cylinder_run["out"] / "model.json")
    q, dq, ddq = np.full(6, 0.3), np.full(6, 0.1), np.zeros(6)
    physical = model.torque_nm(q, dq, ddq)
    want = np.asarray(mc["torque_gain"]) * physical + np.asarray(mc["torque_offset_nm"])
    np.testing.assert_allclose(model.measured_torque_nm(q, dq, ddq), want, rtol=1e-12)
    old = {k: v for k, v in doc.items() if k != "measurement_chain"}
    old["version"] = 3
    (tmp_path / "v3.json").write_text(json.dumps(old))
    v3 = IdentifiedModel.load(tmp_path / "v3.json")
    np.testing.assert_allclose(v3.measured_torque_nm(q, dq, ddq), physical, rtol=1e-12)
    np.testing.assert_allclose(v3.torque_nm(q, dq, ddq), physical, rtol=1e-12)
    doc["measurement_chain"]["torque_gain"][0] = 0.0
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(DataFileError, match="measurement_chain"):
        IdentifiedModel.load(tmp_path / "bad.json")


@pytest.mark.parametrize(
    ("field", "joint", "value", "why"),
    [
        ("torque_gain", 2, float("nan"), "finite and > 0"),
        ("torque_gain", 3, float("inf"), "finite and > 0"),
        ("torque_gain", 1, -1.0, "finite and > 0"),
        ("torque_gain", 6, 0.0, "finite and > 0"),
        ("torque_offset_nm", 4, float("nan"), "finite"),
        ("torque_offset_nm", 5, float("-inf"), "finite"),
    ],
)
def test_a_model_file_with_a_non_finite_or_non_positive_chain_is_refused_naming_it(
    cylinder_run, tmp_path, field, joint, value, why
):
    """The channel's reading is divided by the gain and has the offset taken off: a NaN, an
    infinity or a gain <= 0 would make every torque after it meaningless, silently."""
    doc = json.loads((cylinder_run["out"] / "model.json").read_text())
    doc["measurement_chain"][field][joint - 1] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))  # NaN and Infinity as json writes (and reads) them
    name = doc["joints"][joint - 1]
    with pytest.raises(DataFileError) as err:
        IdentifiedModel.load(path)
    msg = str(err.value)
    assert f"measurement_chain.{field} of joint {joint} ({name})" in msg
    assert f"must be {why}" in msg and str(path) in msg


def test_pressures_need_matching_urdf_joints(cylinder_run, tmp_path):
    """Pressure columns with a URDF that has no joint j2/j3 of the description: clear error."""
    urdf = tmp_path / "panda.urdf"
    urdf.write_text(urdf_from_dh(PANDA_DH_ROWS[:6] + PANDA_DH_ROWS[7:], "modified", "six"))
    args = _parse(
        [
            "--urdf",
            str(urdf),
            "--train",
            str(cylinder_run["paths"]["train"]),
            "--test",
            str(cylinder_run["paths"]["test"]),
            "--out",
            str(tmp_path / "o"),
            "--no-plots",
            "--no-effects",
        ]
    )
    with pytest.raises(ConfigError, match="no matching joint 2 named 'j2'"):
        cli_main(args)


def test_joint_count_mismatch_names_the_file(cylinder_run, tmp_path):
    urdf = tmp_path / "panda.urdf"
    urdf.write_text(urdf_from_dh(PANDA_DH_ROWS, "modified", "panda"))
    train = cylinder_run["paths"]["train"]
    args = _parse(
        [
            "--urdf",
            str(urdf),
            "--train",
            str(train),
            "--test",
            str(train),
            "--out",
            str(tmp_path / "o"),
        ]
    )
    with pytest.raises(DataFileError, match=rf"{train}:1: has 6 joints"):
        cli_main(args)


def test_bad_command_line_values_are_config_errors(cylinder_run, tmp_path):
    train = str(cylinder_run["paths"]["train"])
    common = [
        "--urdf",
        str(cylinder_run["urdf"]),
        "--train",
        train,
        "--test",
        train,
        "--out",
        str(tmp_path),
    ]
    with pytest.raises(ConfigError, match="--gravity"):
        cli_main(_parse([*common, "--gravity", "0,0"]))
    with pytest.raises(ConfigError, match="--gear-ratios"):
        cli_main(_parse([*common, "--gear-ratios", "1,2,x"]))
    with pytest.raises(ConfigError, match="--margin"):
        cli_main(_parse([*common, "--margin", "1.5"]))


# -- preprocessing ----------------------------------------------------------------------------


def _sine_measurements(t: np.ndarray, freq_hz: float = 0.5) -> Measurements:
    w = 2 * np.pi * freq_hz
    q = np.sin(w * t)[:, None]
    return Measurements(t=t, q=q, dq=None, tau=np.cos(w * t)[:, None], p=None, source="sine.csv")


def test_preprocess_is_zero_phase_and_differentiates_accurately():
    t = np.arange(0, 20, 1e-3)
    w = 2 * np.pi * 0.5
    d = prepare(_sine_measurements(t), rate_hz=200.0)
    assert d.rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(d.q[:, 0], np.sin(w * d.t), atol=1e-4)
    np.testing.assert_allclose(d.dq[:, 0], w * np.cos(w * d.t), atol=1e-3 * w)
    np.testing.assert_allclose(d.ddq[:, 0], -(w**2) * np.sin(w * d.t), atol=2e-3 * w**2)
    np.testing.assert_allclose(d.tau[:, 0], np.cos(w * d.t), atol=1e-4)


def test_preprocess_resamples_jittered_time_and_splits_at_gaps():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.7e-3, 1.3e-3, 20_000))
    t[10_000:] += 1.0  # a one-second gap
    d = prepare(_sine_measurements(t))
    assert set(np.unique(d.segment)) == {0, 1}
    w = 2 * np.pi * 0.5
    np.testing.assert_allclose(d.q[:, 0], np.sin(w * d.t), atol=1e-3)


def test_position_jump_is_refused_with_its_line():
    t = np.arange(0, 2, 1e-3)
    m = _sine_measurements(t)
    q = m.q.copy()
    q[500:, 0] += 2 * np.pi  # a wrapped angle
    bad = Measurements(t=t, q=q, dq=None, tau=m.tau, p=None, source="wrapped.csv")
    with pytest.raises(DataFileError, match=r"wrapped.csv:502: q1 jumps"):
        prepare(bad)


def test_too_short_file_is_refused():
    t = np.arange(0, 0.1, 1e-3)
    with pytest.raises(DataFileError, match="too short"):
        prepare(_sine_measurements(t))


def test_identify_leaves_out_a_file_chopped_too_short_and_says_so(cylinder_run, tmp_path):
    """`identify` exports segments with disturbed cycles cut out; one left with nothing long
    enough to filter is reported and left out, where `analyze` alone refuses it."""
    m = read_measurements(cylinder_run["paths"]["train"])
    short = tmp_path / "short.csv"
    write_measurements(short, Measurements(m.t[:60], m.q[:60], None, m.tau[:60], m.p[:60],
                                           str(short), m.p_joints))  # fmt: skip
    train = [cylinder_run["paths"]["train"], short]
    opts = AnalyzeOptions(find_effects=False, plots=False, compare_friction=False)
    with pytest.raises(DataFileError, match=r"short\.csv: too short"):
        analyze(cylinder_run["urdf"], train, [cylinder_run["paths"]["test"]], tmp_path / "a", opts,
                progress=lambda _: None)  # fmt: skip
    opts = AnalyzeOptions(
        find_effects=False, plots=False, compare_friction=False, skip_short_files=True
    )
    summary = analyze(cylinder_run["urdf"], train, [cylinder_run["paths"]["test"]],
                      tmp_path / "b", opts, progress=lambda _: None)  # fmt: skip
    assert len(summary["files_left_out"]) == 1 and "short.csv" in summary["files_left_out"][0]
    assert "Left out:" in (tmp_path / "b" / "report.md").read_text()
    reference = cylinder_run["summary"]["rms_after"]
    np.testing.assert_allclose(summary["rms_after"], reference, rtol=0.05)


def test_other_friction_families_give_loadable_models(cylinder_run, tmp_path):
    paths = cylinder_run["paths"]
    for kind in ("simple", "eq14"):
        out = tmp_path / kind
        args = _parse(
            [
                "--urdf",
                str(cylinder_run["urdf"]),
                "--train",
                str(paths["train"]),
                "--test",
                str(paths["test"]),
                "--out",
                str(out),
                "--friction",
                kind,
                "--no-effects",
                "--no-plots",
            ]
        )
        assert cli_main(args) == 0
        model = IdentifiedModel.load(out / "model.json")
        assert model.friction_kind == kind
        assert model.friction_nm(np.zeros(6), np.full(6, 0.3)).shape == (6,)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["friction_model"] == kind
        assert Path(out / "report.md").read_text().startswith("# Identification report")


def test_control_process_loads_the_identified_model(cylinder_run, tmp_path):
    """The versioned model file is what the control process compensates with."""
    from example_cell import example_cell

    from control.cell_config import load_control_config
    from control.declared_model import DeclaredModel, IdentifiedControlModel
    from control.model.dynamics import RigidBodyModel
    from control.zero_moment_law import ZeroMomentController
    from gateway.message_factories import make_joint_state
    from gateway.messages import ControllerState

    model = DeclaredModel.load(cylinder_run["out"] / "model.json")
    assert isinstance(model, IdentifiedControlModel)
    # the held-out error the rest hold sizes its band by (control/rt/src/law/rest_hold.rs)
    summary = json.loads((cylinder_run["out"] / "summary.json").read_text())
    np.testing.assert_allclose(model.heldout_rms_nm, summary["rms_after"])
    desc = load_description()
    truth = RigidBodyModel.from_description(desc)
    rng = np.random.default_rng(5)
    for q in rng.uniform(desc.lower_rad * 0.5, desc.upper_rad * 0.5, size=(5, 6)):
        np.testing.assert_allclose(model.gravity_nm(q), truth.gravity_nm(q), atol=3.0)
        assert np.all(np.isfinite(model.friction_nm(q, np.full(6, 0.1))))
    cfg, _ = load_control_config(
        example_cell(tmp_path, model=str(cylinder_run["out"] / "model.json"))
    )
    ctl = ZeroMomentController(cfg, model)
    q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
    st = make_joint_state(1, 0.0, ControllerState.EXTERNAL, 0, q, np.zeros(6), np.zeros(6), q,
                          np.zeros(6), 0.008)  # fmt: skip
    cmd = ctl.update(st, np.array([6.0, 4.0]), 0.0)
    assert np.all(np.isfinite(cmd.q_cmd_rad)) and np.all(np.isfinite(cmd.dq_cmd_rad_s))
