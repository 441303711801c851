"""`leadthrough export --format parquet` and Parquet measurement files in `leadthrough analyze`:
the same columns and numbers as the CSV, read into the same arrays, refused with the same
checks (the column and the row named)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from control.identification.datafile import Measurements, read_measurements, write_measurements
from gateway.cli import main
from gateway.errors import EXIT_CONFIG, ConfigError, DataFileError
from gateway.export_cli import output_format
from gateway.message_factories import make_joint_state
from gateway.messages import FLAG_SERVO_POWER, ControllerState, IoState, Keys
from gateway.parquet_file import write_parquet
from gateway.recorder import _McapFile

ROOT = Path(__file__).resolve().parents[2]
PERIOD_S = 0.004
GAINS = [46.21, 66.18, 39.0, 11.15, 11.15, 5.58]
FIELDS = ("t", "q", "dq", "tau", "p")


def _write_recording(path: Path, cycles: int = 120) -> Path:
    """A small recording as `leadthrough record` writes it: pressures, then joint states."""
    keys = Keys()
    rng = np.random.default_rng(3)
    rec = _McapFile(path, {"note": "test_parquet_export"})
    t0_ns = 1_000_000_000
    try:
        io = IoState(1.0, 6.0, 4.0, 6.0, 4.0, True, True).to_bytes()
        rec.add(keys.io_state, t0_ns, t0_ns, io, 0)
        for k in range(cycles):
            q = 0.3 * np.sin(0.02 * k + np.arange(6))
            dq = 0.3 * 0.02 / PERIOD_S * np.cos(0.02 * k + np.arange(6))
            current = rng.normal(size=6)
            st = make_joint_state(500 + k, 2.0 + k * PERIOD_S, ControllerState.EXTERNAL,
                                  FLAG_SERVO_POWER, q, dq, current, q, dq, PERIOD_S)  # fmt: skip
            t_ns = t0_ns + (k + 1) * round(PERIOD_S * 1e9)
            rec.add(keys.joint_state, t_ns, t_ns, st.to_bytes(), k + 1)
    finally:
        rec.close()
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    return _write_recording(tmp_path_factory.mktemp("rec") / "run.mcap")


def _export(*argv: str) -> int:
    return main(["export", *argv, "--gains", *(str(g) for g in GAINS)])


def _assert_same(a: Measurements, b: Measurements) -> None:
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.p_joints == b.p_joints


def test_parquet_export_reads_back_as_the_same_arrays_as_the_csv(recording, tmp_path, capsys):
    assert _export(str(recording), "--out", str(tmp_path / "a.csv")) == 0
    assert _export(str(recording), "--out", str(tmp_path / "b.parquet")) == 0
    out = capsys.readouterr().out
    assert f"{tmp_path / 'b.parquet'}: " in out
    # the sidecar goes into the file's metadata; the export's scratch CSV is gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json", "b.parquet"]

    from_csv = read_measurements(tmp_path / "a.csv")  # gains from the sidecar
    from_parquet = read_measurements(tmp_path / "b.parquet")  # gains from its metadata
    assert from_parquet.n_samples > 100 and from_parquet.dq is not None
    _assert_same(from_csv, from_parquet)
    np.testing.assert_allclose(from_parquet.p[0], [6.0, 4.0])

    # same column names in the same order, float64, the sidecar in the file's metadata
    header = (tmp_path / "a.csv").read_text().splitlines()[0].split(",")
    schema = pq.read_schema(tmp_path / "b.parquet")
    assert schema.names == header
    assert all(field.type == pa.float64() for field in schema)
    sidecar = json.loads((tmp_path / "a.json").read_text())
    meta = {k.decode(): json.loads(v) for k, v in schema.metadata.items()}
    assert meta == sidecar and meta["drive_gains_nm_per_a"] == GAINS


def test_split_writes_train_and_test_parquet_files_for_analyze(recording, tmp_path, capsys):
    out = tmp_path / "parts" / "run"
    argv = [str(recording), "--out", str(out), "--format", "parquet", "--split", "0.5"]
    assert _export(*argv, "--urdf-out", str(tmp_path / "robot.urdf")) == 0
    train, test = out.parent / "run_train.parquet", out.parent / "run_test.parquet"
    assert f"--train {train} --test {test}" in capsys.readouterr().out
    a, b = read_measurements(train), read_measurements(test)
    assert a.n_samples > 20 and b.n_samples > 20
    assert _export(str(recording), "--out", str(tmp_path / "c.csv"), "--split", "0.5") == 0
    _assert_same(read_measurements(tmp_path / "c_train.csv"), a)
    _assert_same(read_measurements(tmp_path / "c_test.csv"), b)
    assert _export(str(recording), "--out", str(tmp_path / "all.parquet")) == 0
    whole = read_measurements(tmp_path / "all.parquet")
    # contiguous parts, the training part first: together the whole recording
    np.testing.assert_array_equal(np.vstack([a.q, b.q]), whole.q)


def test_a_format_that_contradicts_the_suffix_is_refused_naming_both(recording, tmp_path, capsys):
    code = _export(str(recording), "--out", str(tmp_path / "run.parquet"), "--format", "csv")
    assert code == EXIT_CONFIG
    err = capsys.readouterr().err
    assert "--format csv" in err and "run.parquet" in err
    assert not (tmp_path / "run.parquet").exists()
    assert output_format(Path("a.parquet"), None) == "parquet"
    assert output_format(Path("a.csv"), None) == output_format(Path("a"), None) == "csv"
    assert output_format(Path("a"), "parquet") == "parquet"
    with pytest.raises(ConfigError, match=r"--format parquet .*a\.csv"):
        output_format(Path("a.csv"), "parquet")


def _table(tmp_path: Path, columns: dict[str, list], name: str = "bad.parquet") -> Path:
    path = tmp_path / name
    pq.write_table(pa.table(columns), path)
    return path


GOOD = {"t": [0.0, 0.001, 0.002, 0.003], "q1": [0.1, 0.2, 0.3, 0.4], "tau1": [1.0, 2.0, 3.0, 4.0]}


def test_a_parquet_value_that_is_not_finite_is_refused_naming_column_and_row(tmp_path):
    assert read_measurements(_table(tmp_path, GOOD, "good.parquet")).n_samples == 4
    path = _table(tmp_path, {**GOOD, "q1": [0.1, 0.2, float("nan"), 0.4]})
    with pytest.raises(DataFileError, match=r"bad\.parquet: row 3 \(index 2\): .*nan.*'q1'"):
        read_measurements(path)
    path = _table(tmp_path, {**GOOD, "tau1": [1.0, float("inf"), 3.0, 4.0]}, "inf.parquet")
    with pytest.raises(DataFileError, match=r"row 2 \(index 1\): .*'tau1' not finite"):
        read_measurements(path)


def test_a_parquet_missing_a_column_is_refused_naming_it(tmp_path):
    path = _table(tmp_path, {"t": GOOD["t"], "q1": GOOD["q1"]})
    with pytest.raises(DataFileError, match=r"bad\.parquet: missing torque columns.*tau1"):
        read_measurements(path)
    path = _table(tmp_path, {"q1": GOOD["q1"], "tau1": GOOD["tau1"]}, "no_t.parquet")
    with pytest.raises(DataFileError, match="missing required column 't'"):
        read_measurements(path)


def test_a_parquet_is_held_to_every_other_check_of_a_csv(tmp_path):
    back = {**GOOD, "t": [0.0, 0.002, 0.001, 0.003]}
    with pytest.raises(DataFileError, match=r"row 3 \(index 2\): time t=0.001 s non-monotonic"):
        read_measurements(_table(tmp_path, back))
    empty = {**GOOD, "q1": pa.array([0.1, None, 0.3, 0.4])}
    with pytest.raises(DataFileError, match=r"row 2 \(index 1\): empty value in column 'q1'"):
        read_measurements(_table(tmp_path, empty, "null.parquet"))
    text = {**GOOD, "tau1": ["1", "2", "3", "4"]}
    with pytest.raises(DataFileError, match="column 'tau1' holds string, not numbers"):
        read_measurements(_table(tmp_path, text, "text.parquet"))
    # an unused column may hold anything, as in a CSV; integers are numbers
    fine = {**GOOD, "mode": ["a", "b", "c", "d"], "q1": [1, 2, 3, 4]}
    m = read_measurements(_table(tmp_path, fine, "fine.parquet"))
    assert m.q.dtype == np.float64 and m.q[:, 0].tolist() == [1.0, 2.0, 3.0, 4.0]
    currents = {"t": GOOD["t"], "q1": GOOD["q1"], "i1": GOOD["tau1"]}
    with pytest.raises(DataFileError, match=r"has motor currents i1\.\.i1 but no drive gains"):
        read_measurements(_table(tmp_path, currents, "currents.parquet"))
    not_parquet = tmp_path / "text.parquet"
    not_parquet.write_text("t,q1,tau1\n0,0,0\n")
    with pytest.raises(DataFileError, match="not a readable Parquet file"):
        read_measurements(not_parquet)


def test_csv_and_parquet_of_the_same_measurements_read_back_identical(tmp_path):
    rng = np.random.default_rng(5)
    t = np.arange(40) * 1e-3
    q, dq, tau = rng.normal(size=(3, 40, 3))
    m = Measurements(t, q, dq, tau, rng.uniform(3, 7, (40, 2)), "mem", (2, 3))
    write_measurements(tmp_path / "m.csv", m)
    from_csv = read_measurements(tmp_path / "m.csv")
    names = ["t", *(f"{c}{j}" for c in ("q", "dq", "tau") for j in (1, 2, 3)), "p2", "p3"]
    data = np.column_stack([from_csv.t, from_csv.q, from_csv.dq, from_csv.tau, from_csv.p])
    write_parquet(tmp_path / "m.parquet", names, data)
    _assert_same(from_csv, read_measurements(tmp_path / "m.parquet"))
    # a Parquet file is known by its magic whatever its name
    (tmp_path / "m.parquet").rename(tmp_path / "m.data")
    _assert_same(from_csv, read_measurements(tmp_path / "m.data"))


def test_pyarrow_is_imported_only_when_a_parquet_file_is_read_or_written():
    code = (
        "import sys\n"
        "from gateway.cli import _single\n"
        "for name in ('export', 'analyze'):\n"
        "    _single(name)\n"
        "import control.identification.datafile\n"
        "assert 'pyarrow' not in sys.modules, 'pyarrow imported'\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert out.returncode == 0, out.stderr
