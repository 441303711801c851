"""systemd's service notification protocol (sd_notify(3)), for ``Type=notify`` with a watchdog.

systemd passes ``NOTIFY_SOCKET`` (a Unix datagram socket: a path, or ``@name`` in the abstract
namespace) and, with ``WatchdogSec=``, ``WATCHDOG_USEC``. The service sends ``READY=1`` once it
serves, ``WATCHDOG=1`` at least every half of the watchdog interval while its main loop is
alive (systemd kills and restarts it otherwise), and ``STOPPING=1`` as it shuts down. Outside
systemd there is no socket and every call does nothing, so the gateway runs the same from a
terminal or a test.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


class Notifier:
    """One service's notifications; the environment is read at construction."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        if address.startswith("@"):
            address = "\0" + address[1:]
        self.address = address or None
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        watched = usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid()))
        #: how often to ping the watchdog [s] (half its interval), or None without one
        self.watchdog_period_s = int(usec) / 2e6 if watched else None
        self._next_ping_s = float("-inf")

    def _send(self, state: str) -> bool:
        if self.address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
                s.connect(self.address)
                s.sendall(state.encode())
        except OSError as exc:  # systemd gone or the socket not ours: nothing to tell
            log.warning("sd_notify %s failed: %s", state.split("\n", 1)[0], exc)
            return False
        return True

    def ready(self, status: str = "") -> bool:
        return self._send("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def stopping(self) -> bool:
        return self._send("STOPPING=1")

    def watchdog(self, now_s: float) -> bool:
        """Ping the watchdog if it is due at monotonic time ``now_s`` [s]."""
        if self.watchdog_period_s is None or now_s < self._next_ping_s:
            return False
        self._next_ping_s = now_s + self.watchdog_period_s
        return self._send("WATCHDOG=1")
