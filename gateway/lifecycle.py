"""The gateway's lifecycle state machine (pure: no I/O, clock passed in).

    STOPPED --start [links healthy]--> READY --enabling held, servo on, still, load ok--> TEACHING
       ^                                 ^  <--enabling released---------     |
       |---------------- stop -----------+-----------------------------------+
    any --fault condition--> FAULT --reset [cause gone]--> STOPPED
    READY|TEACHING --identify PLAN [enabling held, servo on]--> IDENTIFYING
    READY|TEACHING --replay PLAN [enabling held, servo on]--> REPLAYING
    IDENTIFYING|REPLAYING --plan done | enabling released--> READY

STOPPED is the initial state and the state `stop` leads to from anywhere but FAULT. A robot
controller in FAULT (after a crash of this service, its host heartbeat lost) makes STOPPED a
FAULT too, so that `reset` — which the CAN driver forwards as the controller's RESET_FAULT —
clears both; the controller then has :data:`CONTROLLER_RESET_UPDATES` updates to leave its
FAULT before the gateway faults again. Every fault
condition wins over every operator command. Like ros2_control's hardware lifecycle, READY means
"link up, states readable, holding still": only TEACHING lets the control process's commands
through (the CAN driver checks the same conditions again before forwarding a command). Teaching
starts only when the control process reports that the model carries the arm's static load
(``load_problem`` None): a load the model lacks would fall as soon as the arm is weightless.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from gateway.messages import PLAYING, SERVO_ON, ControllerState, Lifecycle

#: The CAN driver's latched trips: the key of its health report → how the gateway names it.
#: Each faults the cell and refuses a reset while it stands; the driver clears it once the
#: cell is stopped and the cause has gone.
DRIVER_TRIPS = {
    "speed_trip": "CAN driver's speed monitor",  # drivers/can/rt/src/speed_monitor.rs
    "standstill_trip": "CAN driver's standstill monitor",  # drivers/can/rt/src/stop_ramp.rs
    "bus_fault": "CAN bus",  # drivers/can/rt/src/bus_errors.rs: bus-off, an error burst
    "lost_cycles_trip": "CAN driver's command link",  # drivers/can/rt/src/lost_cycles.rs
}


@dataclass(frozen=True)
class Observations:
    """What the gateway knows about the cell at one instant; ages in [s], None = never seen."""

    joint_state_age_s: float | None
    io_age_s: float | None
    controller_state: ControllerState | None
    enabling: bool
    estop_ok: bool
    dead_processes: tuple[str, ...] = ()
    stale_processes: tuple[str, ...] = ()
    #: started within [gateway].boot_grace_s and no heartbeat yet: not silent, not up either
    booting_processes: tuple[str, ...] = ()
    max_speed_rad_s: float | None = None  #: fastest joint in the latest joint state
    #: how long the arm has been still: no joint left a band of standstill_rad_s·standstill_s
    #: and none read faster than 10 standstill speeds (gateway/joint_state_watch.py JointStateWatch)
    still_for_s: float = 0.0
    #: how long the drives have held or followed without a break (servo on) [s]; 0: off or
    #: not known (gateway/joint_state_watch.py JointStateWatch.servo_on_s)
    servo_on_for_s: float = 0.0
    #: why the model does not match the arm's static load (control/load_check.py); None: it does
    load_problem: str | None = None
    #: the CAN driver's latched trips, health key → what it measured (:data:`DRIVER_TRIPS`)
    driver_trips: Mapping[str, str] = field(default_factory=dict)
    #: the controller's fault in the CAN driver's words ("J2 fault EMCY 0x8611"), from its
    #: health while the controller reports FAULT; None: not known (yet)
    controller_fault_text: str | None = None


#: how the gateway names a controller's FAULT (with its cause, when the CAN driver tells it)
CONTROLLER_FAULT = "robot controller reports FAULT"


def controller_fault(obs: Observations) -> str:
    """The problem a faulted controller is: :data:`CONTROLLER_FAULT`, with the cause the CAN
    driver gave."""
    text = obs.controller_fault_text
    return f"{CONTROLLER_FAULT} ({text})" if text else CONTROLLER_FAULT


@dataclass(frozen=True)
class Limits:
    joint_state_timeout_s: float = 0.1
    io_timeout_s: float = 0.25
    #: teaching (and identification) start only from standstill: after servo-on the arm first
    #: settles onto the vendor loop's position error, and a weightless arm would keep any
    #: velocity it has at takeover. Still: for ``standstill_s`` [s] no joint moved farther
    #: than ``standstill_rad_s`` [rad/s] would take it, and no state read a joint faster than
    #: 10 times that. A vendor loop holding on a quantised encoder dithers by 1-2 mrad/s
    #: without going anywhere (measured on the virtual cell: ±1.4 mrad/s on J4 for 15 s, the
    #: position still to 0.1 mrad), which is why positions, not the newest speed, decide.
    standstill_rad_s: float = 2e-3
    standstill_s: float = 0.3
    #: teaching starts only once the servo has been on this long [s]. At servo-on the drives
    #: catch the arm's weight and their current rings before it settles; the zero-moment law
    #: calibrates ω̂ and its dead zone (the torque's spread at rest) from the hold's last 64
    #: states when it takes over (control/rt/src/law/zero_moment/engagement.rs), 0.51 s at an
    #: 8 ms cycle, so those states must all come after the ringing. Measured on the virtual
    #: cell (seed 0, 8 ms): J2/J3 current spread 0.09 A over 0.1-0.4 s after servo-on, at the
    #: noise (0.02 A) from 0.3 s; engaged 0.4 s after servo-on, an arm carrying an 8 kg gun on
    #: its identified model drifted 1.38 and 1.45 mm in 5 s, engaged 1.5 s or more after it
    #: 0.22-0.29 mm (issue 2's bound: 1 mm). 0.3 s ringing + 0.51 s of states, rounded up.
    servo_settle_s: float = 1.0


#: updates (gateway ticks, 10 ms) a robot controller has to leave FAULT after a reset
CONTROLLER_RESET_UPDATES = 200


@dataclass
class LifecycleMachine:
    limits: Limits = field(default_factory=Limits)
    state: Lifecycle = Lifecycle.STOPPED
    reason: str = "initial state"
    seq: int = 0
    #: the plan being played while IDENTIFYING or REPLAYING (JSON-able), with its "plan_id"
    plan: dict | None = None
    #: how the last plan went: {"plan_id", "state": running|done|failed|aborted, "reason"}
    plan_result: dict | None = None
    #: updates left for the robot controller to leave FAULT after a reset (0: none pending)
    controller_reset_left: int = 0

    def _go(self, state: Lifecycle, reason: str) -> None:
        if state != self.state or reason != self.reason:
            self.seq += 1
        running = self.plan_result is not None and self.plan_result["state"] == "running"
        if running and self.state in PLAYING and state != self.state:
            assert self.plan_result is not None
            self.plan_result = {**self.plan_result, "state": "aborted", "reason": reason}
        self.state, self.reason = state, reason

    def link_problems(self, obs: Observations) -> list[str]:
        """Why the cell cannot be started now (empty list: it can)."""
        problems = []
        if obs.dead_processes:
            problems.append(f"process(es) not running: {', '.join(obs.dead_processes)}")
        if obs.stale_processes:
            problems.append(f"process(es) silent: {', '.join(obs.stale_processes)}")
        lim = self.limits
        if obs.joint_state_age_s is None or obs.joint_state_age_s > lim.joint_state_timeout_s:
            problems.append("no fresh joint state from the CAN driver")
        if obs.io_age_s is None or obs.io_age_s > lim.io_timeout_s:
            problems.append("no fresh I/O state from the Modbus driver")
        if not obs.estop_ok:
            problems.append("e-stop chain open")
        if obs.controller_state == ControllerState.FAULT:
            problems.append(controller_fault(obs))
        for key, label in DRIVER_TRIPS.items():
            if obs.driver_trips.get(key):
                problems.append(f"{label}: {obs.driver_trips[key]}")
        return problems

    def start_problems(self, obs: Observations) -> list[str]:
        """Why ``start`` is refused now (empty list: it is accepted): the link's problems, and
        a process still starting. A booting process is no fault (nothing moves while it
        boots), but the cell does not servo on before every process it runs is up: on a slow
        machine control's first heartbeat came 12 s after its start ([gateway].boot_grace_s),
        and a start accepted meanwhile held the arm at servo-on with teaching blocked for
        that long."""
        problems = self.link_problems(obs)
        if obs.booting_processes:
            problems.append(f"process(es) still starting: {', '.join(obs.booting_processes)}")
        return problems

    def update(self, obs: Observations) -> Lifecycle:
        """Apply the automatic transitions for the latest observations."""
        if self.state in (Lifecycle.READY, Lifecycle.TEACHING, *PLAYING):
            problems = self.link_problems(obs)
            if problems:
                self._go(Lifecycle.FAULT, "; ".join(problems))
                return self.state
            if self.state in PLAYING:
                if not obs.enabling:
                    what = self.state.name.lower()
                    self._go(Lifecycle.READY, f"{what} aborted: enabling device released")
                return self.state
            servo_on = obs.controller_state in SERVO_ON
            settled = servo_on and obs.servo_on_for_s >= self.limits.servo_settle_s
            if self.state == Lifecycle.READY and obs.enabling and settled and self._still(obs):
                if obs.load_problem is None:
                    self._go(Lifecycle.TEACHING, "enabling device held")
                else:
                    self._go(Lifecycle.READY, f"teaching blocked: {obs.load_problem}")
            elif self.state == Lifecycle.TEACHING and not obs.enabling:
                self._go(Lifecycle.READY, "enabling device released")
        elif self.state == Lifecycle.STOPPED and not obs.estop_ok and obs.io_age_s is not None:
            self._go(Lifecycle.FAULT, "e-stop chain open")
        elif self.state == Lifecycle.STOPPED and obs.controller_state == ControllerState.FAULT:
            if self.controller_reset_left > 0:
                self.controller_reset_left -= 1  # the reset is on its way to the controller
            else:
                self._go(Lifecycle.FAULT, f"{controller_fault(obs)}; reset to clear it")
        elif (
            self.state == Lifecycle.FAULT
            and obs.controller_state == ControllerState.FAULT
            and obs.controller_fault_text
            and CONTROLLER_FAULT in self.reason
            and f"{CONTROLLER_FAULT} (" not in self.reason
        ):
            # the cause comes with the CAN driver's health, up to a health period after the
            # joint state that reported the FAULT: name it once it is known
            named = self.reason.replace(CONTROLLER_FAULT, controller_fault(obs), 1)
            self._go(Lifecycle.FAULT, named)
        if obs.controller_state != ControllerState.FAULT:
            self.controller_reset_left = 0
        return self.state

    def command(self, name: str, obs: Observations) -> tuple[bool, str]:
        """Apply an operator command; returns (accepted, message)."""
        if name == "status":
            return True, self.reason
        if name == "stop":
            if self.state == Lifecycle.FAULT:
                return True, f"already stopped by fault ({self.reason}); use reset to clear it"
            self._go(Lifecycle.STOPPED, "stop requested by operator")
            return True, "stopped: brakes engaged"
        if name == "start":
            if self.state in (Lifecycle.READY, Lifecycle.TEACHING, *PLAYING):
                return True, f"already {self.state.name.lower()}"
            if self.state == Lifecycle.FAULT:
                return False, f"in fault ({self.reason}); use reset first"
            problems = self.start_problems(obs)
            if problems:
                return False, "cannot start: " + "; ".join(problems)
            self._go(Lifecycle.READY, "started by operator; hold the enabling device to teach")
            return True, self.reason
        if name == "reset":
            if self.state != Lifecycle.FAULT:
                return True, f"nothing to reset (state {self.state.name.lower()})"
            # the controller's own FAULT is what this reset clears (the CAN driver sends it)
            problems = self.link_problems(replace(obs, controller_state=None))
            if problems:
                return False, "fault cause still present: " + "; ".join(problems)
            if obs.controller_state == ControllerState.FAULT:
                self.controller_reset_left = CONTROLLER_RESET_UPDATES
            self._go(Lifecycle.STOPPED, "fault reset by operator")
            return True, self.reason
        return False, f"unknown command {name!r}; use start, stop, status or reset"

    def _still(self, obs: Observations) -> bool:
        """The arm has been still for ``standstill_s``, as the joint-state watch judges it
        from positions (gateway/joint_state_watch.py ``JointStateWatch``): not from the newest
        measured speed, whose noise and a hold's dither would keep teaching waiting."""
        return obs.max_speed_rad_s is not None and obs.still_for_s >= self.limits.standstill_s

    def identify(self, plan: dict, obs: Observations) -> tuple[bool, str]:
        """Start an excitation plan (operator command `identify`)."""
        return self.play(Lifecycle.IDENTIFYING, plan, obs)

    def play_problems(self, obs: Observations, verb: str = "a plan") -> list[str]:
        """Why ``verb`` (identify, replay) would be refused now, most basic first (empty: it
        would start). The status publishes them, so that a client waits for exactly what
        :meth:`play` checks: on one CPU the arm was still (brakes) 1.7 s before the
        controller reported servo-on, and an identify sent on the standstill alone was
        refused."""
        if self.state not in (Lifecycle.READY, Lifecycle.TEACHING):
            return [f"{verb} needs state ready, not {self.state.name.lower()}"]
        problems = []
        if not obs.enabling:
            problems.append("hold the enabling device: the robot will move by itself")
        if obs.controller_state not in SERVO_ON:
            problems.append("robot controller is not servo-on yet")
        elif self.state == Lifecycle.READY and not self._still(obs):
            problems.append("the robot is still settling after servo-on; try again")
        return problems

    def play(self, state: Lifecycle, plan: dict, obs: Observations) -> tuple[bool, str]:
        """Start playing ``plan`` in ``state`` (IDENTIFYING: an excitation plan, operator
        command `identify`; REPLAYING: a taught program, `replay`)."""
        assert state in PLAYING
        verb = "identify" if state == Lifecycle.IDENTIFYING else "replay"
        problems = self.play_problems(obs, verb)
        if problems:
            return False, problems[0]
        self.plan = plan
        self.plan_result = {"plan_id": plan.get("plan_id"), "state": "running", "reason": ""}
        what = "excitation plan" if state == Lifecycle.IDENTIFYING else "taught program"
        self._go(state, f"running {what} {plan.get('plan_id')}")
        return True, self.reason

    def plan_finished(self, plan_id: str, ok: bool, why: str) -> None:
        """The control process reports the plan ended (done, or refused/aborted)."""
        if self.state in PLAYING and self.plan and self.plan.get("plan_id") == plan_id:
            reason = f"plan {plan_id} {'done' if ok else 'failed: ' + why}"
            self.plan_result = {"plan_id": plan_id, "state": "done" if ok else "failed",
                                "reason": reason}  # fmt: skip
            self._go(Lifecycle.READY, reason)

    def plan_progress(self, plan_id: str, progress: float, segment: str | None) -> None:
        """The control process reports how far the running plan is: ``progress`` (0..1) and
        the segment it plays (for `leadthrough identify`'s progress lines)."""
        r = self.plan_result
        if r is not None and r["state"] == "running" and r.get("plan_id") == plan_id:
            self.plan_result = {**r, "progress": progress, "segment": segment}

    def fault(self, reason: str) -> None:
        """Enter FAULT from any state (used by error paths)."""
        self._go(Lifecycle.FAULT, reason)
