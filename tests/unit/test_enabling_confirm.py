"""The gateway counts the enabling device as held only once `[gateway] enabling_confirm_polls`
I/O states in a row read it held (gateway/supervisor.py); a release counts at once. One corrupt
Modbus reply with the bit set (tests/transport/test_modbus_fuzz.py publishes such ones: Modbus
TCP has no checksum above TCP's) must not start teaching."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.bus import BusConfig
from gateway.errors import ConfigError
from gateway.gateway_config import GatewayConfig
from gateway.messages import IoState
from gateway.supervisor import Gateway


class _Sample:
    def __init__(self, io: IoState) -> None:
        self._raw = io.to_bytes()
        self.payload = self

    def to_bytes(self) -> bytes:
        return self._raw


def _feed(gw: Gateway, *enabling: bool) -> list[bool]:
    seen = []
    for k, held in enumerate(enabling):
        gw._on_io(_Sample(IoState(float(k), 6.0, 4.0, 6.0, 4.0, held, True)))
        seen.append(gw.observations(gw.io_rx_s).enabling)
    return seen


@pytest.mark.parametrize("polls", [1, 2, 3])
def test_held_after_n_states_in_a_row_released_at_once(polls):
    gw = Gateway(Path("cell.toml"), BusConfig(), GatewayConfig(enabling_confirm_polls=polls))
    seen = _feed(gw, True, False, True, True, True, True, False, True)
    if polls == 1:
        assert seen == [True, False, True, True, True, True, False, True]
    elif polls == 2:
        assert seen == [False, False, False, True, True, True, False, False]
    else:
        assert seen == [False, False, False, False, True, True, False, False]


def test_the_confirmation_is_checked():
    for bad in (0, 51, 1.5, True):
        with pytest.raises(ConfigError, match="enabling_confirm_polls"):
            GatewayConfig(enabling_confirm_polls=bad)
