"""The `leadthrough` command line as a new user meets it: `--version` and `--help` answer at
once (no subcommand module is imported), and an operator command with no gateway to talk to
says so within its `--timeout`, without a traceback."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from gateway.cli import _version
from sim_bridge.harness import free_port

ROOT = Path(__file__).resolve().parents[2]


def _leadthrough(*args: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gateway.cli", *args],
        cwd=ROOT, capture_output=True, text=True, timeout=timeout_s,
    )  # fmt: skip


def test_version_and_help_import_no_subcommand():
    code = (
        "import sys\nfrom gateway.cli import main\n"
        "for argv in (['--version'], ['--help']):\n"
        "    try:\n        main(argv)\n    except SystemExit as exc:\n"
        "        assert exc.code == 0, (argv, exc.code)\n"
        "heavy = sorted(m for m in ('mujoco', 'scipy', 'zenoh', 'numpy') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=30)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert f"leadthrough {_version()}" in out.stdout
    assert "status" in out.stdout and "teach-bench" in out.stdout  # the subcommands listed
    assert _version().count(".") >= 1


def test_status_without_a_gateway_answers_within_its_timeout():
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nobody listens there
    start = time.monotonic()
    out = _leadthrough("status", "--bus", endpoint, "--timeout", "1")
    took = time.monotonic() - start
    assert out.returncode == 1, out
    assert "Traceback" not in out.stdout + out.stderr, out.stderr
    assert endpoint in out.stdout and "leadthrough gateway" in out.stdout, out.stdout
    assert took < 6.0, f"took {took:.1f} s with --timeout 1"
