"""Measurement CSV files: round trip, currents and drive gains, a named line for each bad file."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from control.identification.datafile import Measurements, read_measurements, write_measurements
from gateway.errors import ConfigError, DataFileError

HEADER = "t,q1,q2,tau1,tau2"
GOOD_ROWS = ["0.000,0.1,0.2,1.0,2.0", "0.001,0.1,0.2,1.0,2.0", "0.002,0.1,0.2,1.0,2.0"]


def _measurements(
    rng: np.random.Generator, n_samples: int = 50, with_p: bool = True
) -> Measurements:
    t = np.arange(n_samples) * 1e-3 + 12.5
    return Measurements(
        t=t,
        q=rng.normal(size=(n_samples, 3)),
        dq=rng.normal(size=(n_samples, 3)),
        tau=rng.normal(scale=100.0, size=(n_samples, 3)),
        p=rng.uniform(3, 7, size=(n_samples, 2)) if with_p else None,
        source="mem",
        p_joints=(2, 3) if with_p else (),
    )


def _write(tmp_path: Path, text: str, name: str = "run.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode())
    return path


def test_round_trip_keeps_every_column(tmp_path):
    m = _measurements(np.random.default_rng(1))
    path = tmp_path / "a.csv"
    write_measurements(path, m)
    back = read_measurements(path)
    for name in ("t", "q", "dq", "tau", "p"):
        np.testing.assert_allclose(getattr(back, name), getattr(m, name), rtol=1e-11, atol=1e-12)
    assert back.p_joints == (2, 3)
    assert back.source == str(path)


def test_velocity_and_pressure_columns_are_optional(tmp_path):
    path = _write(tmp_path, HEADER + "\n" + "\n".join(GOOD_ROWS) + "\n")
    m = read_measurements(path)
    assert m.dq is None and m.p is None and m.q.shape == (3, 2)


def test_unknown_columns_are_ignored_even_text(tmp_path):
    rows = ["0,0.1,teach,0.2,1,2", "0.1,0.1,teach,0.2,1,2"]
    path = _write(tmp_path, "t,q1,mode,q2,tau1,tau2\n" + "\n".join(rows) + "\n")
    m = read_measurements(path)
    np.testing.assert_allclose(m.q, [[0.1, 0.2], [0.1, 0.2]])


def test_crlf_line_ends_and_missing_final_newline_are_accepted(tmp_path):
    path = _write(tmp_path, HEADER + "\r\n" + "\r\n".join(GOOD_ROWS))
    assert read_measurements(path).n_samples == 3


def test_currents_become_torque_with_command_line_gains(tmp_path):
    path = _write(tmp_path, "t,q1,q2,i1,i2\n0,0,0,1.5,-2\n0.1,0,0,1,1\n")
    m = read_measurements(path, drive_gains=[10.0, 4.0])
    np.testing.assert_allclose(m.tau, [[15.0, -8.0], [10.0, 4.0]])


def test_currents_use_sidecar_gains(tmp_path):
    path = _write(tmp_path, "t,q1,q2,i1,i2\n0,0,0,1.5,-2\n0.1,0,0,1,1\n", "A.csv")
    (tmp_path / "A.json").write_text(json.dumps({"drive_gains_nm_per_a": [2.0, 3.0]}))
    np.testing.assert_allclose(read_measurements(path).tau, [[3.0, -6.0], [2.0, 3.0]])
    # the command line wins over the sidecar
    np.testing.assert_allclose(read_measurements(path, [1.0, 1.0]).tau, [[1.5, -2.0], [1.0, 1.0]])


def test_torque_columns_win_over_currents(tmp_path):
    path = _write(tmp_path, "t,q1,tau1,i1\n0,0,5,1\n0.1,0,6,1\n")
    np.testing.assert_allclose(read_measurements(path).tau[:, 0], [5.0, 6.0])


def test_currents_without_gains_name_the_file(tmp_path):
    path = _write(tmp_path, "t,q1,i1\n0,0,1\n0.1,0,1\n")
    with pytest.raises(DataFileError, match=rf"{path}:1: .*no drive gains"):
        read_measurements(path)


def test_wrong_number_of_gains_is_a_config_error(tmp_path):
    path = _write(tmp_path, "t,q1,q2,i1,i2\n0,0,0,1,1\n0.1,0,0,1,1\n")
    with pytest.raises(ConfigError, match="--drive-gains"):
        read_measurements(path, drive_gains=[1.0])


def test_bad_sidecar_is_named(tmp_path):
    path = _write(tmp_path, "t,q1,i1\n0,0,1\n0.1,0,1\n", "B.csv")
    (tmp_path / "B.json").write_text("{not json")
    with pytest.raises(DataFileError, match=r"B\.json"):
        read_measurements(path)


def _rows(*rows: str, end: str = "\n") -> str:
    return "\n".join(rows) + end


BAD_FILES = {
    # name: (file text, line named in the error, message fragment)
    "missing torque columns": (_rows("t,q1,q2", "0,0,0"), 1, "missing torque columns"),
    "missing time column": (_rows("q1,tau1", "0,0"), 1, "missing required column 't'"),
    "missing position columns": (_rows("t,tau1", "0,0"), 1, "q1..qN"),
    "duplicate column": (_rows("t,q1,q1,tau1", "0,0,0,0"), 1, "appears twice"),
    "inconsistent joint count tau": (
        _rows("t,q1,q2,tau1", "0,0,0,0"),
        1,
        "inconsistent joint count",
    ),
    "inconsistent joint count dq": (
        _rows("t,q1,q2,dq1,tau1,tau2", "0,0,0,0,0,0"),
        1,
        "inconsistent joint count",
    ),
    "gap in q numbering": (_rows("t,q1,q3,tau1,tau2,tau3", "0,0,0,0,0,0"), 1, "missing"),
    "pressure of a joint that is not there": (_rows(HEADER + ",p5", "0,0,0,0,0,3"), 1, "p5"),
    "non-numeric value": (_rows(HEADER, GOOD_ROWS[0], "0.001,0.1,abc,1,2"), 3, "non-numeric"),
    "empty value": (_rows(HEADER, GOOD_ROWS[0], GOOD_ROWS[1], "0.002,0.1,,1,2"), 4, "empty value"),
    "too many fields": (
        _rows(HEADER, GOOD_ROWS[0], "0.001,0.1,0.2,1,2,9"),
        3,
        "wrong column count",
    ),
    "too few fields": (_rows(HEADER, "0.000,0.1,0.2,1", GOOD_ROWS[1]), 2, "wrong column count"),
    "empty line": (_rows(HEADER, GOOD_ROWS[0], "", GOOD_ROWS[1]), 3, "empty line"),
    "truncated last line": (
        _rows(HEADER, GOOD_ROWS[0], GOOD_ROWS[1], "0.002,0.1", end=""),
        4,
        "truncated",
    ),
    "time going back": (
        _rows(HEADER, GOOD_ROWS[0], GOOD_ROWS[2], GOOD_ROWS[1]),
        4,
        "non-monotonic",
    ),
    "repeated time": (_rows(HEADER, GOOD_ROWS[0], GOOD_ROWS[0]), 3, "repeated"),
    "NaN": (_rows(HEADER, GOOD_ROWS[0], "0.001,nan,0.2,1,2"), 3, "not finite"),
    "infinity": (_rows(HEADER, GOOD_ROWS[0], GOOD_ROWS[1], "0.002,0.1,0.2,inf,2"), 4, "not finite"),
    "no data rows": (_rows(HEADER), 1, "no data rows"),
    "empty file": ("", 1, "empty file"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_file_names_file_and_line(tmp_path, case):
    text, line, fragment = BAD_FILES[case]
    path = _write(tmp_path, text)
    with pytest.raises(DataFileError) as info:
        read_measurements(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}:"), message
    assert fragment in message


def test_bad_line_is_found_deep_in_a_large_file(tmp_path):
    rng = np.random.default_rng(3)
    m = _measurements(rng, n_samples=20_000, with_p=False)
    path = tmp_path / "big.csv"
    write_measurements(path, m)
    lines = path.read_text().splitlines()
    fields = lines[15_001].split(",")
    fields[4] = "1.2.3"
    lines[15_001] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        DataFileError, match=rf"{path}:15002: non-numeric value '1.2.3' in column 'dq1'"
    ):
        read_measurements(path)


def test_reading_is_fast(tmp_path):
    """100k rows x 6 joints (t, q, tau: 13 columns) read well under a second on a free core;
    the bound is loose because CI machines are shared."""
    rng = np.random.default_rng(4)
    n = 100_000
    m = Measurements(
        t=np.arange(n) * 1e-3,
        q=rng.normal(size=(n, 6)),
        dq=None,
        tau=rng.normal(size=(n, 6)),
        p=None,
        source="mem",
    )
    path = tmp_path / "fast.csv"
    write_measurements(path, m)
    start = time.perf_counter()
    back = read_measurements(path)
    elapsed = time.perf_counter() - start
    assert back.n_samples == n
    assert elapsed < 5.0, f"reading {n} rows took {elapsed:.2f} s"
