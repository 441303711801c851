"""teach-bench over a range of seeds (sim_bridge/teach_seeds.py): the range, the rows per
seed and the counts of seeds meeting issue 47's figures, on hand-made summaries."""

from __future__ import annotations

import argparse

import pytest

from sim_bridge.teach_phases import PHASES
from sim_bridge.teach_seeds import aggregate, parse_seeds, print_seed_table, seed_rows


def test_a_range_of_seeds_or_one():
    assert parse_seeds("100-103") == [100, 101, 102, 103]
    assert parse_seeds("7") == [7]
    for bad in ("3-1", "a-b", "-2", "1-", "1,2"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_seeds(bad)


def _run(mean, p95, peak, path_mm, missed=0, completed=True):
    phases = {p: {"mean_force_n": mean, "seconds": 1.0} for p in PHASES}
    return {"mean_force_n": mean, "p95_force_n": p95, "peak_force_n": peak,
            "path_error_mm": path_mm, "commands_missed": missed, "completed": completed,
            "phases": phases}  # fmt: skip


def _summary(floor, best):
    inertia = _run(floor, 3 * floor, 5 * floor, 5.0)
    return {"hand": {"max_force_n": 80.0}, "strategies": {"inertia": inertia, "best": best}}


def test_each_seed_is_scored_against_its_own_floor_and_the_figures_are_counted(capsys):
    summaries = {
        101: _summary(5.0, _run(9.9, 25.0, 60.0, 10.0)),  # meets all four
        100: _summary(4.0, _run(8.1, 25.0, 60.0, 10.0)),  # 2.03 x its floor
        102: _summary(5.0, _run(7.0, 31.0, 79.5, 16.0)),  # p95, the hand's limit, path
    }
    rows = seed_rows(summaries)
    assert [r["seed"] for r in rows] == [100, 101, 102]
    best = {r["seed"]: r["strategies"]["best"] for r in rows}
    assert best[100]["mean_over_floor"] == pytest.approx(8.1 / 4.0)
    assert not best[100]["within_floor_factor"] and best[101]["within_floor_factor"]
    assert best[102]["at_hand_limit"] and not best[102]["p95_ok"] and not best[102]["path_ok"]
    counts = aggregate(rows)["by_strategy"]["best"]
    assert counts == {"seeds": 3, "within_floor_factor": 2, "p95_ok": 2,
                      "never_at_hand_limit": 2, "path_ok": 2, "orientation_ok": None,
                      "all_figures": 1, "completed": 3}  # fmt: skip
    print_seed_table(rows)
    out = capsys.readouterr().out
    assert "all 1/3" in out and "2.02" in out


def test_an_orientation_locked_run_is_judged_on_its_turn_and_a_free_one_is_not(capsys):
    locked_ok = _run(9.0, 25.0, 60.0, 10.0) | {
        "guide": "orientation-locked",
        "orientation_drift_deg": {"max": 0.8},
    }
    locked_off = _run(9.0, 25.0, 60.0, 10.0) | {
        "guide": "plane",
        "orientation_drift_deg": {"max": 1.3},
    }
    free = _run(9.0, 25.0, 60.0, 10.0) | {"guide": "free", "orientation_drift_deg": {"max": 9.0}}
    rows = seed_rows({s: _summary(5.0, r) for s, r in enumerate((locked_ok, locked_off, free))})
    verdicts = [r["strategies"]["best"]["orientation_ok"] for r in rows]
    assert verdicts == [True, False, None]
    counts = aggregate(rows)["by_strategy"]["best"]
    # the plane turned 1.3°: it fails all figures; the free run is not judged on its turn
    assert counts["orientation_ok"] == 1 and counts["all_figures"] == 2
    print_seed_table(rows)
    assert "1 within 1° of the start" in capsys.readouterr().out
