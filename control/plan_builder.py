"""Plans are built off the cycle (issue 45).

A plan (an excitation plan of control/experiments.py, or a taught program's replay path of
control/taught_path*.py: tremor filter, joint limits, timing) takes tens to hundreds of
milliseconds to build, and a slow cell PC takes three times longer. Built in the callback that
answers every cycle, it held that callback back: on a slow machine 88 commands came late within
one second and the CAN driver stopped the arm. Built in another thread of the control process it
would still hold the cycle back, since the GIL is one lock for both.

So :class:`PlanBuilder` builds plans in a worker *process*, started with the first plan and
kept, at a lower CPU priority than the cycle (control/plan_worker.py): the cycle callback
submits the plan and answers every cycle with a hold while the worker builds
(control/plan_player.py ``PlanPlayer``, state ``planning``). :func:`build_parts` is the one
function that builds a plan; the worker runs it, and so do pure tests without a worker.
"""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from gateway.realtime import normal_priority_children
from gateway.robot.description import RobotDescription

log = logging.getLogger(__name__)

#: a plan's segments: (label, role, q (T, n) [rad], dq (T, n) [rad/s])
Parts = list[tuple[str, str, np.ndarray, np.ndarray]]


class PlanRefused(ValueError):
    """The plan cannot be built (a bad spec, a program that does not fit this robot); its
    message names what was wrong. Raised by :func:`build_parts`."""


def build_parts(
    plan: dict,
    q0_rad: np.ndarray,
    lower_rad: np.ndarray,
    upper_rad: np.ndarray,
    period_s: float,
    margin_rad: float,
    desc: RobotDescription | None,
    limits: dict[str, float],
) -> Parts:
    """The plan's segments, starting at ``q0_rad`` and sampled every ``period_s`` [s].

    ``plan`` holds "replay" (``{"program": path, "speed_m_s": v}``) or an excitation plan
    (control/experiments.py). ``limits``: "max_speed_m_s", "max_joint_speed_rad_s",
    "max_point_speed_m_s" of a replay. Raises :class:`PlanRefused` naming what was wrong.
    """
    from control.experiments import build_plan
    from gateway.program import ProgramError

    try:
        if "replay" in plan:
            return _replay_parts(plan["replay"], q0_rad, period_s, desc, limits)
        return build_plan(plan, q0_rad, lower_rad, upper_rad, period_s, margin_rad)
    except PlanRefused:
        raise
    except (ValueError, ProgramError) as exc:
        raise PlanRefused(str(exc)) from None


def _replay_parts(
    spec: Any,
    q0_rad: np.ndarray,
    period_s: float,
    desc: RobotDescription | None,
    limits: dict[str, float],
) -> Parts:
    """A taught program's path (:mod:`control.taught_path`) as plan segments, role "replay"."""
    from control.taught_path import replay_trajectory
    from gateway.program import read_program

    if not isinstance(spec, dict) or not isinstance(spec.get("program"), str):
        raise PlanRefused(f"replay needs {{'program': path, 'speed_m_s': v}}, got {spec!r}")
    if desc is None:
        raise PlanRefused("replay needs the robot description")
    speed = float(spec.get("speed_m_s", 0.1))
    top = limits["max_speed_m_s"]
    if not (math.isfinite(speed) and 0 < speed <= top):
        raise PlanRefused(f"replay speed {speed} m/s not in (0, {top}]")
    program = read_program(spec["program"])
    segments = replay_trajectory(
        program, desc, q0_rad, period_s, speed,
        max_joint_speed_rad_s=limits["max_joint_speed_rad_s"],
        max_point_speed_m_s=limits["max_point_speed_m_s"],
    )  # fmt: skip
    return [(label, "replay", q, dq) for label, q, dq in segments]


class PlanBuilder:
    """Builds plans with :func:`build_parts` in one worker process (module docstring).

    :meth:`submit` hands a plan over and returns at once; :meth:`poll` (cheap: one ``poll``
    system call while nothing came) returns its outcome once built. A worker that died is
    reported as the plan's failure and replaced on the next submit. :meth:`close` ends the
    worker at once; the owner calls it (a process leaks otherwise).
    """

    def __init__(self) -> None:
        self._proc: subprocess.Popen | None = None
        self._to: Connection | None = None  #: plans to the worker
        self._from: Connection | None = None  #: outcomes from it
        self._job = 0  #: the last job submitted; outcomes of earlier ones are dropped

    def start(self) -> None:
        """Start the worker now: its interpreter and imports take a second or more on a slow
        machine, which the first plan then does not wait for. Idempotent."""
        if self._proc is not None and self._proc.poll() is None:
            return
        self._stop_worker()
        # a fresh interpreter (never a fork of a process with zenoh's threads in it), and no
        # multiprocessing: its spawn leaves a resource-tracker process behind
        to_worker_r, to_worker_w = os.pipe()
        from_worker_r, from_worker_w = os.pipe()
        try:
            with normal_priority_children():
                proc = subprocess.Popen(
                    [sys.executable, "-m", "control.plan_worker",
                     str(to_worker_r), str(from_worker_w)],
                    pass_fds=(to_worker_r, from_worker_w),
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    # Ctrl-C in a terminal reaches the control process, which ends the worker
                    # (closing the pipe, or terminate); a dead owner's pipe ends it too (EOF)
                    start_new_session=True,
                )  # fmt: skip
        except OSError:
            for fd in (to_worker_r, to_worker_w, from_worker_r, from_worker_w):
                os.close(fd)
            raise
        os.close(to_worker_r)
        os.close(from_worker_w)
        self._proc = proc
        self._to, self._from = Connection(to_worker_w), Connection(from_worker_r)

    def submit(
        self,
        plan: dict,
        q0_rad: np.ndarray,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
        period_s: float,
        margin_rad: float,
        desc: RobotDescription | None,
        limits: dict[str, float],
    ) -> int:
        """Hand a plan to the worker (:func:`build_parts`'s arguments); returns its job id."""
        self.start()
        assert self._to is not None
        self._job += 1
        args = (plan, q0_rad, lower_rad, upper_rad, period_s, margin_rad, desc, limits)
        try:
            self._to.send((self._job, args))
        except (OSError, ValueError):
            self._stop_worker()  # died: the next poll reports it
        return self._job

    def poll(self, job: int) -> tuple[str, Any] | None:
        """The outcome of ``job``, once built: ``("ok", parts)``, ``("refused", why)`` or
        ``("error", what)``; None while it is being built. The worker's log records of the
        build are logged here."""
        conn = self._from
        if conn is None:
            return ("error", "the plan builder's process is not running")
        try:
            while conn.poll(0):
                job_id, outcome, records = conn.recv()
                if job_id != job:
                    continue
                for name, level, message in records:
                    logging.getLogger(name).log(level, "%s", message)
                return outcome
        except (EOFError, OSError):
            self._stop_worker()
            return ("error", "the plan builder's process ended")
        return None

    def _stop_worker(self) -> None:
        proc, conns = self._proc, (self._to, self._from)
        self._proc = self._to = self._from = None
        for conn in conns:
            if conn is not None:
                conn.close()
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(2.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(2.0)

    def close(self) -> None:
        """End the worker process now (a plan being built is dropped). Idempotent."""
        self._stop_worker()
