"""The CiA 402 adapter's hand-over to the compiled cycle (drivers/can/rt/src/cia402.rs): the
tables the Rust cycle is built from, made of a started or a statically configured adapter.

What stays in Python: the start-up, :meth:`drivers.can.cia402.Cia402Adapter.start` (NMT, the
drives' configuration by SDO through python-canopen, their PDO maps, whose byte formats come
from the EDS's data types). The adapter computes its PDO layouts only there; after it,
:func:`cia402_tables` turns what the adapter holds into one JSON-serializable dict, and the
Rust ``Cia402Adapter::from_tables`` runs the cycle from it (SYNC, TPDOs → cycle, RPDOs, the
state machine's controlwords, the host heartbeat), continuing from the adapter's state.

For an adapter that has not been started (tests, golden vectors, a config check),
:func:`configure_statically` gives it the layouts :meth:`~Cia402Adapter.start` would map: the
same PDO contents (:func:`pdo_contents`, as ``Cia402Adapter._configure`` maps them) packed by
the adapter's own ``_layout`` from canopen PDO maps of the EDS, without a bus.
:func:`tables_from_config` does both for a ``[can]`` section.

The tables (``TABLES_FORMAT``; every float is its ``repr()`` string, so that the Rust side
parses it exactly: serde_json without its ``float_roundtrip`` feature may be one ULP off)::

    format, adapter ("cia402"), n_joints, mode ("csp" | "csv"), host_node_id,
    sync_cob_id, nmt_operational, counter_modulus,
    clock_period_s, host_heartbeat_timeout_s, producer_heartbeat_s, heartbeat_late_factor,
    request ("BRAKE" | "SERVO_ON" | "RESET_FAULT": the request the RPDO1s walk towards),
    dropped (the latched "J2 left operation enabled ..." text, "" when none),
    disabled_at_cycle (stats.cycles at the last request other than SERVO_ON | null: none),
    host_disable_cycles (cia402.HOST_DISABLE_CYCLES),
    sync_count (the counter of the last SYNC), corrupt (the current cycle had a bad frame),
    stats ({frames, unknown_frames, bad_frames, cycles, incomplete_cycles, corrupt_cycles,
            last_error}),
    joints: [{node_id, inc_per_rad, amps_per_mille,
              rpdo1 | rpdo2 | tpdo1 | tpdo2: {cob_id, format (struct, "<Hl"), objects},
              state (the drive state's text), nmt_state (-1: no heartbeat yet),
              heartbeat_s (CLOCK_MONOTONIC [s] | null), emcy_code (0: none),
              last_target_inc (null: none sent), position_inc,
              tpdo1_values | tpdo2_values (this cycle's PDO so far | null)}]
"""

from __future__ import annotations

import logging
import math
from typing import Any

from drivers.can.cia402 import (
    HEARTBEAT_LATE_FACTOR,
    HOST_DISABLE_CYCLES,
    NMT_OPERATIONAL,
    SYNC_COB_ID,
    Cia402Adapter,
    _Joint,
    _layout,
)
from drivers.can.config import CanDriverConfig, Cia402Config

#: the tables' format name: the Rust side refuses any other
TABLES_FORMAT = "leadthrough.cia402-tables/1"


def pdo_contents(mode: str) -> dict[tuple[str, int], tuple[int, tuple[int, ...]]]:
    """(kind, number) → (COB-ID base, mapped objects): what ``Cia402Adapter._configure`` maps
    (keep the two alike; tests/unit/test_rt_cia402.py checks it against a real start-up)."""
    velocity_object = 0x60B1 if mode == "csp" else 0x60FF
    return {
        ("rpdo", 1): (0x200, (0x6040, 0x607A)),
        ("rpdo", 2): (0x300, (velocity_object,)),
        ("tpdo", 1): (0x180, (0x6041, 0x6064)),
        ("tpdo", 2): (0x280, (0x606C, 0x6078, 0x6077)),
    }


def static_joints(config: Cia402Config, n_joints: int) -> list[_Joint]:
    """The drives as :meth:`Cia402Adapter.start` configures them, without a bus: the PDO maps
    built by canopen from ``config.eds`` and packed by the adapter's ``_layout``, the units
    from the config (which start-up checks against the drives)."""
    import canopen

    logging.getLogger("canopen").setLevel(logging.WARNING)
    joints = []
    for k, nid in enumerate(config.ids(n_joints)):
        node = canopen.RemoteNode(nid, config.eds)
        where = f"CiA 402 drive node {nid} (J{k + 1})"
        pdos = {}
        for (kind, number), (base, objects) in pdo_contents(config.mode).items():
            pdo_map = (node.rpdo if kind == "rpdo" else node.tpdo)[number]
            pdo_map.clear()
            for index in objects:
                pdo_map.add_variable(index)
            pdo_map.cob_id = base + nid
            pdos[f"{kind}{number}"] = _layout(pdo_map, f"{where} {kind.upper()}{number}")
        joints.append(
            _Joint(
                node_id=nid,
                inc_per_rad=config.encoder_increments * config.gear_ratio[k] / (2.0 * math.pi),
                amps_per_mille=config.rated_current_a[k] / 1000.0,
                **pdos,
            )
        )
    return joints


def configure_statically(adapter: Cia402Adapter) -> Cia402Adapter:
    """Give a not started ``adapter`` the drives :func:`static_joints` configures; returns it."""
    adapter._attach(static_joints(adapter.config, adapter.n_joints))
    return adapter


def tables_from_config(config: CanDriverConfig) -> dict[str, Any]:
    """The tables of the ``[can]`` section ``config`` (adapter "cia402") before any start-up."""
    return cia402_tables(configure_statically(Cia402Adapter.from_config(config)))


def _float(x: float | None) -> str | None:
    return None if x is None else repr(float(x))


def _pdo(pdo: Any) -> dict[str, Any]:
    return {"cob_id": pdo.cob_id, "format": pdo.layout.format, "objects": list(pdo.objects)}


def _values(values: tuple[int, ...] | None) -> list[int] | None:
    return None if values is None else [int(v) for v in values]


def cia402_tables(adapter: Cia402Adapter) -> dict[str, Any]:
    """Everything the compiled cycle needs of a started (or :func:`configure_statically`)
    ``adapter``, continuing from its state (module docstring). ValueError if it has no drives
    (neither started nor configured)."""
    joints = adapter._joints
    if len(joints) != adapter.n_joints:
        raise ValueError(
            f"the CiA 402 adapter knows {len(joints)} of {adapter.n_joints} drives: start it "
            "(or configure_statically) first"
        )
    cfg = adapter.config
    return {
        "format": TABLES_FORMAT,
        "adapter": adapter.name,
        "n_joints": adapter.n_joints,
        "mode": cfg.mode,
        "host_node_id": cfg.host_node_id,
        "sync_cob_id": SYNC_COB_ID,
        "nmt_operational": NMT_OPERATIONAL,
        "counter_modulus": adapter.counter_modulus,
        "clock_period_s": _float(adapter.clock_period_s),
        "host_heartbeat_timeout_s": _float(adapter.host_heartbeat_timeout_s),
        "producer_heartbeat_s": _float(cfg.producer_heartbeat_s),
        "heartbeat_late_factor": _float(HEARTBEAT_LATE_FACTOR),
        "request": adapter._request.name,
        "dropped": adapter._dropped,
        "disabled_at_cycle": adapter._disabled_at_cycle,
        "host_disable_cycles": HOST_DISABLE_CYCLES,
        "sync_count": adapter._sync_count,
        "corrupt": adapter._corrupt,
        "stats": adapter.stats.as_dict(),
        "joints": [
            {
                "node_id": j.node_id,
                "inc_per_rad": _float(j.inc_per_rad),
                "amps_per_mille": _float(j.amps_per_mille),
                "rpdo1": _pdo(j.rpdo1),
                "rpdo2": _pdo(j.rpdo2),
                "tpdo1": _pdo(j.tpdo1),
                "tpdo2": _pdo(j.tpdo2),
                "state": j.state.value,
                "nmt_state": j.nmt_state,
                "heartbeat_s": _float(j.heartbeat_s),
                "emcy_code": int(j.emergency.removeprefix("EMCY 0x"), 16) if j.emergency else 0,
                "last_target_inc": j.last_target_inc,
                "position_inc": int(j.position_inc),
                "tpdo1_values": _values(adapter._tp1[k]),
                "tpdo2_values": _values(adapter._tp2[k]),
            }
            for k, j in enumerate(joints)
        ],
    }
