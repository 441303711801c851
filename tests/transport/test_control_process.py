"""The control process over a real zenoh router: bad messages are refused and counted, and no
command is published unless the gateway says TEACHING with fresh pressures."""

import math
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from example_cell import ADMITTANCE_ALONE, example_cell

from control.cell_config import load_control_config
from control.process import ControlProcess
from gateway.bus import BusConfig, open_client, open_router
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState, IoState, JointCommand, Lifecycle, LifecycleMsg

Q0 = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
ROOT = Path(__file__).resolve().parents[2]
PUBLISHER = Path(__file__).with_name("delayed_state_publisher.py")
#: The GIL held by the test [us], and the other process's delay before it publishes [s]:
#: a state arriving 0.1 s into a 0.5 s hold leaves 0.4 s for a slow machine to answer it.
HOLD_US = 500_000
DELAY_S = 0.1


@pytest.fixture
def rig(port, tmp_path):
    yield from control_rig(port, tmp_path)


@pytest.fixture
def admittance_rig(port, tmp_path):
    yield from control_rig(port, tmp_path, **ADMITTANCE_ALONE)


def control_rig(port, tmp_path, **control):
    """A control process of the example cell (``control``: its [control] settings) on a
    router of its own, a client and the commands it publishes."""
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}")
    router = open_router(bus)
    cfg, _ = load_control_config(example_cell(tmp_path, **control))
    proc = ControlProcess(cfg, bus)
    proc.open()
    client = open_client(bus)
    commands: list[JointCommand] = []
    sub = client.declare_subscriber(
        bus.keys.joint_command,
        lambda s: commands.append(JointCommand.from_bytes(s.payload.to_bytes())),
    )
    time.sleep(0.5)  # declarations reach every session
    yield bus, client, proc, commands
    sub.undeclare()
    client.close()
    proc.close()
    router.close()


def state(cycle: int) -> bytes:
    return make_joint_state(
        cycle, time.monotonic(), ControllerState.EXTERNAL, 2, Q0, np.zeros(6), np.zeros(6), Q0,
        np.zeros(6), 0.008,
    ).to_bytes()  # fmt: skip


def settle() -> None:
    time.sleep(0.3)


def state_while_the_gil_is_held(
    endpoint: str, cycle: int, refresh: Callable[[], None]
) -> tuple[float, float]:
    """A joint state of ``cycle`` arrives while this process holds its GIL: a publisher
    process, once ready, is told to publish it DELAY_S later, ``refresh`` having made the
    lifecycle and pressures fresh, and this process holds the GIL for HOLD_US (a C call that
    keeps it). Returns when the hold began and ended (monotonic [s]).

    The state comes from another process, DELAY_S after this one holds its GIL: put from here,
    it could be answered before the hold began (a fast machine did, 52 us after the put,
    before the next line ran), and the test would prove nothing."""
    import ctypes

    publisher = subprocess.Popen(
        [sys.executable, str(PUBLISHER), endpoint, str(cycle), str(DELAY_S)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        assert publisher.stdout is not None and publisher.stdin is not None
        assert publisher.stdout.readline().strip() == "ready"
        refresh()
        time.sleep(0.05)
        publisher.stdin.write("go\n")
        publisher.stdin.flush()
        held_from = time.monotonic()
        ctypes.PyDLL(None).usleep(HOLD_US)  # PyDLL: the GIL stays held through the call
        held_until = time.monotonic()
        assert publisher.wait(timeout=10) == 0
    finally:
        publisher.kill()
        publisher.wait()
    return held_from, held_until


def test_commands_only_while_teaching_with_fresh_pressures(rig):
    bus, client, proc, commands = rig
    keys = bus.keys
    client.put(keys.joint_state, state(1))
    settle()
    assert commands == [], "a command without the gateway's TEACHING"
    client.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, 1, time.monotonic()).to_bytes())
    time.sleep(0.05)
    client.put(keys.joint_state, state(2))
    settle()
    assert commands == [] and proc.stats["io_stale"] == 1, "a command without cylinder pressures"
    # as the gateway and the Modbus driver do: fresh lifecycle and pressures, then the state
    client.put(keys.io_state, IoState(time.monotonic(), 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
    client.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, 1, time.monotonic()).to_bytes())
    time.sleep(0.05)
    client.put(keys.joint_state, state(3))
    settle()
    assert [c.cycle for c in commands] == [3]
    assert np.all(np.isfinite(commands[0].q_cmd_rad))
    assert np.max(np.abs(commands[0].q_cmd_rad - Q0)) < 0.02  # bumpless: starts at the echo


def test_garbage_and_nan_messages_are_refused_and_counted(rig):
    bus, client, proc, commands = rig
    keys = bus.keys
    client.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, 1, time.monotonic()).to_bytes())
    client.put(keys.io_state, IoState(time.monotonic(), 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
    nan_io = IoState(time.monotonic(), math.nan, 4.0, 6.0, 4.0, True, True).to_bytes()
    for bad in ((keys.joint_state, b"not a joint state"), (keys.io_state, nan_io),
                (keys.lifecycle, b'{"state": "teaching", "seq": 1, "stamp_s": NaN}')):  # fmt: skip
        client.put(*bad)
    settle()
    assert proc.stats["bad_messages"] == 3
    assert commands == [], "a command was published from a malformed message"


def test_held_arm_at_rest_is_checked_against_the_models_static_load(rig):
    """READY (not commanding), servo on, at rest: the process checks the static load (its
    health reports the verdict); a held current far from the model's fails naming the joint."""
    bus, client, proc, commands = rig
    keys = bus.keys
    model = proc.ctl.model
    gains = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    p = np.array([6.0, 4.0])
    held = (model.gravity_nm(Q0) - model.cylinder_nm(Q0, p)) / gains
    for k, current in enumerate((held, held + np.array([0, 0, 100.0, 0, 0, 0]) / gains)):
        client.put(keys.io_state, IoState(time.monotonic(), *p, *p, True, True).to_bytes())
        time.sleep(0.05)
        st = make_joint_state(10 + k, time.monotonic(), ControllerState.HOLD, 2, Q0, np.zeros(6),
                              current, Q0, np.zeros(6), 0.008)  # fmt: skip
        client.put(keys.joint_state, st.to_bytes())
        settle()
        assert proc.load_check is not None and proc.load_check.ok is (k == 0), proc.load_check
    assert proc.load_check.joint == 3 and "joint 3" in proc.load_check.message
    assert commands == []


def test_a_held_state_not_checked_says_why(rig):
    """The operator waits for the static-load check before teaching; while none comes, the
    control process says why (its health carries it to the status): the arm not at rest,
    naming the joint, or pressures too old to check against."""
    bus, client, proc, commands = rig
    keys = bus.keys
    p = (6.0, 4.0)

    def held(cycle: int, dq: np.ndarray) -> None:
        st = make_joint_state(cycle, time.monotonic(), ControllerState.HOLD, 2, Q0, dq,
                              np.zeros(6), Q0, np.zeros(6), 0.008)  # fmt: skip
        client.put(keys.joint_state, st.to_bytes())
        settle()

    client.put(keys.io_state, IoState(time.monotonic(), *p, *p, True, True).to_bytes())
    time.sleep(0.05)
    held(20, np.array([0.0, 0.0, 0.0, 0.0, 0.004, 0.0]))  # J5 creeping at 4 mrad/s
    assert proc.load_check is None
    assert proc.load_waiting is not None and "J5 at 4.0 mrad/s" in proc.load_waiting
    time.sleep(proc.cfg.io_timeout_s + 0.05)  # the pressures age past the limit
    held(21, np.zeros(6))
    assert proc.load_check is None
    assert proc.load_waiting is not None and "pressures are" in proc.load_waiting
    assert commands == []


def test_teaching_is_answered_while_python_holds_the_gil(rig):
    """The compiled loop (control/rt/src/py_cycle_loop.rs): a teaching state is answered and
    the command sent while this process's Python is held (a C call that keeps the GIL for
    0.5 s): no Python on the path from the joint state to the command."""
    answered_while_python_holds_the_gil(rig)


def test_the_admittances_teaching_is_answered_while_python_holds_the_gil(admittance_rig):
    """As the zero-moment law's: the admittance's cycle is compiled
    (control/rt/src/law/admittance/cycle.rs), and the loop answers with it."""
    answered_while_python_holds_the_gil(admittance_rig)


def answered_while_python_holds_the_gil(rig) -> None:
    """The law engages on a first teaching state, then answers a second sent while this
    process's Python is held, from the compiled loop."""
    bus, client, proc, commands = rig
    keys = bus.keys
    client.put(keys.io_state, IoState(time.monotonic(), 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
    client.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, 1, time.monotonic()).to_bytes())
    time.sleep(0.05)
    client.put(keys.joint_state, state(1))  # engages (the example cell engages at once)
    settle()
    assert [c.cycle for c in commands] == [1]

    def refresh() -> None:
        now = time.monotonic()
        client.put(keys.io_state, IoState(now, 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
        client.put(keys.lifecycle, LifecycleMsg(Lifecycle.TEACHING, 2, now).to_bytes())

    held_from, held_until = state_while_the_gil_is_held(bus.endpoint, 2, refresh)
    settle()
    assert [c.cycle for c in commands] == [1, 2]
    # sent while held, with the state's delay before it and room after it
    assert held_from + DELAY_S < commands[1].sent_stamp_s < held_until - 0.1, (
        held_from,
        commands[1].sent_stamp_s,
        held_until,
    )
    assert proc._loop_report()["compiled_commands"] == 2


#: A short identification-like plan played under REPLAYING (the lifecycle's ``plan``).
REPLAY_PLAN = {
    "plan_id": "gil",
    "multisine": [
        {"seed": 1, "duration_s": 2.0, "amplitude_rad": 0.01, "base_hz": 0.5, "harmonics": 2}
    ],
    "pause_s": 0.0,
}
#: How long the plan builder (a worker process) may take to build it [s].
BUILD_TIMEOUT_S = 30.0


def test_a_replay_is_held_and_played_by_the_compiled_loop_while_python_holds_the_gil(rig):
    """The compiled loop answers a replay's cycles from its first: while the plan is built
    (control/plan_player.py) with the pose the arm holds, at rest, then the built plan
    (control/rt/src/law/plan_play.rs), taken by the slow loop's :meth:`PlanPlayer.poll`; a
    state sent while this process's Python is held is answered then, as teaching's is."""
    bus, client, proc, commands = rig
    keys = bus.keys

    def replaying(seq: int) -> None:
        now = time.monotonic()
        client.put(keys.io_state, IoState(now, 6.0, 4.0, 6.0, 4.0, True, True).to_bytes())
        msg = LifecycleMsg(Lifecycle.REPLAYING, seq, now, "", {"plan": REPLAY_PLAN})
        client.put(keys.lifecycle, msg.to_bytes())

    cycle, deadline = 1, time.monotonic() + BUILD_TIMEOUT_S
    while proc.player.state != "running" and time.monotonic() < deadline:
        replaying(cycle)  # the lifecycle stays fresh
        time.sleep(0.02)
        client.put(keys.joint_state, state(cycle))
        cycle += 1
        time.sleep(0.03)
        proc.player.poll()  # what the slow loop (ControlProcess.run) does every 0.1 s
    assert proc.player.state == "running", proc.player.report()
    settle()
    held = commands[:]
    assert len(held) == cycle - 1  # every cycle answered while planning
    # the first state came to Python, which started the plan; the loop answered the others
    assert proc._loop_report()["compiled_commands"] == len(held) - 1 > 0
    for c in held:  # where the plan starts (the held pose and the load's offset), at rest
        np.testing.assert_array_equal(c.q_cmd_rad, held[0].q_cmd_rad)
        assert not np.any(c.dq_cmd_rad_s)
    replaying(cycle)
    time.sleep(0.05)
    client.put(keys.joint_state, state(cycle))  # the built plan's first cycle
    settle()
    assert proc._loop_report()["compiled_commands"] == len(held)
    held_from, held_until = state_while_the_gil_is_held(
        bus.endpoint, cycle + 1, lambda: replaying(cycle + 1)
    )
    settle()
    last = commands[-1]
    assert last.cycle == cycle + 1
    assert held_from + DELAY_S < last.sent_stamp_s < held_until - 0.1, (
        held_from,
        last.sent_stamp_s,
        held_until,
    )
    assert proc._loop_report()["compiled_commands"] == len(held) + 1
    report = proc.player.report()
    assert report["state"] == "running" and report["segments"][0]["start_cycle"] == cycle
