"""A joint that never slid in the data (a wrist the operator did not turn while teaching) has
no held-out figure: NaN in memory, never a warning, null in summary.json, "—" where a person
reads it, and no say in the choice of the friction family."""

from __future__ import annotations

import json
import warnings

import numpy as np

from control.identification.families import choose_family
from control.identification.fit import FrictionFit
from control.identification.lsq import Evaluation, Solution
from control.identification.report import NO_SAMPLES, finite_or_none


def _evaluation(cv_sse, n_rows) -> Evaluation:
    sse = np.asarray(cv_sse, dtype=float)
    return Evaluation(sse, sse, 3, np.asarray(n_rows), Solution({}, 3))


def test_a_joint_without_rows_has_no_rms_and_no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rms = _evaluation([4.0, 0.0, 9.0], [1, 0, 4]).cv_rms
    assert rms[0] == 2.0 and np.isnan(rms[1]) and rms[2] == 1.5


def test_the_friction_family_is_chosen_on_the_joints_that_slid():
    fits = {
        "a": FrictionFit("a", [], np.ones(3), _evaluation([1.0, 0.0, 4.0], [1, 0, 1])),
        "b": FrictionFit("b", [], np.ones(3), _evaluation([2.0, 0.0, 1.0], [1, 0, 1])),
    }
    # a: 1/1 + 4/1 = 5, b: 2/1 + 1/1 = 3 (joint 2 has no rows in either)
    assert choose_family(fits) == "b"
    fits["b"] = FrictionFit("b", [], np.ones(3), _evaluation([2.0, 0.0, 8.0], [1, 0, 1]))
    assert choose_family(fits) == "a"  # not whichever came first, as with a NaN sum


def test_summary_json_holds_null_where_a_figure_has_no_samples():
    summary = {"rms_before": [1.5, float("nan")], "nested": {"x": [float("inf"), 2]}, "n": 3}
    text = json.dumps(finite_or_none(summary), allow_nan=False)
    assert json.loads(text) == {"rms_before": [1.5, None], "nested": {"x": [None, 2]}, "n": 3}
    assert NO_SAMPLES == "—"
