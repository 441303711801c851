"""`leadthrough sim --plant-seed N` from the command line, as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import tomli_w

from gateway.config import load_toml
from sim_bridge.harness import REPO, TRUTH, deep_merge, free_port, unique_can_address

pytestmark = pytest.mark.stack


def _sim(tmp_path, *extra: str) -> tuple[subprocess.CompletedProcess, dict | None]:
    truth = deep_merge(
        load_toml(TRUTH),
        {"endpoints": {"can_channel": unique_can_address(), "modbus_port": free_port()}},
    )
    path = tmp_path / "truth.toml"
    path.write_bytes(tomli_w.dumps(truth).encode())
    summary = tmp_path / "summary.json"
    done = subprocess.run(
        [sys.executable, "-m", "gateway.cli", "sim", "--truth", str(path),
         "--summary", str(summary), "--duration", "0.2", *extra],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    return done, json.loads(summary.read_text()) if summary.exists() else None


def test_sim_runs_the_plant_drawn_from_a_seed(tmp_path):
    done, summary = _sim(tmp_path, "--plant-seed", "3")
    assert done.returncode == 0, done.stderr
    assert summary is not None and summary["plant_seed"] == 3


def test_a_negative_plant_seed_is_refused_with_its_name(tmp_path):
    done, _ = _sim(tmp_path, "--plant-seed", "-1")
    assert done.returncode != 0
    assert "plant_seed" in done.stderr + done.stdout
