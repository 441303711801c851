"""Issue 8's acceptance on independent data, as a test: ``leadthrough analyze`` run as a user
runs it (the CLI in a child process, through :func:`.table.table_case`) on the generator's null
case, an effect present all along (hose spring) and one appearing between training and test
(thermal drift of friction); each judged by :func:`.table.criteria`.

The full table (all cases and the Panda run) is ``python -m tests.independent.table``.
"""

from __future__ import annotations

import pytest

from .table import DEFAULT_TIMEOUT_S, format_case, table_case


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("acceptance")


def _record(name: str, root) -> dict:
    rec = table_case(name, root, seed=0, timeout_s=DEFAULT_TIMEOUT_S)
    print("\n" + format_case(rec))
    assert not rec["problems"], rec["problems"]
    return rec


def test_null_case_accepts_nothing_and_beats_plain_least_squares(root):
    rec = _record("null", root)
    assert rec["criteria"]["null_accepts_nothing"]
    assert all(rec["criteria"]["beats_plain_ls"])
    # with nothing undeclared, the model is at the noise floor (same filtered target)
    after, floor = rec["analyze_rms_after"], rec["floor_nm"]
    assert all(a <= 2.0 * f for a, f in zip(after, floor, strict=True))


@pytest.mark.parametrize("case", ["hose_spring", "thermal_drift"])
def test_effect_is_named_measured_and_brings_the_joint_to_the_floor(root, case):
    rec = _record(case, root)
    crit = rec["criteria"]
    assert crit["effect_named"], rec["analyze_effects"]
    assert crit["parameter_within_20pct"], rec["parameters"]
    assert all(crit["after_within_2x_floor"]), (rec["analyze_rms_after"], rec["floor_nm"])
    assert all(crit["beats_plain_ls"])
