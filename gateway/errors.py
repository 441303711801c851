"""One exception tree for the whole product.

Leaves also subclass the builtin they resemble, so callers that only know Python's
exceptions still catch them (``except ValueError`` catches a bad config value).
"""

#: exit status of a process that refuses its configuration (sysexits' EX_CONFIG): the gateway
#: does not restart such a child, and the systemd unit does not restart such a gateway
#: (``RestartPreventExitStatus``), since the same file would be refused again
EXIT_CONFIG = 78


class LeadthroughError(Exception):
    """Root of every error this product raises on purpose."""


class ConfigError(LeadthroughError, ValueError):
    """A configuration file or field is missing, malformed or out of range."""


class MessageError(LeadthroughError, ValueError):
    """A zenoh message could not be decoded or failed validation."""


class FrameError(LeadthroughError, ValueError):
    """A CAN frame is malformed: wrong length, bad checksum, out-of-range signal."""


class ModbusReplyError(LeadthroughError, ValueError):
    """A Modbus reply is an exception response, has the wrong size, or decodes to nonsense."""


class LinkTimeoutError(LeadthroughError, TimeoutError):
    """A peer (controller, I/O, bus process) stopped answering within its deadline."""


class SafetyError(LeadthroughError, RuntimeError):
    """A safety condition (e-stop, enabling device, limit) forbids the requested action."""


class DataFileError(LeadthroughError, ValueError):
    """A measurement file (CSV, MCAP) is malformed; the message names file and line."""
