"""Progress bars of the long commands (gateway/progress.py): they count real work to its total,
draw nothing where stderr is no terminal, yield to `--no-progress`, survive a fork, and the
analysis's stage bar reaches its total."""

from __future__ import annotations

import io
import logging
import multiprocessing
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.progress import progress_bar, progress_enabled

#: the commands with a bar, and the arguments each needs to parse
COMMANDS = {
    "identify": ["--config", "cell.toml"],
    "analyze": ["--urdf", "r.urdf", "--train", "a.csv", "--test", "b.csv", "--out", "o"],
    "bench": [],
    "teach-bench": [],
}

#: the bar's drawing: tqdm's ASCII bar and its counts
BAR_MARKS = ("|", "%", "/")


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_forced_bar_counts_to_its_total_and_closes_once():
    out = io.StringIO()
    with progress_bar(5, "work", "item", enabled=True, file=out) as bar:
        assert bar.shown
        for k in range(5):
            bar.advance(label=f"item {k}")
        bar.update_to(3)  # never counts back
        assert bar.n == 5
    assert bar.closed and not bar.shown
    drawn = out.getvalue()
    assert "work item 4" in drawn and "5/5" in drawn and drawn.endswith("\n")
    bar.advance()  # after the end: nothing more
    bar.close()
    assert bar.n == 5 and out.getvalue() == drawn


def test_a_bar_draws_nothing_when_its_stream_is_not_a_terminal(capsys):
    quiet = io.StringIO()
    with progress_bar(3, "work", file=quiet) as bar:
        bar.advance(2, label="two")
        bar.set_note("a note")
        bar.write("a line")
        bar.advance()
    assert not bar.shown and bar.n == 3  # counted all the same
    assert quiet.getvalue() == ""
    assert capsys.readouterr() == ("a line\n", "")  # printed as without a bar
    # the default stream is stderr: under pytest a capture, no terminal
    with progress_bar(2, "work") as bar:
        bar.advance(2)
    assert not any(mark in capsys.readouterr().err for mark in BAR_MARKS)

    terminal = _Terminal()
    with progress_bar(1, "work", file=terminal) as bar:  # a terminal: drawn
        bar.advance()
    assert "1/1" in terminal.getvalue()
    off = _Terminal()
    with progress_bar(1, "work", enabled=False, file=off) as bar:  # --no-progress
        bar.advance()
    assert off.getvalue() == "" and bar.n == 1


def test_console_logging_goes_through_the_bar_while_it_is_drawn_and_comes_back():
    root = logging.getLogger()
    console = logging.StreamHandler(sys.stderr)
    root.addHandler(console)
    try:
        with progress_bar(1, "work", enabled=True, file=io.StringIO()):
            assert console not in root.handlers
            assert any(type(h).__name__ == "_TqdmLoggingHandler" for h in root.handlers)
        assert console in root.handlers
        with progress_bar(1, "work", file=io.StringIO()):  # not drawn: logging untouched
            assert console in root.handlers
    finally:
        root.removeHandler(console)


def _in_child(bar, result) -> None:
    bar.advance(3, label="child")
    bar.write("from the child", file=io.StringIO())
    bar.close()
    result.put((bar.n, bar.closed))


def test_a_bar_inherited_by_a_forked_process_stays_inert_there(tmp_path):
    ctx = multiprocessing.get_context("fork")
    result = ctx.SimpleQueue()
    with (
        (tmp_path / "bar.txt").open("w") as out,
        progress_bar(4, "work", enabled=True, file=out) as bar,
    ):
        bar.advance()
        out.flush()
        before = (tmp_path / "bar.txt").read_text()
        child = ctx.Process(target=_in_child, args=(bar, result))
        child.start()
        child.join(30)
        assert child.exitcode == 0
        assert result.get() == (1, False)  # nothing counted or closed in the child
        assert (tmp_path / "bar.txt").read_text() == before  # and nothing drawn
        bar.advance(3)
    assert bar.n == 4 and "4/4" in (tmp_path / "bar.txt").read_text()


def _parse(command: str, *extra: str):
    from gateway.cli import _single

    return _single(command).parse_args([command, *COMMANDS[command], *extra])


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_long_command_takes_no_progress(command):
    assert progress_enabled(_parse(command, "--no-progress")) is False
    assert progress_enabled(_parse(command)) is None  # drawn on a terminal only


def test_the_identification_benchmark_takes_no_progress():
    from control.identification.bench import build_parser

    assert progress_enabled(build_parser().parse_args(["--no-progress"])) is False
    assert progress_enabled(build_parser().parse_args([])) is None


def test_identify_counts_the_experiments_the_cell_plays():
    from control.identification.on_cell import (
        QUICK_PLAN,
        experiments_done,
        plan_labels,
        time_left_note,
    )

    labels = plan_labels(QUICK_PLAN, 6)
    friction = 6 * len(QUICK_PLAN["friction"]["speeds_deg_s"])
    inner = len(QUICK_PLAN["inner_loop"]["joints"])
    assert len(labels) == friction + inner + len(QUICK_PLAN["multisine"]) + len(
        QUICK_PLAN["teaching"]
    )
    assert labels[0] == "friction/j1/2.0dps"
    assert experiments_done(labels, labels[3], 0) == 3
    assert experiments_done(labels, labels[3], 5) == 5  # never back
    assert experiments_done(labels, None, 2) == 2
    assert plan_labels({"nonsense": 1}, 6) == []  # the gateway's reply says why
    assert time_left_note(0.25, 300.0) == "25 % of the plan, 15:00 left"


PENDULUM = """<robot name="pendulum">
  <link name="base"/>
  <link name="arm">
    <inertial><origin xyz="0.5 0 0"/><mass value="40"/>
      <inertia ixx="0.1" ixy="0" ixz="0" iyy="4" iyz="0" izz="4"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1000" velocity="2"/></joint>
</robot>"""


def _pendulum_run(path: Path, seconds: float, rate_hz: float, t0_s: float, seed: int) -> None:
    """A 1-joint pendulum on a multi-sine, with Coulomb and viscous friction and noise."""
    import pinocchio as pin

    from control.identification.datafile import Measurements, write_measurements

    rng = np.random.default_rng(seed)
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    w = 2 * np.pi * np.array([0.11, 0.23, 0.37])
    phase = np.outer(t, w) + rng.uniform(0, 2 * np.pi, 3)
    amp = np.array([0.6, 0.25, 0.12])
    q, dq = (amp * np.sin(phase)).sum(1), (amp * w * np.cos(phase)).sum(1)
    ddq = -(amp * w**2 * np.sin(phase)).sum(1)
    model = pin.buildModelFromXML(PENDULUM)
    data = model.createData()
    tau = np.array([pin.rnea(model, data, np.r_[a], np.r_[b], np.r_[c])[0]
                    for a, b, c in zip(q, dq, ddq, strict=True)])  # fmt: skip
    tau += 8.0 * np.sign(dq) + 3.0 * dq + 0.3 * rng.standard_normal(t.size)
    m = Measurements(t + t0_s, q[:, None], dq[:, None], tau[:, None], None, path.name)
    write_measurements(path, m)


def test_the_analysis_stage_bar_reaches_its_total(tmp_path):
    from control.identification.analyze import analyze
    from control.identification.stages import STAGES, AnalyzeOptions

    _pendulum_run(tmp_path / "train.csv", 6.0, 250.0, 0.0, 1)
    _pendulum_run(tmp_path / "test.csv", 6.0, 250.0, 7.0, 2)
    (tmp_path / "p.urdf").write_text(PENDULUM)
    out = io.StringIO()
    # the friction families are fitted in forked workers while this bar is open
    with progress_bar(len(STAGES), "analyze", "stage", enabled=True, file=out) as bar:
        summary = analyze(
            tmp_path / "p.urdf",
            [tmp_path / "train.csv"],
            [tmp_path / "test.csv"],
            tmp_path / "out",
            AnalyzeOptions(plots=False, find_effects=False),
            progress=lambda _line: None,
            bar=bar,
        )
    assert bar.n == bar.total == len(STAGES)
    assert f"{len(STAGES)}/{len(STAGES)}" in out.getvalue()
    assert "analyze done" in out.getvalue()
    timed = set(summary["timing_s"]) - {"total"}
    assert timed == {key for key, _ in STAGES}
