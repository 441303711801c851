"""`leadthrough gateway`: hosts the zenoh router, supervises the driver and control processes,
owns the lifecycle and answers operator requests (gateway/operator_answers.py).

Children are started as ``python -m gateway.cli <process> --config CELL --bus ENDPOINT``. A child
that exits is a fault (the robot is stopped) and is restarted after a back-off, so that `reset`
can bring the cell back once the cause is gone. A child that refuses its configuration (exit
status EXIT_CONFIG) is not restarted: the same file would be refused again every back-off. The
fault names it and stays; `reset` starts it again (after the file was mended).
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import Future
from pathlib import Path

import zenoh

from gateway.bus import BusConfig, LockedRouter, open_router, undeclare_all
from gateway.bus_refusals import BusRefusals
from gateway.children import Child, _die_with_parent
from gateway.config import resolve_path
from gateway.errors import EXIT_CONFIG, ConfigError, MessageError
from gateway.gateway_config import GatewayConfig, load_gateway_config
from gateway.joint_state_watch import JointStateWatch
from gateway.lifecycle import DRIVER_TRIPS, LifecycleMachine, Limits, Observations
from gateway.messages import (
    LIFECYCLE_RATE_HZ,
    PLAYING,
    IoState,
    JointState,
    Lifecycle,
    LifecycleMsg,
    decode_json,
)
from gateway.operator_answers import OperatorAnswers
from gateway.program import ProgramError
from gateway.program_thread import STALL_S, ProgramThread
from gateway.runner import run_service
from gateway.sd_notify import Notifier

#: A static-load check older than this (at the control process's last health) does not count [s].
LOAD_CHECK_MAX_AGE_S = 0.5

log = logging.getLogger("leadthrough.gateway")

TICK_S = 0.01
STOP_GRACE_S = 0.3  #: after announcing STOPPED on exit, before children are terminated
TERMINATE_TIMEOUT_S = 3.0
#: StateWindows the bus keeps for the gateway's next tick (a zenoh ring channel, oldest dropped
#: first): far more than arrive in one tick; only a tick stalled that long loses some.
JOINT_STATE_QUEUE = 64
#: Operator requests waiting for the next tick (a zenoh FIFO channel).
REQUEST_QUEUE = 16


class Gateway(OperatorAnswers):
    def __init__(self, cell_path: Path, bus: BusConfig, cfg: GatewayConfig, spawn: bool = True):
        self.cell_path = cell_path
        self.bus = bus
        self.keys = bus.keys
        self.cfg = cfg
        self.machine = LifecycleMachine(
            Limits(
                cfg.joint_state_timeout_s,
                cfg.io_timeout_s,
                cfg.standstill_rad_s,
                cfg.standstill_s,
                cfg.servo_settle_s,
            )
        )
        self.lock = threading.Lock()
        self.stop_event = threading.Event()
        self.spawn = spawn
        self.watch = JointStateWatch(cfg.standstill_rad_s, time.monotonic(), cfg.standstill_s)
        self._state_sub = None  #: joint states, in a ring channel the tick drains
        self._requests = None  #: operator requests, in a channel the tick serves
        self.io: IoState | None = None
        self.io_rx_s: float | None = None
        #: I/O states in a row that read the enabling device held (0: the newest read released)
        self.enabling_polls = 0
        self.health_rx_s: dict[str, float] = {}
        #: the control process's static-load check (control/load_check.py) as last reported
        self.load_check: dict | None = None
        #: why control has not checked the static load lately, from its health (None: no reason)
        self.load_waiting: str | None = None
        #: the mass eq. (29) added to the model in replay (control/model_adaptation.py)
        self.model_adaptation: dict | None = None
        #: what the control law is doing, from its health (None: not reported)
        self.engagement: dict | None = None
        #: the constrained guide the operator's start asked for (None: the control config's),
        #: passed to the control process in the lifecycle while ready or teaching; and the
        #: guide in force with its deviation, from control's health
        self.guide: str | None = None
        self.guide_report: dict | None = None
        #: the CAN driver's latched trips, from its health (lifecycle.DRIVER_TRIPS)
        self.driver_trips: dict[str, str] = {}
        #: the controller's fault in the CAN driver's words, from its health (None: none)
        self.controller_fault_text: str | None = None
        self.children: dict[str, Child] = {}
        self.session = None
        self._decls: list = []
        self._last_pub_s = 0.0
        self._last_seq = -1
        self._dead: tuple[str, ...] = ()  #: children not running, as of the last tick
        self.program_dir = resolve_path(cell_path, cfg.program_dir)
        #: the taught program, written by a thread of its own (gateway/program_thread.py)
        self.teach = ProgramThread(str(cell_path))
        self._mark_button = False  #: the teach handle's mark button, as last seen
        self._handle_marks = 0  #: presses of it not yet recorded
        #: the teach handle's marks on their way to the disk
        self._handle_marks_written: list[Future] = []
        #: operator requests answered once their mark is on disk: (query, result, since [s])
        self._waiting: list[tuple[object, Future, float]] = []
        #: the program's writes have waited past STALL_S, and that has been reported
        self._program_stall_reported = False
        #: what the locked bus's access-control list refused (None on an open bus)
        self.refusals: BusRefusals | None = None

    # --- processes ----------------------------------------------------------------------
    def _argv(self, name: str) -> list[str]:
        return [sys.executable, "-m", "gateway.cli", name, "--config", str(self.cell_path),
                "--bus", self.bus.endpoint]  # fmt: skip

    def _start_child(self, child: Child) -> None:
        log.info("starting %s", child.name)
        # Same process group as the gateway (a terminal's Ctrl-C or a killpg reaches them all),
        # and the kernel sends SIGTERM if the gateway itself dies.
        child.proc = subprocess.Popen(child.argv, preexec_fn=_die_with_parent)
        child.started_s = time.monotonic()
        child.restart_at_s = None

    def _poll_children(self, now: float) -> list[str]:
        dead = []
        for child in self.children.values():
            if child.proc is not None and child.proc.poll() is not None:
                code = child.proc.returncode
                child.exits.append(code)
                child.proc = None
                if code == EXIT_CONFIG:
                    child.config_refused = True
                    reason = (f"process {child.name} refused its configuration (see its log); "
                              "mend the cell config, then reset")  # fmt: skip
                    log.error("%s; not restarting it", reason)
                else:
                    child.restart_at_s = now + self.cfg.restart_backoff_s
                    reason = f"process {child.name} exited (code {code})"
                    log.error("%s; restarting in %.1f s", reason, self.cfg.restart_backoff_s)
                with self.lock:
                    self.machine.fault(reason)
            if child.proc is None:
                if child.restart_at_s is not None and now >= child.restart_at_s:
                    self._start_child(child)
                else:
                    dead.append(child.name)
        return dead

    def _stop_children(self) -> None:
        for child in self.children.values():
            if child.proc is not None and child.proc.poll() is None:
                child.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + TERMINATE_TIMEOUT_S
        for child in self.children.values():
            if child.proc is None:
                continue
            try:
                child.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.error("%s did not stop; killing it", child.name)
                child.proc.kill()
                child.proc.wait()

    # --- bus ------------------------------------------------------------------------------
    def _take_states(self) -> None:
        """Fold the joint states received since the last call (call with the lock held)."""
        payloads, start_s = [], time.monotonic()
        if self._state_sub is not None:
            while (sample := self._state_sub.try_recv()) is not None:
                payloads.append(sample.payload.to_bytes())
        problems = self.watch.fold(payloads, start_s, time.monotonic())
        if problems:
            log.warning("ignored %d joint state(s): %s", len(problems), problems[-1])

    def _on_io(self, sample) -> None:
        try:
            io = IoState.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            log.warning("ignored I/O state: %s", exc)
            return
        with self.lock:
            if io.mark and not self._mark_button:
                self._handle_marks += 1  # recorded by the next tick (an fsync is no callback work)
            self._mark_button = io.mark
            self.enabling_polls = self.enabling_polls + 1 if io.enabling else 0
            self.io, self.io_rx_s = io, time.monotonic()

    def _on_health(self, sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        body: dict = {}
        if name in ("control", "can_driver"):
            try:
                body = decode_json(sample.payload.to_bytes(), f"{name} health")
            except MessageError as exc:
                log.warning("%s health unreadable: %s", name, exc)
        with self.lock:
            self.health_rx_s[name] = time.monotonic()
            if name == "control":
                load_check = body.get("load_check")
                self.load_check = load_check if isinstance(load_check, dict) else None
                waiting = body.get("load_check_waiting")
                self.load_waiting = waiting if isinstance(waiting, str) else None
                engagement = body.get("engagement")
                self.engagement = engagement if isinstance(engagement, dict) else None
                adapted = body.get("model_adaptation")
                self.model_adaptation = adapted if isinstance(adapted, dict) else None
                guide = body.get("guide")
                self.guide_report = guide if isinstance(guide, dict) else None
            elif name == "can_driver" and body:  # an unreadable one changes nothing
                self.driver_trips = {
                    key: str(body[key]) for key in DRIVER_TRIPS if body.get(key) is not None
                }
                text = body.get("controller_fault_text")
                self.controller_fault_text = str(text) if text else None

    @property
    def joint_state(self) -> JointState | None:
        """The newest valid joint state."""
        return self.watch.state

    def observations(self, now: float, dead: tuple[str, ...] = ()) -> Observations:
        w, io = self.watch, self.io
        stale, booting = [], []
        for name in self.children:
            key = name.replace("-", "_")
            child = self.children[name]
            rx = self.health_rx_s.get(key)
            starting = (
                child.proc is not None
                and now - child.started_s < self.cfg.boot_grace_s
                and rx is None
            )
            if starting:
                booting.append(name)
            elif child.proc is not None and (rx is None or now - rx > self.cfg.health_timeout_s):
                stale.append(name)
        return Observations(
            joint_state_age_s=None if w.rx_s is None else now - w.rx_s,
            io_age_s=None if self.io_rx_s is None else now - self.io_rx_s,
            controller_state=w.controller_state,
            enabling=bool(io and io.enabling)
            and self.enabling_polls >= self.cfg.enabling_confirm_polls,
            estop_ok=bool(io.estop_ok) if io else True,
            dead_processes=dead,
            stale_processes=tuple(stale),
            booting_processes=tuple(booting),
            max_speed_rad_s=w.max_speed_rad_s,
            still_for_s=0.0 if w.moving_s is None else now - w.moving_s,
            servo_on_for_s=0.0 if w.servo_on_s is None else now - w.servo_on_s,
            load_problem=self._load_problem(),
            driver_trips=dict(self.driver_trips),
            controller_fault_text=self.controller_fault_text,
        )

    def _load_problem(self) -> str | None:
        """Why the static-load check does not allow teaching (None: it passed, and recently)."""
        check = self.load_check
        waiting = "" if self.load_waiting is None else f": {self.load_waiting}"
        if check is None:
            return (
                "no static-load check from the control process yet (servo on, arm at rest)"
                + waiting
            )
        age = check.get("age_s")
        if not isinstance(age, int | float) or age > LOAD_CHECK_MAX_AGE_S:
            return f"the control process's static-load check is {age} s old{waiting}"
        if check.get("ok") is not True:
            return str(check.get("message", "static-load check failed"))
        return None

    def status(self, now: float) -> dict:
        obs = self.observations(now, self._dead)
        st = self.joint_state
        return {
            "state": self.machine.state.name.lower(),
            "reason": self.machine.reason,
            "seq": self.machine.seq,
            "can_start": not self.machine.start_problems(obs),
            "problems": self.machine.start_problems(obs),
            # why identify or replay would be refused now (empty: they would start)
            "play_problems": self.machine.play_problems(obs),
            "controller_state": None if st is None else st.controller_state.name.lower(),
            "enabling": obs.enabling,
            "estop_ok": obs.estop_ok,
            "load_problem": obs.load_problem,
            "joint_state_age_s": obs.joint_state_age_s,
            "io_age_s": obs.io_age_s,
            # what teaching waits for after servo-on (Limits.standstill_*)
            "standstill": {
                "speed_rad_s": obs.max_speed_rad_s,
                "still_for_s": round(obs.still_for_s, 3),
                "band_rad": round(self.watch.band_used_rad, 7),
            },
            "processes": {
                n: {
                    "running": c.proc is not None,
                    "pid": None if c.proc is None else c.proc.pid,
                    "exits": c.exits,
                }
                for n, c in self.children.items()
            },
            "q_rad": None if st is None else [round(float(v), 6) for v in st.q_rad],
            "program": self.teach.status(),
            "plan": self.machine.plan_result,
            # the control law's phase (control process health): "probing" while the
            # admittance measures the model's error at engagement
            "engagement": self.engagement,
            # constrained guiding: asked for at start (None: the control config's) and in force
            "guide": {"asked": self.guide, "control": self.guide_report},
            "model_adaptation": self.model_adaptation,
            "bus_refused": None if self.refusals is None else self.refusals.summary(),
        }

    def _on_experiment(self, sample) -> None:
        try:
            msg = decode_json(sample.payload.to_bytes(), "experiment")
            plan_id, state = str(msg["plan_id"]), str(msg["state"])
        except (MessageError, KeyError) as exc:
            log.warning("ignored experiment message: %s", exc)
            return
        if state == "planning":  # the control process builds it; the arm holds meanwhile
            with self.lock:
                self.machine.plan_progress(plan_id, 0.0, "planning")
        if state == "running":
            progress = msg.get("progress")
            playing = [s.get("label") for s in msg.get("segments") or []
                       if isinstance(s, dict) and s.get("start_cycle") is not None
                       and s.get("end_cycle") is None]  # fmt: skip
            if isinstance(progress, int | float) and math.isfinite(progress):
                with self.lock:
                    self.machine.plan_progress(
                        plan_id, float(progress), str(playing[-1]) if playing else None
                    )
        if state in ("done", "failed"):
            with self.lock:
                self.machine.plan_finished(plan_id, state == "done", str(msg.get("reason", "")))

    def _follow_program(self) -> None:
        """The tick's share of the taught program: segment starts and ends, the trace, the
        teach handle's marks, and closing it when the session ends, handed to the program's
        thread (the tick never waits for the disk); a disk that refused a write, or has not
        finished one for STALL_S, ends teaching with a fault."""
        with self.lock:
            m, st = self.machine, self.joint_state
            state, reason, presses = m.state, m.reason, self._handle_marks
            self._handle_marks = 0
        session = state not in (Lifecycle.STOPPED, Lifecycle.FAULT)
        self.teach.follow(
            state == Lifecycle.TEACHING, session, reason,
            None if st is None else st.stamp_s, None if st is None else st.cycle,
            None if st is None else st.q_rad,
        )  # fmt: skip
        for _ in range(presses):
            self._handle_marks_written.append(self._mark("", "handle", st, state))
        waiting = []
        for written in self._handle_marks_written:
            if not written.done():
                waiting.append(written)
                continue
            ok, message = written.result()  # refused: a press too early, not a fault
            (log.info if ok else log.warning)("teach handle mark: %s", message)
        self._handle_marks_written = waiting
        if (failure := self.teach.failure()) is not None:
            self._program_failed(failure)
        stalled_s = self.teach.stalled_s(time.monotonic())
        if stalled_s > STALL_S and not self._program_stall_reported:
            self._program_stall_reported = True
            self.teach.abandon()
            self._program_failed(
                ProgramError(f"the disk has not finished a write for {stalled_s:.1f} s")
            )
        elif stalled_s == 0.0:
            self._program_stall_reported = False

    def _program_failed(self, exc: ProgramError) -> None:
        """The program cannot be written (disk full, removed, stalled): teaching stops with a
        fault, so the operator does not go on guiding a path that is not being kept (the
        program's thread has closed it as far as the disk allows)."""
        log.error("taught program: %s", exc)
        with self.lock:
            self.machine.fault(f"the taught program could not be written: {exc}")

    def _publish_lifecycle(self, now: float) -> None:
        m = self.machine
        if m.seq != self._last_seq or now - self._last_pub_s >= 1.0 / LIFECYCLE_RATE_HZ:
            extra: dict = {"plan": m.plan} if m.state in PLAYING and m.plan else {}
            if self.guide is not None and m.state in (Lifecycle.READY, Lifecycle.TEACHING):
                extra["guide"] = self.guide
            msg = LifecycleMsg(m.state, m.seq, now, m.reason, extra)
            self.session.put(self.keys.lifecycle, msg.to_bytes())
            if m.seq != self._last_seq:
                log.info("lifecycle → %s (%s)", m.state.name, m.reason)
            self._last_pub_s, self._last_seq = now, m.seq

    # --- main -----------------------------------------------------------------------------
    def open(self) -> None:
        self.session = open_router(self.bus)
        if isinstance(self.session, LockedRouter):
            self.refusals = BusRefusals(self.session.refusals)
        s = self.session
        self._state_sub = s.declare_subscriber(
            self.keys.state_window, zenoh.handlers.RingChannel(JOINT_STATE_QUEUE)
        )
        self._requests = s.declare_queryable(
            self.keys.request, zenoh.handlers.FifoChannel(REQUEST_QUEUE)
        )
        self._decls = [
            self._state_sub,
            s.declare_subscriber(self.keys.io_state, self._on_io),
            s.declare_subscriber(self.keys.health_all, self._on_health),
            s.declare_subscriber(self.keys.experiment, self._on_experiment),
            self._requests,
        ]
        if self.spawn:
            for name in self.cfg.processes:
                child = Child(name, self._argv(name))
                self.children[name] = child
                self._start_child(child)

    def run(self, notifier: Notifier | None = None) -> None:
        """The supervision loop until :meth:`stop`; pings systemd's watchdog (``notifier``)
        from each tick, so a loop that hangs gets the service restarted."""
        while not self.stop_event.wait(TICK_S):
            now = time.monotonic()
            if notifier is not None:
                notifier.watchdog(now)
            dead = tuple(self._poll_children(now))
            with self.lock:
                self._take_states()
                self._dead = dead
                before = self.machine.state
                self.machine.update(self.observations(now, dead))
                if before != self.machine.state and self.machine.state == Lifecycle.FAULT:
                    log.error("FAULT: %s", self.machine.reason)
            self._follow_program()
            if self.refusals is not None:
                self.refusals.poll()
            self._serve_requests()
            with self.lock:
                self._publish_lifecycle(now)

    def close(self) -> None:
        try:
            if self.session is not None:
                with self.lock:
                    if self.machine.state != Lifecycle.FAULT:
                        self.machine.command("stop", self.observations(time.monotonic()))
                    self._publish_lifecycle(time.monotonic())
                    st = self.joint_state
                t0 = time.monotonic()
                self.teach.close(None if st is None else st.stamp_s, "gateway stopped")
                self._answer_marks(give_up=True)
                # let the drivers brake before they are stopped
                time.sleep(max(STOP_GRACE_S - (time.monotonic() - t0), 0.0))
        finally:
            self._stop_children()
            undeclare_all(self._decls)
            self._decls, self._state_sub, self._requests = [], None, None
            if self.session is not None:
                self.session.close()
                self.session = None

    def stop(self) -> None:
        self.stop_event.set()


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the gateway: the zenoh router, the CAN driver, the Modbus driver and the control "
        "process, and the lifecycle (stopped → ready → teaching, fault). The robot stays "
        "braked until an operator sends `leadthrough start` and holds the enabling device."
    )
    p.add_argument("--config", type=Path, required=True, help="cell config TOML")
    p.add_argument("--bus", default=None, help="zenoh endpoint to listen on (overrides config)")
    p.add_argument("--no-spawn", action="store_true", help="do not start the child processes")


def cli_main(args: argparse.Namespace) -> int:
    """Run until SIGTERM/SIGINT (:func:`gateway.runner.run_service`, as systemd's main
    process): 0 on a clean stop, EXIT_CONFIG (78) when any section of the cell config is
    refused (each error logged once, with file, section and key), 1 on any other failure."""

    def build() -> Gateway:
        cfg, bus = load_gateway_config(args.config)
        if not args.no_spawn:  # the children's sections, reported here once (config_check.py)
            from gateway.config_check import gateway_start_sections, problems

            errors = problems(args.config, gateway_start_sections())
            for message in errors:
                log.error("cell config refused: %s", message)
            if errors:
                raise ConfigError(
                    f"{len(errors)} error(s) in {args.config}: the gateway does not start"
                )
        bus = bus.with_overrides(args.bus)
        return Gateway(args.config.resolve(), bus, cfg, spawn=not args.no_spawn)

    return run_service(
        "gateway", build, notify=True, status=lambda gw: f"serving the cell on {gw.bus.endpoint}",
        place=getattr(args, "place", None),
    )  # fmt: skip
