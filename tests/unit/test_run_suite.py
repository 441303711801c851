"""tests/run_suite.py: the stack tier's pytest beside the other tiers', which yield to it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from run_suite import MACHINE, REST, REST_NICENESS, run_two

#: a stand-in for pytest: prints its niceness and its -m expression, exits 3 for the rest after
#: a failure's short summary and pytest's closing line, then more lines
FAKE = [
    sys.executable,
    "-c",
    "import os, sys\n"
    "marks = sys.argv[sys.argv.index('-m') + 1]\n"
    "print('nice', os.nice(0), 'marks', marks, 'extra', sys.argv[-1])\n"
    "rest = marks.startswith('not stack')\n"
    "print('FAILED tests/unit/test_x.py::test_y - assert 1 == 2' if rest else 'ok')\n"
    "print('1 failed, 2 passed in 0.10s' if rest else '3 passed in 0.10s')\n"
    "print('a line after the summary')\n"
    "sys.exit(3 if rest else 0)\n",
]


def test_the_rest_runs_niced_beside_the_machine_and_a_failure_of_either_fails_the_run(capsys):
    code = run_two(FAKE, ["--durations=20"])
    out = capsys.readouterr().out.splitlines()
    base = os.nice(0)
    assert f"[machine] nice {base} marks {MACHINE} extra --durations=20" in out
    assert f"[rest] nice {min(base + REST_NICENESS, 19)} marks {REST} extra --durations=20" in out
    assert code == 3
    assert "run_suite: machine: pytest exit status 0" in out
    assert "run_suite: rest: pytest exit status 3" in out


def test_the_tail_of_the_output_names_each_process_failures_and_counts(capsys):
    """CI shows the end of the log; the process that finished first printed its failures long
    before: they come again after both ended, and only they and the counts."""
    run_two(FAKE, ["--durations=20"])
    out = capsys.readouterr().out.splitlines()
    tail = out[out.index("run_suite: each process's failures and summary, again:") + 1 :]
    assert sorted(tail[:3]) == [
        "[machine] 3 passed in 0.10s",
        "[rest] 1 failed, 2 passed in 0.10s",
        "[rest] FAILED tests/unit/test_x.py::test_y - assert 1 == 2",
    ]
    assert [line for line in tail[3:] if not line.startswith("run_suite: ")] == []


def test_no_test_belongs_to_both_processes_and_campaigns_to_neither():
    """The two -m expressions split what `make test` runs: a stack, exclusive or deadline test in
    the machine's, every other test only in the rest's, a campaign in neither."""

    def selects(expr: str, marks: set[str]) -> bool:
        names = {"stack", "exclusive", "deadline", "campaign"}
        return bool(eval(expr, {}, {m: m in marks for m in names}))

    for marks in (
        {"stack"}, {"exclusive"}, {"deadline"}, set(), {"stack", "campaign"}, {"campaign"},
        {"deadline", "campaign"},
    ):  # fmt: skip
        both = (selects(MACHINE, marks), selects(REST, marks))
        want = (False, False) if "campaign" in marks else (bool(marks), not marks)
        assert both == want, (marks, both)


def test_every_test_of_the_stack_directory_is_in_the_machines_process():
    """tests/stack/conftest.py marks what runs the whole stack, whatever its file says: none of
    it is left for the niced process."""
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
         "-m", REST, str(root / "stack")],
        capture_output=True, text=True, cwd=root.parent, timeout=120,
    )  # fmt: skip
    assert done.returncode == 5, done.stdout + done.stderr  # 5: no test selected
    assert "deselected" in done.stdout
