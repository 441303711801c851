"""The virtual cell's CiA 402 drives on no bus: their EDS, NMT, PDOs as the host maps them,
heartbeats and watchdogs (CiA 301), their parameters from the plant's truth, and that they
are written apart from the product's CiA 402 code."""

from __future__ import annotations

import ast
import struct
from pathlib import Path

import can
import canopen
import pytest
from canopen.objectdictionary import datatypes as dt
from canopen.sdo import SdoAbortedError

from sim_bridge.cia402_cell import axis_parameters
from sim_bridge.cia402_dictionary import EDS_PATH
from sim_bridge.cia402_drives import Cia402Drive
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.cia402_profile import DriveState, NmtState
from sim_bridge.config import load_sim_config

REPO = Path(__file__).resolve().parents[2]
CIA402_TRUTH = REPO / "sim_bridge" / "gr630st_truth_cia402.toml"
AXIS = AxisParameters.for_joint(153.0, 61.0, 66.18, 20)
NODE = 5

#: the contract's objects: index → (data type, access the host needs)
CONTRACT = {
    0x1000: (dt.UNSIGNED32, "ro"),
    0x1001: (dt.UNSIGNED8, "ro"),
    0x1005: (dt.UNSIGNED32, "rw"),
    0x1006: (dt.UNSIGNED32, "rw"),
    0x1017: (dt.UNSIGNED16, "rw"),
    0x603F: (dt.UNSIGNED16, "ro"),
    0x6040: (dt.UNSIGNED16, "rw"),
    0x6041: (dt.UNSIGNED16, "ro"),
    0x605A: (dt.INTEGER16, "rw"),
    0x6060: (dt.INTEGER8, "rw"),
    0x6061: (dt.INTEGER8, "ro"),
    0x6064: (dt.INTEGER32, "ro"),
    0x606C: (dt.INTEGER32, "ro"),
    0x6075: (dt.UNSIGNED32, "ro"),
    0x6076: (dt.UNSIGNED32, "ro"),
    0x6077: (dt.INTEGER16, "ro"),
    0x6078: (dt.INTEGER16, "ro"),
    0x607A: (dt.INTEGER32, "rw"),
    0x6085: (dt.UNSIGNED32, "rw"),
    0x60B1: (dt.INTEGER32, "rw"),
    0x60FF: (dt.INTEGER32, "rw"),
    0x6007: (dt.INTEGER16, "rw"),
    0x6502: (dt.UNSIGNED32, "ro"),
}


def test_the_eds_loads_and_has_the_contracts_objects():
    od = canopen.import_od(str(EDS_PATH), NODE)
    for index, (data_type, access) in CONTRACT.items():
        obj = od[index]
        assert obj.data_type == data_type, hex(index)
        assert obj.writable if access == "rw" else not obj.writable, hex(index)
    assert od[0x1000].default == 0x00020192
    assert od[0x1005].default == 0x80
    assert od[0x1016][1].writable and od[0x1018][1].data_type == dt.UNSIGNED32
    for index in (0x608F, 0x6091):
        assert od[index][1].data_type == od[index][2].data_type == dt.UNSIGNED32
    for comm, base in ((0x1400, 0x200), (0x1401, 0x300), (0x1800, 0x180), (0x1801, 0x280)):
        assert od[comm][1].writable and od[comm][2].writable
        assert od[comm][1].default == PDO_NOT_VALID | (base + NODE), "PDOs off at boot"
        assert all(od[comm + 0x200][k].writable for k in range(9))


PDO_NOT_VALID = 1 << 31


class Bench:
    def __init__(self) -> None:
        self.sent: list[can.Message] = []
        self.drive = Cia402Drive(NODE, AXIS, DriveLimits(sync_timeout_cycles=5), self.sent.append)
        self.drive.boot()
        self.t_s = 0.0

    def frames(self, cob_id: int) -> list[bytes]:
        return [bytes(m.data) for m in self.sent if m.arbitration_id == cob_id]

    def nmt(self, command: int, node: int = 0) -> None:
        self.drive.on_nmt(bytes([command, node]))

    def frame(self, cob_id: int, data: bytes, wall_s: float = 0.0) -> None:
        self.drive.on_frame(cob_id, data, wall_s=wall_s, now_s=self.t_s, stamp_s=wall_s)

    def step(self, wall_s: float = 0.0, q_rad: float = 0.0) -> None:
        self.drive.sample(q_rad, 0.0, 0.0)
        self.drive.step(self.t_s, q_rad, wall_s)
        self.t_s += 0.002

    def map_pdo(self, comm: int, entries: list[int], transmission_type: int = 1) -> None:
        """As a host does it (CiA 301's procedure): not valid, count 0, entries, count, valid."""
        d = self.drive
        cob = d.read(comm, 1) & 0x7FF
        d.write(comm, 1, PDO_NOT_VALID | cob)
        d.write(comm, 2, transmission_type)
        d.write(comm + 0x200, 0, 0)
        for k, entry in enumerate(entries, 1):
            d.write(comm + 0x200, k, entry)
        d.write(comm + 0x200, 0, len(entries))
        d.write(comm, 1, cob)

    def enable(self) -> None:
        self.drive.write(0x6060, 0, 8)
        for cw in (0x00, 0x06, 0x07, 0x0F):
            self.drive.write(0x6040, 0, cw)
            self.step()
        assert self.drive.state == DriveState.OPERATION_ENABLED


def test_boot_up_then_nmt_start_stop_pre_operational_and_the_resets():
    b = Bench()
    assert b.frames(0x705) == [b"\x00"] and b.drive.nmt_state == NmtState.PRE_OPERATIONAL
    b.nmt(0x01, node=6)  # another node's
    assert b.drive.nmt_state == NmtState.PRE_OPERATIONAL
    b.nmt(0x01, node=NODE)
    assert b.drive.nmt_state == NmtState.OPERATIONAL
    b.nmt(0x02)
    assert b.drive.nmt_state == NmtState.STOPPED
    b.sent.clear()
    b.frame(0x605, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))  # SDO upload 0x1000
    assert b.sent == [], "no SDO in stopped"
    b.nmt(0x80)
    assert b.drive.nmt_state == NmtState.PRE_OPERATIONAL
    b.drive.write(0x1017, 0, 100)
    b.drive.write(0x6060, 0, 9)
    b.nmt(0x82)  # reset communication: 0x1017 back to its default, the mode kept
    assert b.frames(0x705) == [b"\x00"] and b.drive.read(0x1017) == 0
    assert b.drive.read(0x6061) == 9
    b.nmt(0x81)  # reset node: the application too, the stored parameters kept
    assert b.frames(0x705) == [b"\x00", b"\x00"] and b.drive.read(0x6061) == 0
    assert b.drive.state == DriveState.NOT_READY_TO_SWITCH_ON
    assert b.drive.read(0x6091, 1) == 153 and b.drive.read(0x6075) == 61000


def test_pdos_follow_the_mapping_the_host_writes_not_a_fixed_layout():
    b = Bench()
    d = b.drive
    # TPDO1 in an unusual order: position actual, then statusword; TPDO2 every 2nd SYNC
    b.map_pdo(0x1800, [0x60640020, 0x60410010])
    b.map_pdo(0x1801, [0x60780010, 0x606C0020], transmission_type=2)
    b.map_pdo(0x1400, [0x60400010, 0x607A0020])
    b.nmt(0x01)
    b.step()
    d.sample(0.1, -0.2, 6.1)
    b.sent.clear()
    for _ in range(4):
        b.frame(0x80, b"")
    inc = AXIS.increments_per_rad
    tpdo1 = b.frames(0x185)
    assert len(tpdo1) == 4 and len(b.frames(0x285)) == 2
    position, word = struct.unpack("<iH", tpdo1[0])
    assert position == round(0.1 * inc) and word == d.read(0x6041)
    current, velocity = struct.unpack("<hi", b.frames(0x285)[0])
    assert current == 100 and velocity == round(-0.2 * inc)  # 6.1 A of 61 A: 100 ‰
    # an RPDO takes effect at the next SYNC, not before
    b.frame(0x205, struct.pack("<Hi", 0x06, 12345))
    assert d.read(0x6040) == 0 and d.read(0x607A) == 0
    b.frame(0x80, b"")
    assert d.read(0x6040) == 0x06 and d.read(0x607A) == 12345
    # shorter than its mapping: not processed (CiA 301), EMCY 0x8210
    b.frame(0x205, struct.pack("<H", 0x0F))
    b.frame(0x80, b"")
    assert d.read(0x6040) == 0x06 and d.bad_frames == 1
    assert b.frames(0x085)[-1][:2] == struct.pack("<H", 0x8210)


def test_the_current_is_the_last_servo_cycles_or_with_0x2010_the_mean_since_the_last_sync():
    b = Bench()
    d = b.drive
    b.map_pdo(0x1801, [0x60780010])
    b.nmt(0x01)

    def tpdo_current_after(currents_a: list[float]) -> int:
        for i in currents_a:
            d.sample(0.0, 0.0, i)
        b.sent.clear()
        b.frame(0x80, b"")
        return struct.unpack("<h", b.frames(0x285)[0])[0]

    # 61 A rated: 0.061 A per count
    assert d.read(0x2010) == 0
    assert tpdo_current_after([6.1, 0.0, 12.2, 24.4]) == 400, "the last servo cycle's"
    d.write(0x2010, 0, 1)
    assert tpdo_current_after([6.1, 0.0, 12.2, 24.4]) == 175, "the mean of the four"
    assert tpdo_current_after([-6.1]) == -100, "only those since the last SYNC"
    assert d.read(0x6078) == -100 and d.read(0x6077) == -100, "an SDO read: the same mean"
    with pytest.raises(SdoAbortedError) as refused:
        d.write(0x2010, 0, 2)
    assert refused.value.code == 0x06090030
    b.nmt(0x81)  # reset node: not a stored parameter
    assert d.read(0x2010) == 0


def test_no_pdos_before_nmt_start():
    b = Bench()
    b.map_pdo(0x1800, [0x60410010])
    b.sent.clear()
    b.frame(0x80, b"")
    assert b.frames(0x185) == []
    b.nmt(0x01)
    b.frame(0x80, b"")
    assert len(b.frames(0x185)) == 1


@pytest.mark.parametrize(
    ("write", "code"),
    [
        # a mapping changed while its PDO is valid
        (lambda d: d.write(0x1A00, 1, 0x60640020), 0x06010000),
        # an entry written while the count is not 0
        (lambda d: (d.write(0x1800, 1, PDO_NOT_VALID | 0x185), d.write(0x1A00, 1, 0x60640020)),
         0x06010000),
        # not mappable (a parameter), or into the wrong direction, or of the wrong length
        (lambda d: (d.write(0x1800, 1, PDO_NOT_VALID | 0x185), d.write(0x1A00, 0, 0),
                    d.write(0x1A00, 1, 0x60750020)), 0x06040041),
        (lambda d: (d.write(0x1400, 1, PDO_NOT_VALID | 0x205), d.write(0x1600, 0, 0),
                    d.write(0x1600, 1, 0x60410010)), 0x06040041),
        (lambda d: (d.write(0x1800, 1, PDO_NOT_VALID | 0x185), d.write(0x1A00, 0, 0),
                    d.write(0x1A00, 1, 0x60640010)), 0x06040043),
        # more than 64 bits
        (lambda d: (d.write(0x1800, 1, PDO_NOT_VALID | 0x185), d.write(0x1A00, 0, 0),
                    [d.write(0x1A00, k, 0x60640020) for k in (1, 2, 3)],
                    d.write(0x1A00, 0, 3)), 0x06040042),
        # another COB-ID while valid; a TPDO type it does not do
        (lambda d: d.write(0x1800, 1, 0x186), 0x06090030),
        (lambda d: d.write(0x1800, 2, 0xFE), 0x06090030),
        # the quick stop option codes and 0x6007 it does not do
        (lambda d: d.write(0x605A, 0, 1), 0x06090030),
        (lambda d: d.write(0x6007, 0, 4), 0x06090030),
        # read-only parameters
        (lambda d: d.write(0x6091, 1, 100), 0x06010002),
    ],
)  # fmt: skip
def test_the_drive_refuses_what_cia301_and_its_eds_do_not_allow(write, code):
    b = Bench()
    b.map_pdo(0x1800, [0x60410010])
    with pytest.raises(SdoAbortedError) as err:
        write(b.drive)
    assert err.value.code == code


def test_the_heartbeat_producer_sends_the_nmt_state_every_0x1017_ms():
    b = Bench()
    b.drive.write(0x1017, 0, 50)
    b.nmt(0x01)
    b.sent.clear()
    for k in range(1005):  # 1.004 s in 1 ms steps: beats at 0, 50, .., 1000 ms
        b.drive.heartbeat(k * 0.001)
    beats = b.frames(0x705)
    assert len(beats) == 21 and set(beats) == {bytes([0x05])}


@pytest.mark.parametrize(
    ("option", "state", "code"),
    [
        (0, DriveState.OPERATION_ENABLED, 0),
        (1, DriveState.FAULT_REACTION_ACTIVE, 0x8130),
        (2, DriveState.SWITCH_ON_DISABLED, 0),
        (3, DriveState.SWITCH_ON_DISABLED, 0),  # 11, then 12 at once: already at rest
    ],
)
def test_a_lost_host_heartbeat_applies_the_abort_connection_option_code(option, state, code):
    b = Bench()
    d = b.drive
    d.write(0x1016, 1, (0x7F << 16) | 100)
    d.write(0x6007, 0, option)
    b.nmt(0x01)
    b.enable()
    b.step(wall_s=5.0)  # no heartbeat yet: not armed
    assert d.state == DriveState.OPERATION_ENABLED
    b.frame(0x77F, b"\x05", wall_s=5.0)
    b.step(wall_s=5.1)  # within 100 ms
    assert d.state == DriveState.OPERATION_ENABLED
    b.step(wall_s=5.101)
    assert d.state == state and d.read(0x603F) == code
    taken = {0: 4, 1: 13, 2: 9, 3: 12}[option]
    assert d.transitions[-1] == taken and (option != 3 or d.transitions[-2] == 11)


def test_missing_syncs_in_operation_enabled_fault_after_the_configured_cycles():
    b = Bench()
    d = b.drive
    d.write(0x1006, 0, 4000)  # 4 ms: 5 cycles are 20 ms
    b.nmt(0x01)
    b.enable()
    for _ in range(9):  # 18 ms of 2 ms servo cycles
        b.step()
    assert d.state == DriveState.OPERATION_ENABLED
    b.frame(0x80, b"")
    steps = 0
    while d.state == DriveState.OPERATION_ENABLED and steps < 50:
        b.step()
        steps += 1
    # 20 ms after the SYNC (the step at 20 ms may see 20 ms and a rounding more)
    assert steps in (11, 12)
    assert d.state == DriveState.FAULT_REACTION_ACTIVE and d.read(0x603F) == 0x8700


def test_each_drive_reports_its_joints_gear_encoder_and_rating_from_the_truth():
    cfg = load_sim_config(CIA402_TRUTH)
    assert cfg.controller.can_profile == "cia402" and cfg.controller.cycle_period_s == 0.002
    base = load_sim_config()
    assert cfg.inner_loop == base.inner_loop and cfg.drives == base.drives  # the same plant
    axes = axis_parameters(cfg)
    assert [a.gear_motor_revolutions for a in axes] == [147, 153, 153, 76, 80, 50]
    assert {(a.gear_shaft_revolutions, a.encoder_increments) for a in axes} == {(1, 1 << 20)}
    assert [a.rated_current_ma for a in axes] == [21000, 61000, 44000, 5000, 2000, 2000]
    # rated torque, motor side: K · I_rated / R [mN·m]
    assert [a.rated_torque_mnm for a in axes] == [6601, 26385, 11216, 734, 279, 223]


def test_the_drives_import_nothing_of_the_products_cia402_code():
    seen = _closure("sim_bridge.cia402_cell")
    # the walk works: it reaches the drives through the cell, and the profile through them
    assert {"sim_bridge.cia402_drives", "sim_bridge.cia402_profile", "sim_bridge.sim"} <= seen
    bad = sorted(m for m in seen if m.startswith("drivers.can.cia402"))
    assert not bad, f"the virtual drives reach the product's CiA 402 code: {bad}"


def _closure(root: str) -> set[str]:
    """Modules of this repository that ``root`` imports, transitively (``ast``)."""
    seen, todo = set(), [root]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        base = REPO.joinpath(*name.split("."))
        path = next((p for p in (base.with_suffix(".py"), base / "__init__.py") if p.is_file()),
                    None)  # fmt: skip
        if path is None:
            continue
        seen.add(name)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                todo += [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = package.split(".")
                    mod = ".".join([*parts[: len(parts) - node.level + 1], node.module or ""])
                else:
                    mod = node.module or ""
                todo.append(mod.rstrip("."))
                todo += [f"{mod}.{a.name}" for a in node.names]
    return seen
