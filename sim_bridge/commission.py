"""Commissioning a virtual robot as a user commissions a real one, cached per plant and code.

A drawn plant (:mod:`sim_bridge.truth`) is a robot the product knows nothing about: its model
comes from `leadthrough identify`, run on the virtual cell in lock-step (faster than real time)
through the whole product, exactly as on the real cell: the gateway identifies, the control
process plays :data:`control.identification.on_cell.QUICK_PLAN` (friction sweeps, inner-loop
velocity steps, multi-sines), the CAN driver forwards it, the bus is recorded and fitted. The
output folder holds ``model.json`` (the dynamic model), ``inner_loop.json`` (ω and Υ_I of
eq. 21) and ``current_zero.json`` (the current sensors' zero the model was identified with),
which ``[control] model``, ``[control] inner_loop`` and ``[can] current_zero_file`` point at.

:func:`commissioned` keeps one such folder per plant seed and *code version* (a digest of every
source file of the product and of the virtual cell, and of the plan): a change to either builds
it again, and two processes asking for the same one build it once (a file lock). The truth is
never read here: the plant seed goes to the simulator, which draws the plant itself.

``python -m sim_bridge.commission --plant-seed N`` builds (or finds) one and prints its folder.
"""

from __future__ import annotations

import argparse
import fcntl
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway.config import load_toml
from sim_bridge.harness import REPO, SIM_CELL, Stack, deep_merge

#: Where commissioned models are kept (``LEADTHROUGH_CACHE`` overrides; `make clean` removes it).
DEFAULT_CACHE = REPO / ".cache" / "commission"
CACHE_ENV = "LEADTHROUGH_CACHE"
#: The controller cycle commissioning runs at (the virtual controller's default) [s].
CYCLE_S = 0.008
#: Lock-step commissioning runs the plant at most this many times as fast as the wall clock
#: (the simulator's ``lockstep_max_speedup``; lock-step still waits for every answer, so a
#: machine that cannot keep the pace only slows it), with the Modbus driver polling the I/O
#: module this many times as often: the cylinders' pressures are then sampled as densely in
#: the plant's time as a cell samples them (at 3x with the poll left at its 20 ms the
#: recorded pressures went stale and J3's cylinder torque came out wrong, held-out 1.37
#: against 0.69 N·m on seed 0, 2026-11-29).
COMMISSION_SPEEDUP = 3.0
#: ... where this process may run on at least this many CPUs; on fewer, real time
#: (:func:`commission_speedup`).
SPEEDUP_MIN_CPUS = 2

#: Source trees whose files make up the code version.
CODE_TREES = ("control", "drivers", "gateway", "sim_bridge", "deploy/config")
CODE_SUFFIXES = (".py", ".toml", ".xml", ".dbc", ".json", ".rs")  # .rs: the compiled cycle
#: Longest a commissioning may take before it is abandoned (robot stopped) [s].
IDENTIFY_TIMEOUT_S = 600.0
#: What `leadthrough identify` is given beyond its own limit to stop, analyse and exit [s].
IDENTIFY_GRACE_S = 120.0
#: The longest the cell may take to become ready to start (:func:`commission`) [s].
CELL_READY_S = 60.0
#: The longest the cell may take to stop after a commissioning [s]: Stack.stop gives the
#: gateway (which stops its children) and then the simulator 10 s each to exit on SIGTERM before
#: it kills them; three times that, for a machine that is slow while the stack winds down.
CELL_STOP_S = 60.0
#: The longest one :func:`commission` may take from start to end [s]: the cell's start, the
#: identification's limit and its grace, and the cell's stop. Lock-step commissioning runs the
#: plant no faster than :data:`COMMISSION_SPEEDUP` × real time, so its wall time is at least
#: the plan's motion over that (about 338 s / 3 for
#: :data:`~control.identification.on_cell.QUICK_PLAN`; 159 s in all for seed 0 on a fast
#: machine, 2026-12-03) and more where the machine cannot keep the pace: a test that
#: commissions is given this, not the suite's default per-test limit (300 s, pyproject.toml).
COMMISSION_LIMIT_S = CELL_READY_S + IDENTIFY_TIMEOUT_S + IDENTIFY_GRACE_S + CELL_STOP_S


def commission_speedup(cpus: int | None = None) -> float:
    """How many times real time commissioning runs the plant at most, for a process that may
    run on ``cpus`` CPUs (default: this process's affinity, as ``taskset`` leaves it).

    :data:`COMMISSION_SPEEDUP` on :data:`SPEEDUP_MIN_CPUS` or more, real time on one. At 3x the
    product's cycle runs three times as often in wall time, and one CPU has no room for that
    beside anything else: seed 0 under ``taskset -c 0`` took 216 s at 3x with the CPU 99 % busy
    (user + sys 215 s). Beside one busy process on that CPU, at 3x, it faulted twice 0.5 s into
    the plan on "no fresh joint state from the CAN driver" (the virtual controller then at
    normal priority, stalled), and with the virtual controller at SCHED_FIFO the plan was not
    built within 30 s (its worker, niced, got what the threefold cycle left); at real time
    beside the same process it kept the plan's pace (2026-12-03). Lock-step only slows a plant
    the product cannot keep up with; the product's own wall-clock monitors, rightly, do not
    wait."""
    n = len(os.sched_getaffinity(0)) if cpus is None else cpus
    return COMMISSION_SPEEDUP if n >= SPEEDUP_MIN_CPUS else 1.0


@dataclass(frozen=True)
class Commissioned:
    """A commissioned plant: the folder `leadthrough identify` wrote."""

    plant_seed: int
    folder: Path

    @property
    def model(self) -> Path:
        return self.folder / "model.json"

    @property
    def inner_loop(self) -> Path:
        return self.folder / "inner_loop.json"

    @property
    def current_zero(self) -> Path | None:
        """The current sensors' zero the identification ran with (None: the zero was off)."""
        path = self.folder / "current_zero.json"
        return path if path.exists() else None

    @property
    def summary(self) -> dict[str, Any]:
        return json.loads((self.folder / "summary.json").read_text())


def code_version(plan: dict[str, Any]) -> str:
    """Digest of the plan and of every source file of the product and the virtual cell."""
    h = hashlib.sha256(json.dumps(plan, sort_keys=True).encode())
    for tree in CODE_TREES:
        for path in sorted((REPO / tree).rglob("*")):
            if path.suffix in CODE_SUFFIXES and "__pycache__" not in path.parts:
                h.update(str(path.relative_to(REPO)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:16]


def cache_root() -> Path:
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else DEFAULT_CACHE


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _tag(plant_seed: int, cell_file: Path) -> str:
    """The start of a commissioning folder's name: the plant seed, and the cell config's name
    when it is not the default virtual cell's (``seed0``, ``seed0-sim_cell_cia402``): each
    chain of drives is commissioned on its own, as a user commissions the robot through the
    drives it has."""
    if Path(cell_file).resolve() == SIM_CELL.resolve():
        return f"seed{plant_seed}"
    return f"seed{plant_seed}-{Path(cell_file).stem}"


def _folders(root: Path, tag: str) -> list[Path]:
    """The commissioning folders of ``tag`` in ``root``: ``TAG-`` and a code version (hex
    digits; a cell's name after the seed has other letters: ``seed0-sim_cell_cia402-...``
    is not one of ``seed0``'s)."""
    pattern = re.compile(re.escape(tag) + r"-[0-9a-f]+")
    return [d for d in root.glob(f"{tag}-*") if pattern.fullmatch(d.name)]


def commissioned_stack(workdir: Path, plant_seed: int = 0, **kwargs: Any) -> Stack:
    """A :class:`~.harness.Stack` of ``plant_seed`` whose control process compensates the
    plant's commissioned model and inner-loop estimate (:func:`commissioned`, built by
    `leadthrough identify` on this plant seed when not cached), with the current sensors' zero
    they were identified with; ``kwargs`` as :class:`~.harness.Stack` takes them."""
    done = commissioned(plant_seed)
    return Stack(
        workdir, plant_seed=plant_seed, model=done.model, inner_loop=done.inner_loop,
        current_zero=done.current_zero, **kwargs,
    )  # fmt: skip


def _complete(folder: Path) -> bool:
    """A commissioning folder `leadthrough identify` finished: its model and inner loop."""
    return (folder / "model.json").exists() and (folder / "inner_loop.json").exists()


def newest_commissioned(
    plant_seed: int, *, root: Path | None = None, cell_file: Path = SIM_CELL
) -> Commissioned | None:
    """The newest complete commissioning of ``plant_seed`` in the cache, whatever version of
    the code made it (None: there is none). For benching a change to the laws without
    commissioning every seed again (any edit changes :func:`code_version`): valid only while
    the identification is the same as when the folder was made, which the caller answers for;
    the folder's name carries the digest it was made with."""
    if plant_seed < 0:
        raise ValueError(f"plant seed {plant_seed} must be >= 0")
    root = root or cache_root()
    done = [d for d in _folders(root, _tag(plant_seed, cell_file)) if _complete(d)]
    if not done:
        return None
    return Commissioned(plant_seed, max(done, key=lambda d: (d / "model.json").stat().st_mtime))


def commissioned(
    plant_seed: int,
    *,
    root: Path | None = None,
    progress: Callable[[str], None] = print,
    cell_file: Path = SIM_CELL,
) -> Commissioned:
    """The commissioned model of ``plant_seed`` for this code: from the cache, or built now by
    :func:`commission` (5-7 minutes, 400 s per seed with two at once on 2026-12-06: the plan's
    motion at up to three times real time, and its analysis) and kept. ``cell_file``: the
    product's cell config it is commissioned through (its drives: the virtual cell runs the
    controller its ``[can].adapter`` speaks to), kept apart from the other cells'."""
    from control.identification.on_cell import QUICK_PLAN

    if plant_seed < 0:
        raise ValueError(f"plant seed {plant_seed} must be >= 0")
    plan = {"plan_id": f"commission-seed{plant_seed}", **QUICK_PLAN}
    root = root or cache_root()
    tag = _tag(plant_seed, cell_file)
    folder = root / f"{tag}-{code_version(plan)}"
    with _locked(root / f".{tag}.lock"):
        if _complete(folder):
            return Commissioned(plant_seed, folder)
        progress(f"commissioning plant seed {plant_seed} through {Path(cell_file).name} with "
                 f"`leadthrough identify` (lock-step, 5-7 minutes) into {folder} ...")  # fmt: skip
        work = root / f".build-{tag}-{os.getpid()}"
        shutil.rmtree(work, ignore_errors=True)
        t0 = time.monotonic()
        try:
            commission(plant_seed, plan, work, cell_file=cell_file)
            shutil.rmtree(folder, ignore_errors=True)
            (work / "ident").rename(folder)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        progress(f"commissioned plant seed {plant_seed} in {time.monotonic() - t0:.0f} s")
        # Older versions of this seed on this cell are of no further use.
        for old in _folders(root, tag):
            if old != folder:
                shutil.rmtree(old, ignore_errors=True)
        return Commissioned(plant_seed, folder)


def commission(
    plant_seed: int,
    plan: dict[str, Any],
    work: Path,
    sim_overrides: dict[str, Any] | None = None,
    cell_file: Path = SIM_CELL,
) -> Path:
    """Run `leadthrough identify` with ``plan`` on a fresh virtual cell of ``plant_seed`` whose
    product knows no model yet (``sim_overrides`` on the simulator's truth file, e.g. injected
    effects), through the product's ``cell_file``; returns ``work/ident`` (raises RuntimeError
    on failure)."""
    sim = {"operator": {"enabling_after_s": 0.0}, "controller": {"cycle_period_s": CYCLE_S},
           "lockstep_max_speedup": commission_speedup()}  # fmt: skip
    sim = deep_merge(sim, sim_overrides or {})
    poll_s = load_toml(cell_file)["modbus"]["poll_period_s"] / sim["lockstep_max_speedup"]
    plan_path = work / "plan.json"
    work.mkdir(parents=True, exist_ok=True)
    plan_path.write_text(json.dumps(plan))
    with Stack(
        work / "cell", sim_overrides=sim, lockstep=True,
        plant_seed=plant_seed, model=None, cell_file=cell_file,
        cell_overrides={"modbus": {"poll_period_s": poll_s}},
    ) as stack:  # fmt: skip
        stack.start()
        stack.wait_status(lambda s: s.get("can_start") is True, CELL_READY_S, "cell ready to start")
        reply = stack.request("start")
        if not reply.get("ok"):
            raise RuntimeError(f"start refused: {reply}")
        stack.wait_status(lambda s: s.get("state") == "ready", 10.0, "ready")
        out = subprocess.run(
            [sys.executable, "-m", "gateway.cli", "identify", "--config", str(stack.cell_path),
             "--plan", str(plan_path), "--out", str(work / "ident"),
             "--timeout", str(IDENTIFY_TIMEOUT_S)],
            capture_output=True, text=True, timeout=IDENTIFY_TIMEOUT_S + IDENTIFY_GRACE_S,
            cwd=REPO,
        )  # fmt: skip
        stack.request("stop")
    (work / "identify.log").write_text(out.stdout + out.stderr)
    if out.returncode != 0:
        lifecycle = _lifecycle_lines(work / "cell")
        raise RuntimeError(
            f"commissioning plant seed {plant_seed} failed ({out.returncode}): "
            f"{_cause(out.stdout, out.stderr, lifecycle)}\n"
            f"{out.stdout[-3000:]}{out.stderr[-3000:]}\n"
            f"the gateway's lifecycle and errors:\n{lifecycle}"
        )
    shutil.copy(work / "identify.log", work / "ident" / "identify.log")
    return work / "ident"


def _cause(stdout: str, stderr: str, lifecycle: str) -> str:
    """One line that says why `leadthrough identify` failed: its error (its stderr's last line),
    how the plan ended on the cell if it said, and the gateway's last error or lifecycle change.
    It goes on the RuntimeError's first line, which is all pytest's short summary of a failure
    shows, and a CI log read from its tail has only that (session 104's CI: "failed (2):" and
    nothing more)."""
    error = next((ln for ln in reversed(stderr.splitlines()) if ln.strip()), "")
    ended = next((ln for ln in stdout.splitlines() if ln.startswith("identification ended")), "")
    gateway = next((ln for ln in reversed(lifecycle.splitlines()) if ln.strip()), "")
    parts = [p.strip() for p in (error, ended, gateway and f"gateway: {gateway}") if p]
    return "; ".join(parts) or "(it printed nothing)"


def _lifecycle_lines(cell_dir: Path, last: int = 30) -> str:
    """The last lifecycle changes and errors of the gateway's log in ``cell_dir`` (the
    commissioning work folder is removed after a failure: this is what explains it)."""
    log = cell_dir / "gateway.log"
    if not log.exists():
        return "(no gateway log)"
    lines = [
        line for line in log.read_text(errors="replace").splitlines()
        if "lifecycle" in line or " ERROR " in line or " WARNING " in line
    ]  # fmt: skip
    return "\n".join(lines[-last:])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_bridge.commission", description=__doc__)
    p.add_argument("--plant-seed", type=int, default=0)
    p.add_argument("--cell", type=Path, default=SIM_CELL,
                   help="the product's cell config to commission through (default: "
                   "deploy/config/sim_cell.toml)")  # fmt: skip
    args = p.parse_args(argv)
    c = commissioned(args.plant_seed, cell_file=args.cell)
    print(c.folder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
