"""The identification benchmark runs end to end (a short recording here; 10 minutes by hand)."""

from __future__ import annotations

from control.identification.bench import bench_identify


def test_bench_reports_seconds_per_stage(tmp_path):
    lines: list[str] = []
    result = bench_identify(minutes=0.5, rate_hz=500.0, workdir=tmp_path, progress=lines.append)
    assert set(result["stages_s"]) >= {"read", "preprocess", "regressor", "fit", "effects"}
    assert result["samples"] == 15_000
    assert result["summary"]["cylinders_removed"] is True
    assert result["summary"]["effects"] == []
    assert any(line.startswith("bench:       read") for line in lines)
    assert (tmp_path / "out" / "report.md").is_file()
