"""The raw held-out error per test file: a multi-sine and a slow motion judged apart."""

from __future__ import annotations

import numpy as np
import pytest

from control.identification import heldout
from control.identification.datafile import Measurements


def _file(name: str, rows: int) -> heldout.TestFile:
    t = np.arange(rows) * 0.01
    q = np.zeros((rows, 2))
    return heldout.TestFile(Measurements(t, q, q, q, None, name), rows)


def test_each_file_is_scored_on_its_own_rows_and_a_declined_row_is_left_out():
    files = [_file("multisine.csv", 4), _file("slow.csv", 3)]
    rows = [np.array([True, True, True, False]), np.ones(3, dtype=bool)]
    after = np.array([[1.0, 2.0], [1.0, 2.0], [1.0, np.nan], [3.0, 0.0], [3.0, 0.0], [3.0, 0.0]])
    plain = 2 * after
    answered = np.isfinite(after).all(axis=1)
    out = heldout.per_file_rms(files, rows, {"rms_after": after, "rms_plain_ls": plain}, answered)
    assert [f["file"] for f in out] == ["multisine.csv", "slow.csv"]
    assert [f["rows_scored"] for f in out] == [2, 3]
    assert out[0]["rms_after"] == pytest.approx([1.0, 2.0])
    assert out[1]["rms_plain_ls"] == pytest.approx([6.0, 0.0])


def test_a_file_with_no_row_answered_has_no_figure():
    files = [_file("a.csv", 2)]
    err = np.full((2, 2), np.nan)
    out = heldout.per_file_rms(
        files, [np.ones(2, dtype=bool)], {"rms_after": err}, np.zeros(2, bool)
    )
    assert out == [{"file": "a.csv", "rows_scored": 0, "rms_after": None}]
