"""One way to run a product process: the gateway, the CAN driver, the Modbus driver, control.

Each process is a :class:`Service` built from the cell config; :func:`run_service` gives all
four the same life:

- **logging**: one line format naming the process (journald adds the time stamp in
  production; a terminal or a test log gets it from the format);
- **configuration**: the service is built before anything opens; a :class:`ConfigError`
  (or one raised while opening, e.g. a drive reporting other units than the config) is logged
  once, in one line, and the exit status is :data:`EXIT_CONFIG`, which the gateway does not
  restart (the same file would be refused again);
- **signals**: SIGTERM and SIGINT set the service's stop event (:mod:`gateway.signals`: no
  lock in a signal handler);
- **zenoh**: the service opens its session as its bus identity (:mod:`gateway.bus_security`)
  in :meth:`Service.open` and closes it in :meth:`Service.close`, which runs on every path,
  after an error too (the CAN driver's close is what brakes the arm);
- **health**: :meth:`Service.run` returns when the stop event is set, or when the service's
  worker died, which it reports by raising: the process then exits 1 and the gateway restarts
  it. The health *messages* stay with each service's own loop: a health message is evidence
  that the thread doing the work is alive, so it must come from that thread;
- **systemd** (``notify=True``, the gateway: the unit's main process): ``READY=1`` once open,
  ``STOPPING=1`` on the way out, and :meth:`Service.run` pings the watchdog from its loop.
  The children leave systemd alone (``NotifyAccess=main`` ignores them anyway).

Expected failures (:class:`LeadthroughError`: a link that timed out, a refused reply) are
logged in one line; anything else is a bug and gets its traceback too. Both exit 1.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, Protocol

from gateway.errors import EXIT_CONFIG, ConfigError, LeadthroughError
from gateway.sd_notify import Notifier
from gateway.signals import StopSignals

log = logging.getLogger(__name__)

#: exit status of a process that failed on anything but its configuration
EXIT_FAILED = 1

LOG_FORMAT = "%(asctime)s {process} %(levelname)s %(name)s: %(message)s"


class Service(Protocol):
    """A product process between its configuration and its exit."""

    #: set by SIGTERM/SIGINT (or by the service itself) to end :meth:`run`
    stop_event: threading.Event

    def open(self) -> None:
        """Open the links (zenoh session, CAN, Modbus) and start the workers."""

    def run(self, notifier: Notifier | None) -> None:
        """Serve until :attr:`stop_event`; raise if a worker died. Ping ``notifier``'s
        watchdog from the loop that proves the service alive."""

    def close(self) -> None:
        """Stop the workers and close the links; safe after a failed or partial :meth:`open`."""


def setup_logging(process: str, level: int = logging.INFO) -> None:
    """The process's log format, unless logging is set up already (``leadthrough`` did)."""
    if not logging.getLogger().handlers:
        logging.basicConfig(level=level, format=LOG_FORMAT.format(process=process))


def run_service(
    process: str,
    build: Callable[[], Service],
    *,
    notify: bool = False,
    status: Callable[[Any], str] | None = None,
    log_level: int = logging.INFO,
    place: Callable[[], Any] | None = None,
) -> int:
    """Build, open and run one product process until it is asked to stop; its exit status:
    0 on a clean stop, :data:`EXIT_CONFIG` for a refused configuration, :data:`EXIT_FAILED`
    for anything else (module docstring). ``status(service)`` is systemd's line once ready.
    ``place()`` applies the process's ``[realtime]`` (gateway/realtime.py) once it is built and
    before it opens a link: the threads it opens then inherit the cycle's priority, and the
    building (a model loaded, a law set up: 0.8 s in a CPU group given 0.15 of each CPU, 4-5
    times harsher than the slowest machine of our class) ran at the cycle's priority before and
    held the CAN driver off its cycle."""
    setup_logging(process, log_level)
    try:
        service = build()
    except ConfigError as exc:
        log.error("%s: configuration refused: %s", process, exc)
        return EXIT_CONFIG
    notifier = Notifier() if notify else None
    with StopSignals(service.stop_event):
        try:
            if place is not None:
                place()
            service.open()
            if notifier is not None:
                notifier.ready("" if status is None else status(service))
            service.run(notifier)
        except ConfigError as exc:
            log.error("%s: configuration refused: %s", process, exc)
            return EXIT_CONFIG
        except LeadthroughError as exc:
            log.error("%s failed: %s", process, exc)
            return EXIT_FAILED
        except Exception as exc:
            log.error("%s failed: %s: %s", process, type(exc).__name__, exc, exc_info=True)
            return EXIT_FAILED
        finally:
            if notifier is not None:
                notifier.stopping()
            _close(process, service)
    return 0


def _close(process: str, service: Service) -> None:
    """Close ``service``; an error while closing is logged, never raised over the one that
    ended the run."""
    try:
        service.close()
    except Exception as exc:
        log.error("%s: closing failed: %s: %s", process, type(exc).__name__, exc, exc_info=True)
    else:
        log.info("%s stopped", process)
