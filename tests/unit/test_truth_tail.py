"""The harness's incremental reader of the simulator's truth log (sim_bridge/harness.py
TruthTail): only what was appended is parsed, a line cut by the writer waits for its end."""

from __future__ import annotations

from sim_bridge.harness import TruthTail


def test_the_tail_reads_what_was_appended_and_waits_for_a_cut_line(tmp_path):
    log = tmp_path / "truth.csv"
    tail = TruthTail(log, ("t_s", "teaching", "tool_x"), keep=3)
    assert tail.update().shape == (0, 3)  # no file yet
    log.write_text("t_s,q1,teaching,tool_x\n0.000,0,0,1.0\n0.002,0,1,1.5\n0.004,0,1,2.")
    rows = tail.update()
    assert rows.tolist() == [[0.0, 0.0, 1.0], [0.002, 1.0, 1.5]]  # the cut line is not read
    with log.open("a") as fh:
        fh.write("5\n0.006,0,0,3.0\n0.008,0,1,3.5\n")
    rows = tail.update()
    # the cut line completed, then two more; the newest three kept
    assert rows.tolist() == [[0.004, 1.0, 2.5], [0.006, 0.0, 3.0], [0.008, 1.0, 3.5]]
    assert tail.first_teaching_t_s == 0.002 and tail.last_teaching_t_s == 0.008
