"""The tables the compiled cycle's adapter is built from, for any adapter the driver runs.

The DBC and EDS files stay parsed in Python (cantools, canopen); the compiled adapters
(drivers/can/rt/src/{ltc_adapter,ltc_fd_adapter,cia402}.rs) take what those parsers derive,
as JSON. This picks the derivation for an adapter instance: the LTC profiles' message and
signal tables (:mod:`drivers.can.rt_tables`), or the CiA 402 drives' PDO layouts and state
after the adapter's start-up (:mod:`drivers.can.rt_cia402_tables`).
"""

from __future__ import annotations

from typing import Any

from drivers.can.adapter import CanAdapter
from drivers.can.config import CanDriverConfig
from drivers.can.rt_cia402_tables import cia402_tables, tables_from_config
from drivers.can.rt_tables import ltc_tables
from gateway.errors import ConfigError

#: Adapters the compiled cycle has (drivers/can/rt/src/py.rs build_adapter).
COMPILED_ADAPTERS = ("ltc_dbc", "ltc_fd", "cia402")


def adapter_tables(adapter: CanAdapter) -> dict[str, Any]:
    """The compiled adapter's tables for ``adapter``; ConfigError for an adapter the compiled
    cycle does not have (an entry-point adapter written in Python cannot run on it)."""
    if adapter.name == "cia402":
        return cia402_tables(adapter)
    if adapter.name in ("ltc_dbc", "ltc_fd"):
        return ltc_tables(adapter.name, adapter.n_joints)
    raise ConfigError(
        f"[can].adapter = {adapter.name!r}: the compiled cycle has {list(COMPILED_ADAPTERS)}; "
        "a vendor protocol is added as a compiled adapter (drivers/can/rt/src/adapter.rs)"
    )


def static_tables(config: CanDriverConfig) -> dict[str, Any]:
    """The tables the ``[can]`` section alone gives, before any adapter's start-up (CiA 402:
    the PDO layouts the start-up will write, from the EDS): enough to check a config."""
    if config.adapter == "cia402":
        return tables_from_config(config)
    return ltc_tables(config.adapter, config.joints)
