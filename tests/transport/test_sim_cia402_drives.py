"""The virtual cell's CiA 402 drives on a real in-process CAN segment (the cell's seqpacket
hub), driven by a minimal host written here with canopen's RemoteNode and the drives' EDS,
not with the product's code: NMT start-up, PDO mapping by SDO, enabling through transitions
2, 3, 4, cyclic SYNC + RPDOs with a TPDO answer at every SYNC, the host's heartbeat lost
(0x6007 = 3: quick stop, then switch on disabled with the brakes), a following error and its
fault reset; then ``leadthrough sim`` with the CiA 402 truth file, as a process."""

from __future__ import annotations

import contextlib
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import pytest
from cia402_rig import cia402_cell

from sim_bridge.cia402_dictionary import EDS_PATH
from sim_bridge.harness import REPO, free_port, unique_can_address
from sim_bridge.sim import VirtualCell

CIA402_TRUTH = REPO / "sim_bridge" / "gr630st_truth_cia402.toml"
NODES = range(1, 7)
HOST_ID = 0x7F
SYNC_PERIOD_S = 0.004  #: the host's loop and 0x1006
HEARTBEAT_PERIOD_S = 0.02  #: the host's heartbeat
CONSUMER_TIME_MS = 100  #: 0x1016 written to the drives
SDO_TIMEOUT_S = 2.0  #: a loaded machine answers SDO late
# CiA 402-2: (mask, value)
READY_TO_SWITCH_ON, SWITCHED_ON = (0x6F, 0x21), (0x6F, 0x23)
OPERATION_ENABLED, QUICK_STOP_ACTIVE = (0x6F, 0x27), (0x6F, 0x07)
SWITCH_ON_DISABLED, FAULT = (0x4F, 0x40), (0x4F, 0x08)


def shows(word: int, pattern: tuple[int, int]) -> bool:
    return word & pattern[0] == pattern[1]


class Host:
    """The test's CANopen master: SDO configuration, NMT, then SYNC + RPDOs every cycle."""

    def __init__(self, address: str) -> None:
        bus = can.Bus(interface="seqpacket", channel=address, connect_timeout_s=5.0)
        self.net = canopen.Network(bus)
        self.net.connect()
        self.nodes = {i: self.net.add_node(i, str(EDS_PATH)) for i in NODES}
        for node in self.nodes.values():
            node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
        #: per node: (arrival [monotonic s], statusword, position actual) of each TPDO1
        self.tpdo1: dict[int, list[tuple[float, int, int]]] = {i: [] for i in NODES}
        self.tpdo2: dict[int, list[tuple[int, int, int]]] = {i: [] for i in NODES}
        self.boot_ups: list[int] = []
        self.syncs = 0
        self.target = {i: 0 for i in NODES}  #: target position [increments]
        self.velocity = {i: 0 for i in NODES}  #: velocity offset [increments/s]
        self.controlword = {i: 0 for i in NODES}
        self.heartbeat = True
        self.last_heartbeat_s = -math.inf
        #: after each SYNC, wait for every drive's TPDO1 (a lock-step host: the cell runs one
        #: servo cycle per SYNC, so the next SYNC must not come before this one's answer)
        self.lockstep = False
        for i in NODES:
            self.net.subscribe(0x700 + i, self._on_heartbeat)

    def _on_heartbeat(self, cob_id: int, data: bytearray, _stamp: float) -> None:
        if bytes(data) == b"\x00":
            self.boot_ups.append(cob_id - 0x700)

    def close(self) -> None:
        self.net.disconnect()

    def boot(self) -> None:
        """NMT reset communication: every drive answers with its boot-up."""
        self.net.nmt.send_command(0x82)
        wait_for(lambda: sorted(self.boot_ups) == list(NODES), "six boot-ups")

    def configure(self, node: canopen.RemoteNode) -> None:
        """The wire contract, by SDO in pre-operational."""
        node.tpdo.read()
        node.rpdo.read()
        layouts = [
            (node.tpdo[1], [0x6041, 0x6064]),
            (node.tpdo[2], [0x606C, 0x6078, 0x6077]),
            (node.rpdo[1], [0x6040, 0x607A]),
            (node.rpdo[2], [0x60B1]),
        ]
        for pdo, objects in layouts:
            pdo.clear()
            for index in objects:
                pdo.add_variable(index)
            pdo.trans_type = 1
            pdo.enabled = True
            pdo.save()
        i = node.id
        node.tpdo[1].add_callback(
            lambda m: self.tpdo1[i].append((time.monotonic(), m[0].raw, m[1].raw))
        )
        node.tpdo[2].add_callback(lambda m: self.tpdo2[i].append((m[0].raw, m[1].raw, m[2].raw)))
        node.sdo[0x6007].raw = 3  # quick stop on a lost connection
        node.sdo[0x1016][1].raw = (HOST_ID << 16) | CONSUMER_TIME_MS
        node.sdo[0x1006].raw = round(SYNC_PERIOD_S * 1e6)
        node.sdo[0x6060].raw = 8  # cyclic synchronous position
        node.sdo[0x6085].raw = round(3.0 * increments_per_rad(node))  # 3 rad/s²
        assert node.sdo[0x6061].raw == 8

    def cycle(self) -> None:
        """One host cycle: heartbeat when due, the RPDOs, then SYNC."""
        now = time.monotonic()
        if self.heartbeat and now - self.last_heartbeat_s >= HEARTBEAT_PERIOD_S:
            self.net.send_message(0x700 + HOST_ID, b"\x05")
            self.last_heartbeat_s = now
        for i, node in self.nodes.items():
            node.rpdo[1][0].raw = self.controlword[i]
            node.rpdo[1][1].raw = self.target[i]
            node.rpdo[2][0].raw = self.velocity[i]
            node.rpdo[1].transmit()
            node.rpdo[2].transmit()
        answered = [len(self.tpdo1[i]) + 1 for i in NODES]
        self.net.sync.transmit()
        self.syncs += 1
        if self.lockstep:
            wait_for(lambda: [len(self.tpdo1[i]) for i in NODES] >= answered,
                     "every drive's TPDO1", timeout_s=1.0)  # fmt: skip

    def run(self, cycles: int, each: Callable[[int], None] | None = None) -> None:
        """``cycles`` host cycles at SYNC_PERIOD_S (absolute deadlines)."""
        start = time.monotonic()
        for k in range(cycles):
            if each is not None:
                each(k)
            self.cycle()
            left = start + (k + 1) * SYNC_PERIOD_S - time.monotonic()
            if left > 0:
                time.sleep(left)

    def statusword(self, i: int) -> int:
        return self.tpdo1[i][-1][1]

    def position(self, i: int) -> int:
        return self.tpdo1[i][-1][2]

    def run_until(self, done: Callable[[], bool], what: str, cycles: int = 250) -> None:
        for _ in range(cycles):
            self.run(1)
            if done():
                return
        states = {i: hex(self.statusword(i)) for i in NODES}
        raise AssertionError(f"no {what} after {cycles} cycles; statuswords {states}")


def increments_per_rad(node: canopen.RemoteNode) -> float:
    """From the drive's own parameters, as a host reads them."""
    encoder = node.sdo[0x608F][1].raw / node.sdo[0x608F][2].raw
    gear = node.sdo[0x6091][1].raw / node.sdo[0x6091][2].raw
    return encoder * gear / (2.0 * math.pi)


def wait_for(cond: Callable[[], bool], what: str, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"waited {timeout_s} s for {what}")
        time.sleep(0.01)


@pytest.fixture
def cell():
    with cia402_cell(SYNC_PERIOD_S) as vc:
        yield vc


@pytest.fixture
def host(cell: VirtualCell):
    h = Host(cell.cfg.endpoints.can_channel)
    try:
        yield h
    finally:
        h.close()


#: heartbeats both ways on wall time inside this process (the drives' from the cell's thread,
#: the host's from this one): it keeps them only with the CPU when they fall due
@pytest.mark.deadline
def test_a_canopen_host_starts_maps_enables_drives_and_loses_them_by_heartbeat(cell, host):
    host.boot()
    for node in host.nodes.values():
        host.configure(node)
    # each drive's parameters as the host reads them: this cell's J1..J6
    assert [host.nodes[i].sdo[0x6091][1].raw for i in NODES] == [147, 153, 153, 76, 80, 50]
    # read now: SDO round trips in Operation enabled would pause the SYNC the drives watch
    inc = {i: increments_per_rad(host.nodes[i]) for i in NODES}
    host.net.nmt.send_command(0x01)  # start: operational
    host.lockstep = True
    host.run(3)
    wait_for(lambda: all(len(host.tpdo1[i]) == len(host.tpdo2[i]) == 3 for i in NODES),
             "TPDO1 and TPDO2 of every drive at each of 3 SYNCs", timeout_s=1.0)  # fmt: skip
    start = {i: host.position(i) for i in NODES}
    host.target.update(start)
    # enable operation through 2, 3, 4
    for controlword, pattern in ((0x06, READY_TO_SWITCH_ON), (0x07, SWITCHED_ON),
                                 (0x0F, OPERATION_ENABLED)):  # fmt: skip
        host.controlword.update(dict.fromkeys(NODES, controlword))
        host.run_until(lambda p=pattern: all(shows(host.statusword(i), p) for i in NODES),
                       f"statusword pattern {pattern}", cycles=10)  # fmt: skip
    # enabled on one repeated target: holding, not following the host (no "teaching")
    assert cell.ctrl.servo_on and not cell.ctrl.following

    # --- follow: J1 swings 0.1 rad at 1 Hz, the others hold -------------------------------
    inc_j1 = inc[1]
    amplitude_rad, omega = 0.1, 2.0 * math.pi
    commanded: list[float] = []

    def swing(k: int) -> None:
        t = k * SYNC_PERIOD_S  # the plant's time from the first of these SYNCs
        q = amplitude_rad * math.sin(omega * t)
        commanded.append(q)
        host.target[1] = start[1] + round(q * inc_j1)
        host.velocity[1] = round(amplitude_rad * omega * math.cos(omega * t) * inc_j1)

    syncs_before = host.syncs
    counts_before = {i: len(host.tpdo1[i]) for i in NODES}
    host.run(300, swing)
    assert cell.ctrl.following  # a moving setpoint: the arm follows the host
    syncs = host.syncs - syncs_before
    # a TPDO1 and a TPDO2 at every SYNC, from every drive (the last SYNC's on their way)
    wait_for(lambda: all(len(host.tpdo1[i]) - counts_before[i] == syncs for i in NODES),
             "a TPDO1 per SYNC", timeout_s=0.02)  # fmt: skip
    assert all(len(host.tpdo2[i]) == len(host.tpdo1[i]) for i in NODES)
    j1 = [(p - start[1]) / inc_j1 for _, _, p in host.tpdo1[1][counts_before[1] :]]
    assert max(j1) > 0.08 and min(j1) < -0.08, "J1 swings as commanded"

    # the target sent before SYNC k - 1 takes effect at it and is extrapolated with its
    # velocity offset: the position answered at SYNC k is the command for SYNC k's time,
    # within a few mrad once the swing's start (at full speed) is past; a delay of a cycle
    # more or less would be off by 2.5 mrad per SYNC
    def off_rad(shift: int) -> float:
        pairs = zip(j1[shift:], commanded[: len(commanded) - shift], strict=True)
        return max(abs(a - c) for a, c in list(pairs)[50:])

    assert off_rad(0) < 0.003, f"J1 off its command by {off_rad(0):.4f} rad"
    assert off_rad(0) < off_rad(2)
    for i in (2, 3, 4, 5, 6):
        drift = max(abs(p - start[i]) for _, _, p in host.tpdo1[i])
        assert drift / inc[i] < 0.005, f"J{i} holds"
    assert all(shows(host.statusword(i), OPERATION_ENABLED) for i in NODES)
    assert cell.ctrl.stats.command_sets >= 300 and not cell.ctrl.stats.faults

    # --- the host's heartbeat stops: quick stop, then switch on disabled with the brakes ----
    host.velocity[1] = round(0.3 * inc_j1)  # J1 moving at 0.3 rad/s when it happens
    moving = time.monotonic()
    step = round(0.3 * inc_j1 * SYNC_PERIOD_S)
    host.run(25, lambda _k: host.target.update({1: host.target[1] + step}))
    assert time.monotonic() - moving > 0.08
    host.heartbeat = False
    last_beat = host.last_heartbeat_s
    seen = len(host.tpdo1[1])
    host.run_until(lambda: not shows(host.statusword(1), OPERATION_ENABLED), "quick stop")
    stamp, word, _ = next(r for r in host.tpdo1[1][seen:] if not shows(r[1], OPERATION_ENABLED))
    assert shows(word, QUICK_STOP_ACTIVE), hex(word)
    after_s = stamp - last_beat
    # the consumer time, plus one servo cycle, one SYNC period and the machine's jitter
    assert CONSUMER_TIME_MS / 1000 < after_s < CONSUMER_TIME_MS / 1000 + 0.04, after_s
    host.run_until(lambda: all(shows(host.statusword(i), SWITCH_ON_DISABLED) for i in NODES),
                   "switch on disabled")  # fmt: skip
    stops = [r for r in host.tpdo1[1][seen:] if shows(r[1], QUICK_STOP_ACTIVE)]
    assert len(stops) >= 10, "J1 ramped down (0.3 rad/s at 3 rad/s²: 0.1 s) before stopping"
    host.run_until(lambda: cell.plant.brakes, "the brakes holding every joint")
    assert not cell.ctrl.servo_on
    host.run(20)
    resting = [p for _, _, p in host.tpdo1[1][-20:]]
    assert max(resting) - min(resting) <= 1, "J1 stands on its brake"
    assert all(host.nodes[i].sdo[0x603F].raw == 0 for i in NODES), "a quick stop, no fault"

    # --- a following error faults J1; a fault reset (rising bit 7) clears it ---------------
    host.heartbeat = True
    host.velocity[1] = 0
    host.target.update({i: host.position(i) for i in NODES})
    for controlword, pattern in ((0x06, READY_TO_SWITCH_ON), (0x0F, OPERATION_ENABLED)):
        host.controlword.update(dict.fromkeys(NODES, controlword))
        host.run_until(lambda p=pattern: all(shows(host.statusword(i), p) for i in NODES),
                       f"statusword pattern {pattern}", cycles=20)  # fmt: skip
    host.target[1] += round(0.2 * inc_j1)  # 0.2 rad away: beyond the 0.05 rad window
    host.run_until(lambda: shows(host.statusword(1), FAULT), "fault")
    assert all(shows(host.statusword(i), OPERATION_ENABLED) for i in (2, 3, 4, 5, 6))
    host.controlword.update(dict.fromkeys((2, 3, 4, 5, 6), 0x00))  # disable voltage (9)
    host.run_until(lambda: all(shows(host.statusword(i), SWITCH_ON_DISABLED) for i in NODES[1:]),
                   "the others switched off", cycles=10)  # fmt: skip
    assert host.nodes[1].sdo[0x603F].raw == 0x8611
    assert host.nodes[1].sdo[0x1001].raw & 0x01
    host.target[1] = host.position(1)
    host.controlword[1] = 0x80  # fault reset: 0x0F → 0x80 is bit 7's rising edge
    host.run_until(lambda: shows(host.statusword(1), SWITCH_ON_DISABLED), "fault reset")
    assert host.nodes[1].sdo[0x603F].raw == 0 and host.nodes[1].sdo[0x1001].raw == 0

    # --- the e-stop chain opens: every drive faults, its voltage off ------------------------
    cell.estop_open = True  # what the operator's e-stop does to the cell
    host.run_until(lambda: all(shows(host.statusword(i), FAULT) for i in NODES), "e-stop")
    assert not any(host.statusword(i) & (1 << 4) for i in NODES), "voltage enabled"
    summary = cell.summary()
    assert summary["can_profile"] == "cia402" and summary["syncs"] == host.syncs
    assert any("0x8611" in f for f in summary["faults"])
    assert sum("0x9000" in f for f in summary["faults"]) == 6


def test_leadthrough_sim_with_the_cia402_truth_answers_sync_on_its_can_endpoint(tmp_path):
    address = unique_can_address()
    truth = tmp_path / "truth.toml"
    truth.write_text(
        f'extends = "{CIA402_TRUTH}"\n'
        f'[endpoints]\ncan_channel = "{address}"\nmodbus_port = {free_port()}\n'
    )
    summary_path = tmp_path / "summary.json"
    sim = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "sim", "--truth", str(truth),
         "--summary", str(summary_path), "--duration", "30"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    host: Host | None = None
    try:
        host = Host(address)  # waits up to 5 s for the socket
        host.boot()
        words: dict[int, list[int]] = {i: [] for i in NODES}
        for i, node in host.nodes.items():
            node.sdo[0x1800][1].raw = 0x180 + i  # TPDO1 valid, as mapped at boot (0x6041)
            node.tpdo[1].read()
            node.tpdo[1].add_callback(lambda m, i=i: words[i].append(m[0].raw))
        host.net.nmt.send_command(0x01)
        for _ in range(5):
            host.net.sync.transmit()
            time.sleep(0.02)
        wait_for(lambda: all(len(words[i]) == 5 for i in NODES), "a TPDO1 per SYNC", 2.0)
        assert all(shows(w, SWITCH_ON_DISABLED) for i in NODES for w in words[i])
    finally:
        if host is not None:
            host.close()
        with contextlib.suppress(ProcessLookupError):
            sim.send_signal(signal.SIGTERM)
        out, _ = sim.communicate(timeout=20)
    assert sim.returncode == 0, out[-2000:]
    summary = json.loads(Path(summary_path).read_text())
    assert summary["can_profile"] == "cia402" and summary["syncs"] == 5
    assert [d["nmt"] for d in summary["drives"]] == ["OPERATIONAL"] * 6
