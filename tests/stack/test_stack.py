"""The whole product on the virtual cell, every part its own process, as a user runs it:
`leadthrough sim` + `leadthrough gateway` (CAN driver, Modbus driver, control), driven through
the operator commands. Physical outcomes are judged from the simulator's truth log."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from gateway.gateway_config import GatewayConfig
from gateway.messages import ControllerState
from sim_bridge.cia402_drives import MOVED_WITHIN_SYNCS
from sim_bridge.commission import commissioned_stack
from sim_bridge.harness import CAN_PROFILES, TOOL_COLUMNS, Stack, TruthTail, tail_tool_speed

pytestmark = pytest.mark.stack


def tool_xyz(truth: dict[str, np.ndarray], mask: np.ndarray) -> np.ndarray:
    return np.stack([truth[f"tool_{a}"][mask] for a in "xyz"], axis=1)


def teaching_rows(truth: dict[str, np.ndarray]) -> np.ndarray:
    rows = np.flatnonzero(truth["teaching"] > 0.5)
    assert rows.size, "the robot never followed the control process's commands"
    return rows


def tool_speed(truth: dict[str, np.ndarray], rows: np.ndarray, span: int = 5) -> np.ndarray:
    """The tool's speed [m/s] over ``span`` truth rows, at each of ``rows`` but the last
    ``span``."""
    t, xyz = truth["t_s"][rows], tool_xyz(truth, rows)
    return np.linalg.norm(xyz[span:] - xyz[:-span], axis=1) / (t[span:] - t[:-span])


PROFILES = CAN_PROFILES


def cycle_record(stack: Stack) -> str:
    """What the virtual controller saw of the command cycle (its summary, written when it
    exited): printed beside a physical verdict, so a failure under load tells a starved cycle
    (commands missed, the simulator's own overruns and late wake-ups) from the law's doing."""
    try:
        s = json.loads(stack.sim_summary.read_text())
    except (OSError, ValueError) as exc:
        return f"no simulator summary: {exc}"
    keys = ("teaching_cycles", "teaching_missed_cycles", "controller_missed_cycles", "overruns",
            "late_frames", "latency_p99_s", "wake_late_max_s")  # fmt: skip
    return "virtual controller: " + ", ".join(f"{k} {s.get(k)}" for k in keys)


def rest_without_operator(tmp_path, sim_overrides=None, cell_overrides=None):
    """Teach for 5 s with no hand on the tool: (truth, its first 5 s of teaching rows, the
    tool's largest distance from where it started [m])."""
    with commissioned_stack(
        tmp_path, sim_overrides=sim_overrides, cell_overrides=cell_overrides
    ) as stack:
        stack.start()
        stack.start_teaching()
        truth = stack.wait_teaching(5.2, 30.0)
        stack.request("stop")
    print(cycle_record(stack))
    rows = teaching_rows(truth)
    t = truth["t_s"][rows]
    window = rows[t - t[0] <= 5.0]
    xyz = tool_xyz(truth, window)
    # and it really was the control process holding it (weightless), not brakes
    assert np.all(truth["ctrl_state"][window] == 2)
    return truth, window, float(np.linalg.norm(xyz - xyz[0], axis=1).max())


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_weightless_arm_without_operator_drifts_less_than_1mm_in_5s(tmp_path, profile):
    """The plant has true stiction (its default truth): a zero-moment law that switched its
    friction compensation on in full at the first measured motion made the wrists chatter
    (±20-40 mrad/s, J4 and J6 drifting 6 mrad in 5 s); ramped in over the speed the loop's
    delay allows ([control] friction_ramp_factor), the arm rests."""
    truth, window, drift_m = rest_without_operator(tmp_path, *PROFILES[profile])
    speed = np.abs(np.stack([truth[f"dq{j + 1}"][window] for j in range(6)], axis=1))
    row, j = np.unravel_index(int(np.argmax(speed)), speed.shape)
    t_s = truth["t_s"][window]
    print(f"{profile}: tool drift {drift_m * 1e3:.3f} mm, fastest joint J{j + 1} "
          f"{speed.max() * 1e3:.2f} mrad/s at {t_s[row] - t_s[0]:.2f} s, per joint "
          f"{np.round(speed.max(axis=0) * 1e3, 2).tolist()} mrad/s in 5 s without operator "
          f"force")  # fmt: skip
    assert drift_m < 1e-3, f"tool drifted {drift_m * 1e3:.3f} mm in 5 s"
    # the chatter this guards against ran at 20-40 mrad/s; at rest the fastest joint reads
    # ~2.5 mrad/s here, and once 5.3 under make test's load (a held cycle's transient)
    assert speed.max() < 10e-3, f"a joint chattered at {speed.max() * 1e3:.1f} mrad/s"


def test_the_can_drivers_speed_monitor_stops_an_arm_the_law_lets_run(tmp_path):
    """The CAN driver's own speed monitor (drivers/can/rt/src/speed_monitor.rs), from measured
    positions: with the control law's speed limit taken away ([control] max_tool_speed_m_s =
    0), a hand that drags the tool towards a point moving along x at 350 mm/s (a
    spring-damper, 80 N at most: enough to break J2 and J3 away from their stiction) takes
    the weightless arm past 250 mm/s; the driver holds, the arm stops and the gateway faults
    naming the speed, and stays stopped until a reset. The hand pulls harder the further the
    tool falls behind, so a machine that holds a few cycles does not decide the verdict (a
    constant 60 N push reached 251-254 mm/s on one core, 1-2 % over the limit)."""
    operator = {
        "mode": "path",
        "path": [[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0], [2.5, 0.7, 0.0, 0.0]],
        "hand_stiffness_n_per_m": 1500.0,
        "hand_damping_n_s_per_m": 100.0,
        "max_force_n": 80.0,
    }
    with commissioned_stack(
        tmp_path, sim_overrides={"operator": operator},
        cell_overrides={"control": {"max_tool_speed_m_s": 0.0}},
    ) as stack:  # fmt: skip
        stack.start()
        stack.start_teaching()
        status = stack.wait_status(lambda s: s.get("state") == "fault", 15.0, "the speed fault")
        time.sleep(1.0)
        truth = stack.truth()
        still = stack.request("status")
    assert "speed monitor" in status["reason"] and "mm/s" in status["reason"], status["reason"]
    assert still["state"] == "fault"
    rows = teaching_rows(truth)
    t = truth["t_s"][rows]
    span = 5
    speed = tool_speed(truth, rows, span)
    tripped = int(np.argmax(speed > 0.25))
    after_ms = (t[-1] - t[tripped + span]) * 1e3
    print(f"speed monitor: the tool reached {speed.max() * 1e3:.0f} mm/s; "
          f"{after_ms:.0f} ms of teaching after it passed 250 mm/s")  # fmt: skip
    # The monitor judges from measured positions with the datasheet's kinematics, the tool
    # point and the flange; the truth log has the plant's own tool point. They differ by a few
    # per cent (CI: the monitor tripped over 250 mm/s while the truth's tool read 249), so the
    # monitor's own figure must be over the limit and the truth's close to it: the trip was
    # not one of a slow arm.
    measured = re.search(r"moved at (\d+) mm/s", status["reason"])
    assert measured and int(measured.group(1)) > 250, status["reason"]
    assert speed.max() > 0.9 * 0.25, "the push never came near the limit: nothing was tested"
    assert speed.max() < 0.4, f"the arm reached {speed.max() * 1e3:.0f} mm/s before it stopped"
    # after the trip the arm is held: the tool rests once the hold has braked it
    tail = np.flatnonzero(truth["t_s"] >= truth["t_s"][-1] - 0.5)
    moved = np.linalg.norm(tool_xyz(truth, tail)[-1] - tool_xyz(truth, tail)[0])
    assert moved < 1e-3, f"the tool moved {moved * 1e3:.1f} mm in the last 0.5 s"


#: the command cycle of both virtual controllers [s]: the LTC controller's cycle and the CiA 402
#: host's SYNC period (deploy/config/sim_cell*.toml)
COMMAND_PERIOD_S = 0.008
#: a ramp :func:`commanded_stop` can tell from the law's last commands: its walk starts at the
#: third-to-last step and needs one steady step before it. The drag's operating point (0.12
#: m/s at the release) commands the fastest joint at about 0.1 rad/s, a ramp of 6 cycles;
#: the bound was 0.05 s (0.1 rad/s), which judged the drag's speed, not the ramp: under
#: `taskset -c 0 make test` a release at 0.109 m/s, 0.095 rad/s, ramped at 2.000 rad/s² over
#: 0.056 s against the 0.048 s a ramp needs, and failed it
MIN_RAMP_CYCLES = 4
#: the CAN driver's ramp ([can] stop_deceleration_rad_s2, deploy/config/sim_cell*.toml)
STOP_DECELERATION_RAD_S2 = 2.0
#: a speed change smaller than this is none [rad/s]: the LTC frames carry positions in 1 µrad
#: steps, so a speed over one 8 ms cycle is known to ±1.25e-4 rad/s and the change of two to
#: ±2.5e-4 (the CiA 402 targets' increments are finer)
RESOLUTION_RAD_S = 3e-4
#: two steps of one ramp differ by less than this [rad/s²]: each is known to ± 0.031 (three
#: 1 µrad positions over (8 ms)², above), two to ± 0.0625; a law's or a coast's steps differ
#: by more (the half step into a ramp's first cycle alone by half the ramp's rate)
STEADY_TOL_RAD_S2 = 0.1

STOP_REPORT = (
    "{event} at {speed_m_s:.3f} m/s, the hand at {hand_n:.1f} N: a joint's command braked at "
    "up to {ref_decel_rad_s2:.3f} rad/s² over {ref_stop_s:.3f} s (a ramp needs {ref_need_s:.3f}; "
    "the law before it {law_decel_rad_s2:.2f}), "
    "stopped in {stop_s:.3f} s over {distance_m:.4f} m, peak "
    "deceleration {peak_decel_m_s2:.2f} m/s² (a joint's {joint_decel_rad_s2:.2f} rad/s²), went "
    "back {back_m:.4f} m, moved {tail_m:.5f} m in the last 0.5 s, {state}"
)


def commanded_stop(truth: dict[str, np.ndarray], released: np.ndarray, n: int) -> dict:
    """The ramp the virtual controller was commanded after the release (rows ``released``).

    Its commands are the truth log's q_ref at the first row of each command cycle, the
    position the host sent for it, on the host's time base (cycles × the period: the CiA 402
    drives' rows are 2 ms servo cycles a SYNC arrives among with the host's wall-clock
    jitter). After the release the law goes on commanding until the CAN driver learns of it
    (through the I/O module's poll, the Modbus driver and the bus: 2-7 cycles), and the law,
    its hand gone, slows the arm by itself, at whatever rate its dynamics give (J4 at up to
    5.1 rad/s² in one run on a loaded core); then the driver's ramp takes over. A ramp's
    commanded speed falls by the same step every cycle: the ramp is the final run of cycles
    whose steps agree within :data:`STEADY_TOL_RAD_S2` on the joint commanded fastest when it
    begins, the step into its first cycle excepted (half a step: the ramp starts from the
    last command's own position) and its last two (to standstill, each at most a step).
    ``ref_decel_rad_s2``: the fastest fall of any joint's commanded speed from one cycle to the
    next within the ramp, its last step included [rad/s²]; ``ref_stop_s``: how long the ramp
    took [s]; ``ref_need_s``: how long one at :data:`STOP_DECELERATION_RAD_S2` needs from the
    speed it starts at [s]; ``law_decel_rad_s2``: the fastest fall before it (reported) (NaN:
    the servo was off, after an e-stop)."""
    nan = {"ref_decel_rad_s2": np.nan, "ref_stop_s": np.nan, "ref_need_s": np.nan,
           "law_decel_rad_s2": np.nan}  # fmt: skip
    cycle = truth["cycle"][released].astype(np.int64)
    first = np.flatnonzero(np.r_[True, np.diff(cycle) != 0])
    t_set = np.r_[0, np.cumsum(np.diff(cycle[first]) % 0x10000)] * COMMAND_PERIOD_S
    q_set = np.stack([truth[f"q_ref{j + 1}"][released[first]] for j in range(n)], axis=1)
    speed = np.abs(np.diff(q_set, axis=0)) / np.diff(t_set)[:, None]  # per cycle [rad/s]
    if not np.isfinite(speed).all():
        return nan
    moving = np.flatnonzero(speed.max(axis=1) > RESOLUTION_RAD_S)
    end = int(moving[-1]) + 1 if moving.size else 0  # the first cycle at standstill
    mid = 0.5 * (t_set[:-1] + t_set[1:])  # each speed's instant
    fall = -np.diff(speed[: end + 1], axis=0) / np.diff(mid[: end + 1])[:, None]  # into k + 1
    # the ramp's steps, walking back from its third-to-last (fall index end - 3: the last two
    # may be short, its final position lies between two cycles' grid points)
    ref = max(end - 3, 0)
    g = int(np.argmax(speed[ref]))
    start = ref
    while start > 0 and abs(fall[start - 1, g] - fall[ref, g]) <= STEADY_TOL_RAD_S2:
        start -= 1
    # speed[start] is the ramp's first commanded speed; fall[start:] its steps to standstill
    return {
        "ref_decel_rad_s2": float(fall[start:].max()),
        "ref_stop_s": float(t_set[end] - t_set[start]),
        "ref_need_s": float(speed[start].max() / STOP_DECELERATION_RAD_S2),
        "law_decel_rad_s2": float(fall[: max(start - 1, 0)].max()) if start > 1 else 0.0,
    }


def stop_while_dragging(tmp_path, event: str = "release", cell_overrides=None) -> dict:
    """The hand drags the tool along +x at 0.15 m/s; 2.5 s into teaching, at the first cycle
    the tool has moved at 0.12 m/s or more over each of the last two 0.1 s, the operator lets
    go of the enabling device (and the tool: ``event`` "release") or hits the e-stop
    ("estop", the hand still pulling): the tool's speed then [m/s], its stopping time [s]
    and distance [m], the largest deceleration on the way [m/s²] (over 5 truth rows), how far
    it went back towards where the stop began [m], how far it moved in the last 0.5 s [m],
    and the lifecycle state and reason after 1.5 s; also the largest change of a joint's speed
    over the same windows [rad/s²] (true positions, 40 ms windows as the tool's), the fastest
    fall of a joint's commanded speed after the release [rad/s²] (the positions the virtual
    controller received) and the hand's force just before the release [N]."""
    operator = {"mode": "path", "path": [[0.0, 0, 0, 0], [0.5, 0, 0, 0], [4.5, 0.6, 0, 0]],
                "hand_stiffness_n_per_m": 1500.0, "hand_damping_n_s_per_m": 100.0,
                "max_force_n": 80.0,  # enough to break J2 and J3 away from their stiction
                "release_after_s" if event == "release" else "estop_after_s": 2.5,
                # ... then as soon as the tool moves: in a stall (the arm sticks and slips
                # under the 80 N hand, more often on a loaded machine) there is nothing to stop.
                # The trigger only has to be clear of the 0.08 m/s the tests assert the arm
                # moved at (25 % above it): at 0.12 the CiA 402 arm, whose model was
                # commissioned on the LTC cell and is read through the drives' own current
                # (J2's replay model error 6.7 N·m there, 1.2-1.9 on LTC), stayed under it in
                # 2 of about 14 runs over two days and was never released (2026-11-30: dragged
                # to the path's end, 48 N of hand on a still arm)
                "event_min_speed_m_s": 0.10}  # fmt: skip
    with commissioned_stack(
        tmp_path, sim_overrides={"operator": operator}, cell_overrides=cell_overrides
    ) as st:
        st.start()
        st.start_teaching()
        if event == "release":
            st.wait_status(lambda s: "released" in str(s.get("reason")), 20.0, "the release")
        else:
            st.wait_status(lambda s: s.get("state") == "fault", 20.0, "the e-stop's fault")
        time.sleep(1.5)
        status = st.request("status")
        truth = st.truth()
    t = truth["t_s"]
    if event == "release":
        k0 = np.flatnonzero(truth["enabling"] > 0.5)[-1] + 1  # the first row without it
    else:
        k0 = int(np.argmax(truth["ctrl_state"] == int(ControllerState.FAULT)))
        assert k0 > 0, "the controller never faulted"
    # rows of the truth log: the LTC controller's 8 ms cycles, or the CiA 402 drives' 2 ms
    # servo cycles; the windows below are times (as 8 ms rows: 40 ms, 400 ms, 80 ms)
    per = 0.008 / float(np.median(np.diff(t)))
    span, pre, ten = round(5 * per), round(50 * per), round(10 * per)
    rows = np.arange(k0 - pre, t.size)
    speed = tool_speed(truth, rows, span)  # at rows[:-span], over the next span rows
    xyz = tool_xyz(truth, rows)
    direction = xyz[pre] - xyz[pre - ten]
    direction /= np.linalg.norm(direction)
    after = speed[pre:]
    stop = int(np.argmax(after < 0.005)) if (after < 0.005).any() else after.size - 1
    mid_t = t[rows[:-span]] + 0.5 * (t[rows[span:]] - t[rows[:-span]])
    decel = -np.diff(speed) / np.diff(mid_t)
    travel = (xyz[pre:] - xyz[pre]) @ direction
    tail = np.flatnonzero(t >= t[-1] - 0.5)
    # each joint's speed over the same windows (the ramp is per joint, [rad/s])
    n = sum(1 for name in truth if re.fullmatch(r"q\d+", name))
    q = np.stack([truth[f"q{j + 1}"][rows] for j in range(n)], axis=1)
    dq = (q[span:] - q[:-span]) / (t[rows[span:]] - t[rows[:-span]])[:, None]
    joint_decel = np.abs(np.diff(dq, axis=0)) / np.diff(mid_t)[:, None]
    ramp = commanded_stop(truth, rows[pre:], n)
    hand = np.linalg.norm(np.stack([truth[f"f_{a}"] for a in "xyz"], axis=1), axis=1)
    return {
        "joint_decel_rad_s2": float(joint_decel[pre - span : pre + stop + 1].max()),
        **ramp,
        "hand_n": float(hand[k0 - 1]),
        "event": "enabling released" if event == "release" else "e-stop",
        "speed_m_s": float(speed[pre - ten : pre].mean()),
        "stop_s": float(t[rows[pre + stop]] - t[k0]),
        "distance_m": float(np.linalg.norm(xyz[pre + stop + span] - xyz[pre])),
        "back_m": float(travel.max() - travel[-1]),
        "peak_decel_m_s2": float(decel[pre - span : pre + stop + 1].max()),
        "tail_m": float(np.linalg.norm(tool_xyz(truth, tail)[-1] - tool_xyz(truth, tail)[0])),
        "state": status["state"],
        "reason": status.get("reason", ""),
    }


@pytest.mark.parametrize("profile", ["classic", "cia402"])
def test_releasing_the_enabling_device_ramps_the_arm_to_a_held_standstill(tmp_path, profile):
    """Stop category 2 (drivers/can/rt/src/stop_ramp.rs): released at about 0.16 m/s, the CAN
    driver ramps the last command to standstill at [can] stop_deceleration_rad_s2 (2 rad/s²
    per joint) along its path, then holds; the monitored standstill does not trip, the cell
    stays READY.

    The ramp is checked where it is made, on the positions the virtual controller received
    (:func:`commanded_stop`): over the final run of cycles whose commanded speed falls by one
    steady step (the ramp; before it the law's own last commands, reported), no joint's
    commanded speed falls faster than 2 % over the 2 rad/s² from one cycle to the next, and the
    ramp takes at least what one needs from the speed it starts at, less one cycle (its last
    step). A ramp's positions give its rate exactly at
    the command instants (2.000-2.016 in runs of both profiles), and 2 % covers the LTC
    frames' 1 µrad positions (a speed's change over one cycle from three of them: ± 2 µrad /
    (8 ms)² = ± 0.031 rad/s²) and the CiA 402 targets' finer increments. A hold at once
    (stop_deceleration_rad_s2 = 1000) steps the speed to zero in one cycle: 0.2 rad/s in
    8 ms, 25.6-27.6 rad/s²; a 3 rad/s² ramp reads 3.016. Before the ramp the law goes on
    commanding for 2-7 cycles until the CAN driver learns of the release (through the I/O
    module's poll): its hand gone, it slows the arm itself, at up to 11 rad/s² on a joint in
    twelve runs on one loaded core; bounding that as the ramp failed `taskset -c 0 make test`
    (2.094, then 2.98 in a repeat: J4 under the law, the ramp 2.016).

    The arm's own deceleration is reported, not bounded. On top of the ramp the arm springs
    back by the deflection the hand held against the inner loop, a response of the plant to
    the hand letting go that any stop shows: 2.17-2.65 rad/s² on a joint in seven runs with
    the hand at about 35 N, 3.30 rad/s² once with it at its 80 N limit (one loaded core), and
    7.96 (LTC) / 8.45 (CiA 402) rad/s² with a hold at once (stop_deceleration_rad_s2 = 1000).

    What comes back after the stop is that same deflection: the arm settles onto the ramped
    command once the hand lets go (0.4-1.5 mm in seven runs; 1.6-1.9 mm held at once, where all
    of it comes back). Bounded at 2.5 mm, it catches a stop that pulls the arm back past where
    the hand had it (a hold latched on a stale position). (The 60 N hand once left the arm at
    0.054 m/s at the release, stuck in its stiction: 80 N breaks it away.)"""
    r = stop_while_dragging(tmp_path, cell_overrides=PROFILES[profile][1])
    print(profile, STOP_REPORT.format(**r))
    assert r["speed_m_s"] > 0.08, "the arm was not moving at the release: nothing was tested"
    assert r["state"] == "ready", "the standstill monitor or something else faulted the cell"
    assert r["ref_need_s"] >= MIN_RAMP_CYCLES * COMMAND_PERIOD_S, "nothing ramped long enough"
    assert r["ref_decel_rad_s2"] < 1.02 * STOP_DECELERATION_RAD_S2, "braked harder than the ramp"
    assert r["ref_stop_s"] >= r["ref_need_s"] - COMMAND_PERIOD_S, "stopped sooner than a ramp"
    assert r["distance_m"] < 0.025 and r["back_m"] < 2.5e-3
    assert r["tail_m"] < 1e-3


def test_the_e_stop_cuts_the_power_and_the_brakes_stop_the_arm_after_they_engage(tmp_path):
    """Stop category 0 on the virtual plant ([brakes] in sim_bridge/gr630st_truth.toml): the
    e-stop opens while the hand drags the tool at about 0.15 m/s and keeps pulling; the
    controller cuts the power, the arm moves on freely for the brakes' engagement time (0.1
    s), then the brakes stop it and hold it against the hand; the cell faults on the
    e-stop. The stopping distance is the plant's, measured, not an ideal brake's zero."""
    r = stop_while_dragging(tmp_path, "estop")
    print(STOP_REPORT.format(**r))
    assert r["speed_m_s"] > 0.08, "the arm was not moving at the e-stop: nothing was tested"
    # the controller's FAULT (over CAN) or the e-stop input (over Modbus), whichever is first
    assert r["state"] == "fault" and ("e-stop" in r["reason"] or "FAULT" in r["reason"])
    assert r["stop_s"] > 0.08, "the arm stopped before the brakes engaged: ideal brakes?"
    assert 0.005 < r["distance_m"] < 0.1
    assert r["tail_m"] < 1e-3, "the brakes do not hold the arm"


def test_a_bus_off_faults_the_cell_which_stays_stopped_until_it_is_re_armed(tmp_path):
    """The host's CAN interface goes bus-off for 0.1 s while the hand drags the tool
    (``[operator] bus_off_after_s``: the virtual cell reports the kernel's error frames,
    BUSOFF then RESTARTED, and passes no frame in between). The CAN driver latches a bus
    fault (drivers/can/rt/src/bus_errors.rs), the cell faults and the arm stops; the bus works again
    at once, but the cell stays stopped until the operator resets it, and then it starts."""
    operator = {"mode": "path", "path": [[0.0, 0, 0, 0], [0.5, 0, 0, 0], [4.5, 0.4, 0, 0]],
                "bus_off_after_s": 2.0, "bus_off_s": 0.1}  # fmt: skip
    with commissioned_stack(tmp_path, sim_overrides={"operator": operator}) as stack:
        stack.start()
        stack.start_teaching()
        seen = stack.wait_status(
            lambda s: any("CAN bus" in p for p in s.get("problems") or ()), 20.0, "the bus fault"
        )
        time.sleep(2.5)  # the bus has been back for 2.4 s, quiet for longer than the window
        later = stack.request("status")
        truth = stack.truth()
        reply = stack.request("reset")
        stack.wait_status(lambda s: s.get("can_start") is True, 15.0, "the cell re-armed")
        started = stack.request("start")
    print(f"bus-off: {seen['state']} ({seen['reason']}); 2.5 s later {later['state']}, "
          f"problems {later['problems']}; reset: {reply}")  # fmt: skip
    assert seen["state"] == "fault" and "bus-off" in " ".join(seen["problems"])
    assert later["state"] == "fault", "the bus coming back re-armed the cell by itself"
    assert later["controller_state"] == "braked"
    assert reply.get("ok"), reply
    assert started.get("ok"), started
    tail = np.flatnonzero(truth["t_s"] >= truth["t_s"][-1] - 1.0)
    moved = np.linalg.norm(tool_xyz(truth, tail)[-1] - tool_xyz(truth, tail)[0])
    assert moved < 1e-3, f"the tool moved {moved * 1e3:.1f} mm while the cell was faulted"


def test_a_push_that_breaks_the_stiction_away_moves_the_tool_along_x(tmp_path):
    """The plant has stiction: 20 N along x moved the tool 2 mm (J2 and J3 hold it), 40 N
    broke J1 away first and moved it mostly along -y; 60 N moves it along x."""
    operator = {"mode": "force", "force_n": [60.0, 0.0, 0.0], "start_s": 0.5, "duration_s": 2.0}
    with commissioned_stack(tmp_path, sim_overrides={"operator": operator}) as stack:
        stack.start()
        stack.start_teaching()
        truth = stack.wait_teaching(3.0, 30.0)
        stack.request("stop")
    rows = teaching_rows(truth)
    t = truth["t_s"][rows] - truth["t_s"][rows[0]]
    before = rows[t <= 0.5][-1]
    after = rows[t <= 2.6][-1]
    d = tool_xyz(truth, [after])[0] - tool_xyz(truth, [before])[0]
    print(f"tool displacement after a 2 s, 60 N push along +x: {np.round(d * 1e3, 1)} mm")
    # A weightless arm's apparent mass is not isotropic: in this pose a push at the tool pitches
    # the shoulder forward, so the tool arcs forward and down. It must still go +x, within 60°.
    assert d[0] > 0.01, f"tool moved {d * 1e3} mm under a 60 N +x push"
    cos = d[0] / np.linalg.norm(d)
    assert cos > 0.5, f"motion {d * 1e3} mm is {np.degrees(np.arccos(cos)):.0f}° off +x"


#: the tool speed the kill test waits for before it kills the control process [m/s]: clearly
#: moving (2 s at it would carry the tool 20 mm, four times the travel the test allows after
#: the kill). The hand asks for 0.1 m/s; on one core the product misses enough cycles (issue 7)
#: that the dragged arm only reaches 10–40 mm/s.
MOVING_M_S = 0.01


def tool_speed_m_s(truth: dict[str, np.ndarray], k: int, back: int = 60) -> float:
    """Tool speed [m/s] over the ``back`` logged cycles up to row ``k``."""
    d = tool_xyz(truth, [k])[0] - tool_xyz(truth, [k - back])[0]
    return float(np.linalg.norm(d) / (truth["t_s"][k] - truth["t_s"][k - back]))


def follow_after_kill_bound_s(profile: str) -> float:
    """How long after the control process dies the arm may still follow commands [s].

    The command already computed is forwarded, the next cycle coasts on it (at most
    ``[can].deadline_s`` old), the one after holds; 20 ms more for this 2-core machine's
    scheduling. CiA 402 drives apply a set at the SYNC after it arrives, and the virtual drives'
    truth counts a setpoint moved within ``MOVED_WITHIN_SYNCS`` SYNCs as followed: that many
    more cycles of the host's SYNC period."""
    cell = PROFILES[profile][1]
    deadline_s = cell.get("can", {}).get("deadline_s", 0.010)
    bound_s = deadline_s + 0.020
    if (cia402 := cell.get("can", {}).get("cia402")) is not None:
        bound_s += (1 + MOVED_WITHIN_SYNCS) * cia402["cycle_period_s"]
    return bound_s


def wait_moving(stack: Stack, speed_m_s: float, timeout_s: float) -> None:
    """Wait (at most ``timeout_s``) until the tool moves faster than ``speed_m_s``: the hand
    drags the weightless arm up to speed, sooner on a fast machine than on a slow one. The
    truth log is read incrementally (TruthTail): a whole read each poll took CPU from the
    product on these 2 cores, and time between the speed seen and the test's next step."""
    tail = TruthTail(stack.truth_log, TOOL_COLUMNS, keep=61)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        rows = tail.update()
        if rows.shape[0] > 60 and tail_tool_speed(rows, 60) > speed_m_s:
            return
        time.sleep(0.05)


@pytest.mark.parametrize("profile", ["classic", "cia402"])
def test_killing_control_makes_the_driver_hold_and_the_arm_stop(tmp_path, profile):
    # The operator drags the tool along +x at 0.1 m/s and keeps pulling after the kill.
    operator = {"mode": "path", "path": [[0.0, 0, 0, 0], [0.5, 0, 0, 0], [4.5, 0.4, 0, 0]]}
    cell = PROFILES[profile][1]
    with commissioned_stack(
        tmp_path, sim_overrides={"operator": operator}, cell_overrides=cell
    ) as stack:
        stack.start()
        stack.start_teaching()
        stack.wait_teaching(2.0, 30.0)
        wait_moving(stack, MOVING_M_S, 3.0)
        pid = stack.child_pid("control")
        t_kill = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        time.sleep(2.0)
        status = stack.request("status")
        truth = stack.truth()
    assert status["state"] == "fault" and "control" in status["reason"]
    wall = truth["wall_s"]
    k = int(np.searchsorted(wall, t_kill))
    speed_at_kill = tool_speed_m_s(truth, k)
    assert speed_at_kill > MOVING_M_S, "the arm was not moving when control was killed"
    # Commands computed by control stop, and the driver's hold takes over within its deadline.
    following = np.flatnonzero(truth["teaching"][k:] > 0.5)
    last_follow_s = truth["wall_s"][k + following[-1]] - t_kill if following.size else 0.0
    bound_s = follow_after_kill_bound_s(profile)
    assert last_follow_s < bound_s, (
        f"kept following for {last_follow_s * 1e3:.1f} ms (at most {bound_s * 1e3:.0f} ms)"
    )
    after = tool_xyz(truth, np.arange(k, wall.size))
    travel_m = np.linalg.norm(after - after[0], axis=1).max()
    print(
        f"speed at kill {speed_at_kill * 1e3:.0f} mm/s, commands followed for "
        f"{last_follow_s * 1e3:.1f} ms after the kill, travel after it {travel_m * 1e3:.2f} mm"
    )
    assert travel_m < 5e-3, f"tool travelled {travel_m * 1e3:.2f} mm after the kill"


def test_operator_commands_from_the_command_line(tmp_path):
    with commissioned_stack(tmp_path) as stack:
        stack.start()
        stack.wait_status(lambda s: s.get("can_start") is True, 40.0, "cell ready")
        cli = [sys.executable, "-m", "gateway.cli"]
        bus = ["--bus", stack.bus.endpoint]
        out = subprocess.run([*cli, "status", *bus], capture_output=True, text=True, timeout=20)
        assert out.returncode == 0 and "state: stopped" in out.stdout
        # start, then stop, once: a watchdog fault between the two (a stalled joint-state
        # stream) is a fault of the product or of its placement, not something to retry past.
        # The virtual controller runs at SCHED_FIFO above the product (sim_bridge/harness.py)
        # precisely so that a loaded test machine does not starve it.
        out = subprocess.run([*cli, "start", *bus], capture_output=True, text=True, timeout=20)
        assert out.returncode == 0, out.stdout + out.stderr
        stack.wait_status(lambda s: s.get("state") in ("ready", "teaching"), 5.0, "started")
        out = subprocess.run([*cli, "stop", *bus], capture_output=True, text=True, timeout=20)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "state: stopped" in out.stdout, out.stdout
        out = subprocess.run([*cli, "fly", *bus], capture_output=True, text=True, timeout=20)
        assert out.returncode != 0


def test_teaching_is_refused_while_the_arm_carries_a_load_the_model_lacks(tmp_path):
    """An 8 kg spray gun the declared model does not know: made weightless, the arm would fall
    (measured without this check: the tool dropped 1.6 m in 2 s). The control process's
    static-load check keeps the cell in READY with a reason naming the joint."""
    gun = [{"kind": "payload", "mass_kg": 8.0, "com_m": [0.0, 0.0, 0.05]}]
    with commissioned_stack(tmp_path, sim_overrides={"effects": gun}) as stack:
        stack.start()
        stack.wait_status(lambda s: s.get("can_start") is True, 40.0, "cell ready to start")
        assert stack.request("start")["ok"]
        stack.wait_status(lambda s: "teaching blocked" in s["reason"], 10.0, "teaching blocked")
        # The cell starts once the control process is up (its first heartbeat), but its first
        # static-load check waits for servo-on and an arm at rest: the reason reads "no
        # static-load check ... yet" until then. The refusal this test is about is the check's
        # own: wait for it as long as the gateway waits for a child to start ([gateway]
        # boot_grace_s), leaving READY on the way (teaching) included.
        boot_grace_s = GatewayConfig().boot_grace_s
        stack.wait_status(
            lambda s: s["state"] != "ready" or "static-load check from the" not in s["reason"],
            boot_grace_s, "the control process's static-load check",
        )  # fmt: skip
        time.sleep(2.0)  # enabling held all along
        status = stack.request("status")
        stack.request("stop")
        truth = stack.truth()
    print(f"status: {status['state']}: {status['reason']}")
    assert status["state"] == "ready" and "joint 3" in status["reason"]
    assert status["enabling"] is True
    assert not np.any(truth["teaching"] > 0.5), "the controller followed commands"
    held = truth["ctrl_state"] > 0.5
    xyz = tool_xyz(truth, held)
    assert np.linalg.norm(xyz - xyz[-1], axis=1)[-100:].max() < 1e-3  # held still at the end


@pytest.mark.parametrize("force_n", [80.0, 200.0])
def test_a_hard_push_never_moves_the_tool_faster_than_hand_guiding_allows(tmp_path, force_n):
    """Zero-moment mode, 80 N (it breaks J1's stiction away: 40 N did not) or 200 N (issue
    10's figure) for 3 s at the tool: a weightless arm would reach metres per second; the
    velocity command is scaled to max_tool_speed_m_s (0.22 m/s), less 3 × what the predicted
    speed exceeds it by (control/zero_moment_law.py SPEED_FEEDBACK_GAIN), and the vendor loop brakes
    the arm. 80 N: 222 mm/s at most (238 without the feedback), teaching goes on, and the
    tool never passes 250 mm/s.

    200 N outruns that (248-255 mm/s): the CAN driver's own monitor trips, asks for the
    brakes, and the cell faults. The hand pushes on, and the wrist yields: with only J5
    turning the tool moved at 0.226 m/s per rad/s, so 200 N makes up to 45 N·m about J5,
    twice its drive's peak (22.3 N·m, sim_bridge/gr630st_truth.toml [drives]) and its
    brake's 20 N·m; J5 slipped to 2.6 rad/s and the tool to 578 mm/s. No command holds a
    joint the hand overpowers: issue 10's 250 mm/s under 200 N is out of this arm's reach at
    the wrist. The test holds what the drives can: J1-J3 stand once the brakes are asked for.
    """
    operator = {"mode": "force", "force_n": [0.0, force_n, 0.0], "start_s": 0.5,
                "duration_s": 3.0}  # fmt: skip
    with commissioned_stack(tmp_path, sim_overrides={"operator": operator}) as stack:
        stack.start()
        stack.start_teaching()
        time.sleep(4.0)
        status = stack.request("status")
        truth = stack.truth()
        stack.request("stop")
    rows = teaching_rows(truth)
    speed = tool_speed(truth, rows)
    after = tool_speed(truth, np.arange(rows[0], truth["t_s"].size))
    print(f"zero moment, {force_n:.0f} N push: tool speed max {speed.max() * 1e3:.0f} mm/s "
          f"while teaching, {after.max() * 1e3:.0f} mm/s to the end; {status['state']} "
          f"({status['reason']})")  # fmt: skip
    assert speed.max() > 0.15, "the push never got the tool near the limit"
    if after.max() <= 0.25:
        assert status["state"] == "teaching", status["reason"]
        return
    # the CAN driver's monitor must have stopped it, and the brakes hold the big joints
    reason = status["reason"]
    assert status["state"] == "fault" and "speed monitor" in reason, reason
    braked = np.flatnonzero(truth["ctrl_state"][rows[-1] :] == int(ControllerState.BRAKED))
    assert braked.size, "the controller never braked"
    k = rows[-1] + braked[0]
    dq = np.abs(np.stack([truth[f"dq{j}"][k:] for j in (1, 2, 3)], axis=1))
    print(f"braked {truth['t_s'][k] - truth['t_s'][rows[-1]]:.3f} s after the last followed "
          f"cycle; J1-J3 at most {dq.max(axis=0).round(4).tolist()} rad/s since")  # fmt: skip
    assert dq.max() < 1e-3
