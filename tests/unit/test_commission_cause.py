"""A failed commissioning says why on its error's first line: pytest's short summary shows only
that line, and a CI log read from its tail has nothing else (session 104's CI printed
"commissioning plant seed 0 failed (2):" and no cause)."""

from sim_bridge.commission import _cause


def test_the_first_line_names_identifys_error_the_plans_end_and_the_gateways_last_word():
    stdout = "identification running\nidentification ended: plan p failed: link lost\nmore\n"
    stderr = "warning: x\nleadthrough identify: error: plan p did not finish: failed\n\n"
    lifecycle = "t1 lifecycle -> READY\nt2 lifecycle -> FAULT: no fresh joint state\n"
    cause = _cause(stdout, stderr, lifecycle)
    assert "\n" not in cause
    assert cause == (
        "leadthrough identify: error: plan p did not finish: failed; "
        "identification ended: plan p failed: link lost; "
        "gateway: t2 lifecycle -> FAULT: no fresh joint state"
    )


def test_a_silent_failure_says_so():
    assert _cause("", "\n", "") == "(it printed nothing)"
