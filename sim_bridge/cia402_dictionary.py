"""One virtual CiA 402 drive's canopen node (:mod:`sim_bridge.cia402_drives`): its object
dictionary from the drive's EDS, the SDO server (canopen's :class:`~canopen.LocalNode`), the
frames it sends, and its PDO configuration.

PDOs as the host maps them by SDO in 0x1400-0x1401/0x1600-0x1601 (RPDO) and
0x1800-0x1801/0x1A00-0x1A01 (TPDO), checked on write as CiA 301's mapping procedure asks: a
mapping is changed only with its PDO not valid (bit 31 of the COB-ID) and its count (sub 0)
at 0; every entry a mappable object of its whole size; at most 64 bits. Packing reads the
mapping entries, never a fixed layout.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from sim_bridge.cia402_profile import (
    PDO_COB_ID_MASK,
    PDO_NOT_VALID,
    RPDO_COMMUNICATION,
    RPDO_MAPPING,
    TPDO_COMMUNICATION,
    SdoAbort,
)

#: The drive's EDS, one file for every axis (the node id fills in $NODEID).
EDS_PATH = Path(__file__).resolve().parent.parent / "deploy" / "cia402" / "leadthrough_drive.eds"


@dataclass(frozen=True)
class PdoConfig:
    """One PDO as its communication and mapping objects configure it."""

    cob_id: int
    valid: bool
    transmission_type: int
    entries: tuple[tuple[int, int, int], ...]  #: (index, sub-index, length [bits])

    @property
    def length_bytes(self) -> int:
        return sum(bits for _, _, bits in self.entries) // 8


class _SendingNetwork(canopen.Network):
    """The canopen network of one drive: what it sends goes to ``send``; nothing is received
    through it (the cell loop hands each frame to the drive)."""

    def __init__(self, send: Callable[[can.Message], None]) -> None:
        super().__init__(None)
        self._send = send

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._send(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False))


class DriveDictionary:
    """One drive's canopen node on a network of its own that sends through ``send``: its
    object dictionary (read from ``eds``), SDO server and PDO configuration. ``on_read`` and
    ``on_write`` are the node's read and write callbacks (the drive's live objects, and its
    checks and settings on a write by SDO or RPDO)."""

    def __init__(
        self,
        node_id: int,
        send: Callable[[can.Message], None],
        on_read: Callable[[int, int, ODVariable], int | None],
        on_write: Callable[[int, int, ODVariable, bytes], None],
        eds: Path,
    ) -> None:
        self._network = _SendingNetwork(send)
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        self._network.add_node(self.node)
        # canopen's NMT slave would start a timer thread on a write of 0x1017: the heartbeat
        # producer is the drive's (:meth:`~sim_bridge.cia402_drives.Cia402Drive.heartbeat`),
        # run by the cell loop.
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(on_write)
        self.node.add_read_callback(on_read)
        self._od = self.node.object_dictionary
        self._pdo_cache: tuple[dict[int, PdoConfig], list[PdoConfig]] | None = None

    def send(self, cob_id: int, data: bytes) -> None:
        self._network.send_message(cob_id, data)

    # --- object dictionary ------------------------------------------------------------------
    def read(self, index: int, subindex: int = 0) -> int:
        """An object's value as an SDO upload would give it."""
        obj = self.variable(index, subindex)
        return obj.decode_raw(self.node.get_data(index, subindex))

    def write(self, index: int, subindex: int, value: int) -> None:
        """Write an object as an SDO download would (its checks included: SdoAbortedError)."""
        obj = self.variable(index, subindex)
        self.node.set_data(index, subindex, obj.encode_raw(value), check_writable=True)

    def variable(self, index: int, subindex: int) -> ODVariable:
        obj = self._od[index]
        return obj if isinstance(obj, ODVariable) else obj[subindex]

    def store(self, index: int, subindex: int, value: int) -> None:
        """Set an object without the host's checks (the drive's own values)."""
        raw = self.variable(index, subindex).encode_raw(value)
        self.node.data_store.setdefault(index, {})[subindex] = raw

    def clear_application(self) -> None:
        """The application's objects (0x2000 and up) back to their defaults."""
        for index in [i for i in self.node.data_store if i >= 0x2000]:
            del self.node.data_store[index]

    def clear_communication(self) -> None:
        """The communication objects (0x1000-0x1FFF) back to their defaults."""
        for index in [i for i in self.node.data_store if i < 0x2000]:
            del self.node.data_store[index]
        self._pdo_cache = None

    # --- PDO configuration ------------------------------------------------------------------
    def check_pdo_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301 PDO communication and mapping parameters: what may change, and when."""
        receive = index in RPDO_COMMUNICATION + RPDO_MAPPING
        comm = index if index in RPDO_COMMUNICATION + TPDO_COMMUNICATION else index - 0x200
        cob_now = self.read(comm, 1)
        valid = not cob_now & PDO_NOT_VALID
        if index == comm:  # communication parameter
            if subindex == 1:
                if value & (1 << 29):
                    raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)  # no 29-bit ids
                same_id = (value ^ cob_now) & PDO_COB_ID_MASK == 0
                if valid and not value & PDO_NOT_VALID and not same_id:
                    raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            elif subindex == 2 and not (value <= 240 or (receive and value >= 254)):
                raise SdoAbortedError(SdoAbort.VALUE_RANGE_EXCEEDED)
            return
        # mapping parameter: only with the PDO not valid, entries only with the count at 0
        if valid:
            raise SdoAbortedError(SdoAbort.UNSUPPORTED_ACCESS)
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(SdoAbort.MAPPING_TOO_LONG)
            entries = [self.read(index, k) for k in range(1, value + 1)]
            if sum(e & 0xFF for e in entries) > 64:
                raise SdoAbortedError(SdoAbort.MAPPING_TOO_LONG)
            for entry in entries:
                self._check_entry(entry, receive)
            return
        if self.read(index, 0) != 0:
            raise SdoAbortedError(SdoAbort.UNSUPPORTED_ACCESS)
        if value:
            self._check_entry(value, receive)

    def _check_entry(self, entry: int, receive: bool) -> None:
        index, subindex, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        try:
            obj = self.variable(index, subindex)
        except KeyError:
            raise SdoAbortedError(SdoAbort.NOT_MAPPABLE) from None
        usable = obj.writable if receive else obj.readable
        if not obj.pdo_mappable or not usable:
            raise SdoAbortedError(SdoAbort.NOT_MAPPABLE)
        if bits != len(obj):
            raise SdoAbortedError(SdoAbort.PARAMETER_INCOMPATIBLE)

    def pdo_config(self, comm_index: int) -> PdoConfig:
        """A PDO as its objects now configure it (``comm_index`` 0x1400.. or 0x1800..)."""
        map_index = comm_index + 0x200
        cob = self.read(comm_index, 1)
        entries = []
        for k in range(1, self.read(map_index, 0) + 1):
            if e := self.read(map_index, k):
                entries.append((e >> 16, (e >> 8) & 0xFF, e & 0xFF))
        return PdoConfig(
            cob_id=cob & PDO_COB_ID_MASK,
            valid=not cob & PDO_NOT_VALID,
            transmission_type=self.read(comm_index, 2),
            entries=tuple(entries),
        )

    def pdos(self) -> tuple[dict[int, PdoConfig], list[PdoConfig]]:
        """(valid RPDOs by COB-ID, valid TPDOs), read again when the dictionary changed."""
        if self._pdo_cache is None:
            rpdos = [self.pdo_config(i) for i in RPDO_COMMUNICATION]
            tpdos = [self.pdo_config(i) for i in TPDO_COMMUNICATION]
            self._pdo_cache = (
                {p.cob_id: p for p in rpdos if p.valid},
                [p for p in tpdos if p.valid],
            )
        return self._pdo_cache

    def pack(self, pdo: PdoConfig) -> bytes:
        return b"".join(self.node.get_data(i, s) for i, s, _ in pdo.entries)

    def unpack(self, pdo: PdoConfig, data: bytes, refused: Callable[[str], None]) -> None:
        """Store a PDO's data in the mapped objects; ``refused`` is told of each value the
        drive refuses (its write callback aborting)."""
        offset = 0
        for index, subindex, bits in pdo.entries:
            size = bits // 8
            try:
                self.node.set_data(index, subindex, data[offset : offset + size])
            except SdoAbortedError:
                # a value the drive refuses (a mode it has not) cannot be answered by abort
                why = f"0x{index:04X} = {data[offset : offset + size].hex()} by PDO refused"
                refused(why)
            offset += size

    def invalidate_pdos(self) -> None:
        """A PDO's communication or mapping parameter changed: read them again."""
        self._pdo_cache = None
