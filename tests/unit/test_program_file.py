"""Taught program files (gateway/program.py): written as the gateway writes them, read back,
cut by a crash, corrupted, exported; the gateway's per-session recorder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gateway.program import (
    ProgramError,
    ProgramWriter,
    TeachRecorder,
    program_path,
    read_program,
    write_csv,
)

JOINTS = [f"j{k}" for k in range(1, 7)]


def _q(k: int) -> np.ndarray:
    return np.linspace(0.0, 0.5, 6) + 1e-3 * k


def _write(path, segments=((0, 50), (80, 120)), marks=(10, 90)):
    w = ProgramWriter(path, JOINTS, "cell.toml")
    w.open()
    for first, last in segments:
        w.teach(True, first * 0.01)
        for k in range(first, last):
            w.trace(k * 0.01, 1000 + k, _q(k))
            if k in marks:
                w.mark(k * 0.01, 1000 + k, _q(k), f"p{k}", "cli")
        w.teach(False, last * 0.01, "enabling device released")
    w.close()
    return w


def test_a_written_program_reads_back_exactly(tmp_path):
    path = tmp_path / "p.jsonl"
    _write(path)
    prog = read_program(path)
    assert prog.warnings == []
    assert prog.joints == JOINTS
    assert prog.t_s.size == 90 and prog.n_segments == 2
    assert [len(t) for t, _ in prog.segments()] == [50, 40]
    np.testing.assert_allclose(prog.q_rad[0], _q(0), atol=1e-9)
    np.testing.assert_array_equal(prog.cycle[:2], [1000, 1001])
    assert [(m.index, m.label, m.cycle) for m in prog.marks] == [(1, "p10", 1010), (2, "p90", 1090)]
    np.testing.assert_allclose(prog.marks[1].q_rad, _q(90), atol=1e-9)


def test_the_same_cycle_is_traced_once_and_nothing_outside_teaching(tmp_path):
    w = ProgramWriter(tmp_path / "p.jsonl", JOINTS)
    w.open()
    w.trace(0.0, 1, _q(0))  # not teaching: dropped
    w.teach(True, 0.0)
    for _ in range(3):
        w.trace(0.01, 2, _q(1))
    w.close(0.02, "stopped")
    prog = read_program(w.path)
    assert prog.t_s.tolist() == [0.01]


def test_a_program_is_never_overwritten(tmp_path):
    _write(tmp_path / "p.jsonl")
    with pytest.raises(ProgramError, match="exists"):
        ProgramWriter(tmp_path / "p.jsonl", JOINTS).open()
    with pytest.raises(ProgramError, match="exists"):
        program_path(tmp_path, "p")


@pytest.mark.parametrize("name", ["", "../x", "a/b", ".hidden", "x" * 65, "a b", "é"])
def test_program_names_are_plain(tmp_path, name):
    with pytest.raises(ProgramError, match="program name"):
        program_path(tmp_path, name)


def test_default_and_given_names(tmp_path):
    assert program_path(tmp_path, "spray_1").name == "spray_1.jsonl"
    assert program_path(tmp_path, "spray_1.jsonl").name == "spray_1.jsonl"
    assert program_path(tmp_path, None).name.startswith("teach-")


def test_a_line_cut_by_a_crash_is_dropped_with_a_warning(tmp_path):
    path = tmp_path / "p.jsonl"
    _write(path)
    whole = path.read_bytes()
    path.write_bytes(whole[:-7])  # the writer died mid-line
    prog = read_program(path)
    assert len(prog.warnings) == 1 and "incomplete" in prog.warnings[0]
    assert len(prog.marks) == 2  # the marks before it are all there
    assert prog.t_s.size == 90  # the cut line was the segment's end


@pytest.mark.parametrize(
    ("line", "match"),
    [
        (b"not json", "not a JSON object"),
        (b"[1, 2]", "not a JSON object"),
        (b'{"type": "trace", "t": 9.0, "cycle": 1, "q": [1, 2]}', "list of 6 numbers"),
        (b'{"type": "trace", "t": NaN, "cycle": 1, "q": [0, 0, 0, 0, 0, 0]}', "finite number"),
        (b'{"type": "mark", "index": 7, "t": 1, "cycle": 1, "q": [0, 0, 0, 0, 0, 0]}', "follows"),
        (b'{"type": "teleport"}', "unknown line type"),
        (b'{"type": "teach", "event": "pause", "t": 1}', "teach event"),
    ],
)
def test_a_bad_line_is_an_error_naming_its_line(tmp_path, line, match):
    path = tmp_path / "p.jsonl"
    _write(path)
    lines = path.read_bytes().split(b"\n")
    lines.insert(3, line)
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(ProgramError, match=match) as err:
        read_program(path)
    assert f"{path}:4" in str(err.value)


def test_header_and_time_checks(tmp_path):
    path = tmp_path / "p.jsonl"
    path.write_text('{"type": "trace"}\n')
    with pytest.raises(ProgramError, match="first line"):
        read_program(path)
    path.write_text(json.dumps({"type": "header", "format": "leadthrough-program", "version": 9}))
    path.write_text(path.read_text() + "\n")
    with pytest.raises(ProgramError, match="version 9"):
        read_program(path)
    with pytest.raises(ProgramError, match="cannot read"):
        read_program(tmp_path / "missing.jsonl")
    w = ProgramWriter(tmp_path / "t.jsonl", JOINTS)
    w.open()
    w.teach(True, 0.0)
    w.trace(1.0, 1, _q(0))
    w.trace(0.5, 2, _q(1))  # the writer keeps time increasing: dropped
    with pytest.raises(ProgramError, match="finite"):
        w.trace(1.5, 3, np.full(6, np.inf))
    w.close(2.0)
    assert read_program(w.path).t_s.tolist() == [1.0]
    lines = w.path.read_text().splitlines()
    lines.insert(3, lines[2].replace('"t":1.0', '"t":0.5'))
    w.path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ProgramError, match="does not increase"):
        read_program(w.path)


def test_a_disk_that_refuses_ends_the_program_with_an_error(tmp_path, monkeypatch):
    w = ProgramWriter(tmp_path / "p.jsonl", JOINTS)
    w.open()
    w.teach(True, 0.0)
    w.mark(0.0, 1, _q(0), "first", "cli")

    def full(_fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("gateway.program.os.fsync", full)
    with pytest.raises(ProgramError, match="No space left"):
        w.mark(0.1, 2, _q(1), "second", "cli")
    assert not w.is_open
    monkeypatch.undo()
    assert [m.label for m in read_program(w.path).marks] in (["first"], ["first", "second"])


def test_bad_marks_are_refused_and_leave_the_file_readable(tmp_path):
    w = ProgramWriter(tmp_path / "p.jsonl", JOINTS)
    w.open()
    with pytest.raises(ProgramError, match="label"):
        w.mark(0.0, 1, _q(0), "a\nb", "cli")
    with pytest.raises(ProgramError, match="finite"):
        w.mark(0.0, 1, np.full(6, np.nan), "", "cli")
    w.mark(0.0, 1, _q(0), "ok", "handle")
    w.close()
    assert [m.source for m in read_program(w.path).marks] == ["handle"]


def test_csv_export_has_the_trace_and_the_marks(tmp_path):
    path = tmp_path / "p.jsonl"
    _write(path)
    out = write_csv(read_program(path), tmp_path / "p.csv")
    rows = out.read_text().splitlines()
    assert rows[0] == "t_s,segment,cycle," + ",".join(f"{j}_rad" for j in JOINTS) + ",mark"
    assert len(rows) == 91
    marked = [r.split(",")[-1] for r in rows[1:] if r.split(",")[-1]]
    assert marked == ["1", "2"]


def test_the_recorder_opens_on_teaching_and_closes_with_the_session(tmp_path):
    rec = TeachRecorder("cell.toml")
    path = program_path(tmp_path, "s1")
    rec.prepare(path)
    rec.follow(False, True, "ready", 0.0, 1, _q(0))
    assert not path.exists()  # no file until teaching begins
    with pytest.raises(ProgramError, match="no program"):
        rec.mark(0.0, 1, _q(0), "", "cli")
    for k in range(5):
        rec.follow(True, True, "enabling device held", 0.01 * k, 10 + k, _q(k))
    rec.mark(0.05, 15, _q(5), "corner", "cli")
    rec.follow(False, True, "enabling device released", 0.06, 16, _q(6))
    rec.follow(True, True, "enabling device held", 0.07, 17, _q(7))
    assert rec.status()["marks"] == 1 and rec.status()["open"]
    rec.follow(False, False, "stop requested by operator", 0.08, 18, _q(8))
    assert rec.status()["last_closed"] == str(path) and not rec.status()["open"]
    prog = read_program(path)
    assert prog.n_segments == 2 and prog.t_s.size == 6 and prog.marks[0].label == "corner"
    assert path.read_text().splitlines()[-1].find("stop requested") > 0


def _taught_on_the_nominal_arm(path):
    """A short program on the nominal robot: two joints sweep 0.2 rad in 4 s."""
    w = ProgramWriter(path, JOINTS)
    w.open()
    w.teach(True, 0.0)
    q0 = np.array([0.0, 0.1, 0.3, 0.0, -0.4, 0.0])
    for k in range(400):
        s = 0.5 - 0.5 * np.cos(np.pi * k / 399)
        w.trace(0.01 * k, k, q0 + s * np.array([0.2, 0.0, 0.1, 0.0, 0.0, 0.0]))
        if k == 200:
            w.mark(0.01 * k, k, q0, "middle", "handle")
    w.close(4.0)


def test_program_command_shows_and_exports(tmp_path, capsys):
    from gateway.cli import main

    path = tmp_path / "p.jsonl"
    _taught_on_the_nominal_arm(path)
    assert main(["program", "show", str(path)]) == 0
    out = capsys.readouterr().out
    assert "segment 1: 400 samples, 4.0 s, tool path" in out and "mark 1 'middle'" in out
    assert main(["program", "export", str(path), "--csv", str(tmp_path / "raw.csv")]) == 0
    assert len((tmp_path / "raw.csv").read_text().splitlines()) == 401
    processed = tmp_path / "processed.csv"
    args = ["program", "export", str(path), "--csv", str(processed), "--processed"]
    assert main([*args, "--speed-mm-s", "50", "--period-s", "0.01"]) == 0
    rows = processed.read_text().splitlines()
    assert rows[0].startswith("t_s,piece,j1_rad") and rows[0].endswith("j6_rad_s")
    last = np.array(rows[-1].split(",")[2:], dtype=float)
    np.testing.assert_allclose(last[6:], 0.0, atol=1e-9)  # ends at rest
    assert main([*args, "--speed-mm-s", "900"]) == 2
    assert "--speed-mm-s 900" in capsys.readouterr().err
    assert main(["program", "show", str(tmp_path / "missing.jsonl")]) == 2
