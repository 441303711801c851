"""The assist cylinders' force measured with the arm (control/identification/cylinders.py)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from cylinder_recordings import RATE_HZ, write_recordings

from control.declared_model import IdentifiedControlModel
from control.identification import cylinders as cyl
from control.identification.cli import cli_main, configure_parser
from control.identification.synthetic import GR630ST_NOISE_NM
from control.model.cylinders import cylinder_torque_nm, with_measured_cylinders
from gateway.errors import ConfigError
from gateway.robot.description import RobotDescription, load_description

#: The recorded arm's cylinders against the description: J2's bore 6 % and J3's 8 % wider
#: (forces × 1.124 and × 1.166), within a datasheet's and a linkage's tolerances together.
BORE_FACTORS = (1.06, 1.08)


def _stronger(desc: RobotDescription) -> RobotDescription:
    cylinders = tuple(
        dataclasses.replace(c, piston_diameter_m=c.piston_diameter_m * f)
        for c, f in zip(desc.cylinders, BORE_FACTORS, strict=True)
    )
    return dataclasses.replace(desc, cylinders=cylinders)


@pytest.fixture(scope="module")
def stronger_run(tmp_path_factory) -> dict:
    """GR630ST recordings of an arm whose cylinders push harder than described (pressures
    wander ±15 %), analysed by the CLI with the packaged (described) cylinders."""
    root = tmp_path_factory.mktemp("ident_cyl")
    desc = load_description()
    urdf, paths = write_recordings(root, desc, _stronger(desc))
    out = root / "out"
    p = argparse.ArgumentParser()
    configure_parser(p)
    argv = ["--urdf", str(urdf), "--train", str(paths["train"]), "--test", str(paths["test"])]
    assert cli_main(p.parse_args([*argv, "--out", str(out), "--no-effects", "--no-plots"])) == 0
    summary = json.loads((out / "summary.json").read_text())
    return {"out": out, "summary": summary, "desc": desc, "test": paths["test"]}


def test_a_stronger_cylinder_is_measured_within_two_percent_and_kept(stronger_run):
    cal = stronger_run["summary"]["cylinders"]
    truth = np.square(BORE_FACTORS)
    for c, want in zip(cal["cylinders"], truth, strict=True):
        assert c["kept"], c
        # 2 %: the rigid body shares part of each cylinder's shape (J3's cos q3 against the
        # forearm's gravity); on 40 s of ±15 % pressure at the noise floor the split stays
        # within a fraction of the tolerance the scale is there to measure (8-17 %)
        assert abs(c["torque_scale"] / want - 1) < 0.02, (c, want)
        assert c["piston_diameter_m"] == pytest.approx(
            c["described_piston_diameter_m"] * np.sqrt(c["torque_scale"])
        )
    with_cv = np.asarray(cal["heldout_rms_training_folds_nm"]["with"])
    without_cv = np.asarray(cal["heldout_rms_training_folds_nm"]["without"])
    assert np.all(with_cv[[1, 2]] < without_cv[[1, 2]])


def test_the_held_out_error_with_a_stronger_cylinder_stays_at_the_noise_floor(stronger_run):
    s = stronger_run["summary"]
    # the noise floor after the analysis's 40 Hz torque filter (as test_ident_fit's figure)
    floor = np.asarray(GR630ST_NOISE_NM) * np.sqrt(2 * 40.0 / RATE_HZ)
    assert np.all(np.asarray(s["rms_before"])[[1, 2]] < 2.0 * floor[[1, 2]]), s["rms_before"]


def test_the_control_model_adds_the_measured_cylinders_back(stronger_run):
    model = IdentifiedControlModel(stronger_run["out"] / "model.json")
    truth = _stronger(stronger_run["desc"])
    q = np.array([0.1, 0.3, -0.4, 0.0, 0.2, 0.0])
    p = np.array([5.5, 4.2])
    want = cylinder_torque_nm(q, p, truth)
    got = np.asarray(model.point.cylinder_torques_nm(q.tolist(), p.tolist()))
    np.testing.assert_allclose(got[[1, 2]], want[[1, 2]], rtol=0.02)
    np.testing.assert_allclose(model.cylinder_nm(q, p), got, rtol=1e-12, atol=1e-12)


def _entry(j: int, described: float, measured: float) -> dict:
    return {
        "joint_index": j,
        "described_piston_diameter_m": described,
        "piston_diameter_m": measured,
    }


def test_measured_cylinders_apply_once_and_refuse_another_cylinder():
    desc = load_description()
    d2 = desc.cylinders[1].piston_diameter_m
    measured = [_entry(2, d2, 1.1 * d2)]
    once = with_measured_cylinders(desc, measured, "m")
    assert once.cylinders[1].piston_diameter_m == pytest.approx(1.1 * d2)
    assert once.cylinders[0] == desc.cylinders[0]
    assert with_measured_cylinders(once, measured, "m") == once  # idempotent
    other = dataclasses.replace(
        desc,
        cylinders=(
            desc.cylinders[0],
            dataclasses.replace(desc.cylinders[1], piston_diameter_m=0.2),
        ),
    )
    with pytest.raises(ValueError, match="J3 cylinder was measured on a 100 mm piston"):
        with_measured_cylinders(other, measured, "m")
    with pytest.raises(ValueError, match="a cylinder on J5 was measured"):
        with_measured_cylinders(desc, [_entry(4, d2, d2)], "m")
    with pytest.raises(ValueError, match="piston diameter"):
        with_measured_cylinders(desc, [_entry(2, d2, -1.0)], "m")


def test_a_model_measured_on_another_cylinder_is_refused_by_name(stronger_run, tmp_path):
    doc = json.loads((stronger_run["out"] / "model.json").read_text())
    doc["analysis"]["cylinders"]["cylinders"][1]["described_piston_diameter_m"] = 0.3
    bad = tmp_path / "model.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match=r"model.json: analysis.cylinders: J3 cylinder"):
        IdentifiedControlModel(Path(bad))


def test_judge_keeps_each_cylinder_on_its_own_joint_and_refuses_implausible_scales():
    desc = load_description()
    without = np.array([1.0, 2.0, 3.0, 0.1, 0.1, 0.1])
    with_ = np.array([1.0, 1.0, 3.5, 0.1, 0.1, 0.1])  # J2 better, J3 worse
    cal = cyl.judge(desc, np.array([-0.2, -0.1]), with_, without)
    assert cal.kept == (True, False)
    assert cal.scale == pytest.approx((1.2, 1.1))
    np.testing.assert_allclose(cal.coef, [-0.2, 0.0])
    assert "does not lower J3's held-out error" in cal.reasons[1]
    d = [c.piston_diameter_m for c in desc.cylinders]
    assert cal.diameters_m() == pytest.approx([d[0] * np.sqrt(1.2), d[1]])
    # a cylinder "2.5 times as strong" is a wrong description, not a tolerance
    wild = cyl.judge(desc, np.array([-1.5, np.nan]), with_ * 0.5, without)
    assert wild.kept == (False, False)
    assert all("outside the plausible" in why for why in wild.reasons)
    assert not wild.any_kept and np.all(wild.coef == 0.0)


def test_over_a_torque_gain_the_cylinders_physical_scale_is_the_channels_over_the_gain():
    desc = load_description()
    without = np.array([1.0, 2.0, 3.0, 0.1, 0.1, 0.1])
    with_ = np.array([1.0, 1.0, 3.5, 0.1, 0.1, 0.1])  # J2's kept (1.2), J3's as described
    cal = cyl.judge(desc, np.array([-0.2, -0.1]), with_, without)
    # the channel reads gain × (rigid − cylinder): a scale fitted on it is gain × physical
    phys = cal.over_gain(np.array([1.0, 0.9, 0.8, 1.0, 1.0, 1.0]))
    assert phys.scale == pytest.approx((1.2 / 0.9, 1.0 / 0.8))
    assert phys.kept == (True, True)
    assert "gain 0.8 on J3" in phys.reasons[1]
    d = [c.piston_diameter_m for c in desc.cylinders]
    assert phys.diameters_m() == pytest.approx([d[0] * np.sqrt(1.2 / 0.9), d[1] / np.sqrt(0.8)])
    assert cal.over_gain(np.ones(6)) == cal  # gain 1: as it was


def test_predict_reads_the_cylinders_share_through_the_channels_gain(stronger_run, tmp_path):
    from control.identification.datafile import read_measurements
    from control.identification.model import IdentifiedModel
    from control.identification.predict import predict_rows

    model = IdentifiedModel.load(stronger_run["out"] / "model.json")
    gain = np.array([1.0, 0.9, 0.85, 1.0, 1.0, 1.0])
    offset = np.array([0.0, 2.0, -1.0, 0.0, 0.0, 0.0])
    chained = dataclasses.replace(model, torque_gain=gain, torque_offset_nm=offset)
    m = read_measurements(stronger_run["test"])
    plain = predict_rows(model, m, stronger_run["desc"])
    through = predict_rows(chained, m, stronger_run["desc"])
    ok = np.isfinite(plain).all(axis=1)
    # the whole motor torque, cylinders' share included, goes through gain and offset
    np.testing.assert_allclose(through[ok], gain * plain[ok] + offset, rtol=1e-9, atol=1e-9)


def test_a_version_4_model_with_a_gain_on_a_cylinder_joint_is_refused(stronger_run, tmp_path):
    from control.identification.model import IdentifiedModel
    from gateway.errors import DataFileError

    doc = json.loads((stronger_run["out"] / "model.json").read_text())
    doc["version"] = 4
    ok = tmp_path / "ok.json"
    ok.write_text(json.dumps(doc))
    IdentifiedModel.load(ok)  # gain 1 everywhere: its diameters are physical
    doc["measurement_chain"] = {"torque_gain": [1.0, 0.9, 1.0, 1.0, 1.0, 1.0],
                                "torque_offset_nm": [0.0] * 6}  # fmt: skip
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(DataFileError, match=r"version 4 with a torque gain of 0.9 on J2"):
        IdentifiedModel.load(bad)
