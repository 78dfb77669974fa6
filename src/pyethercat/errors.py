"""Typed errors raised by pyethercat.

Every failure a user can meet is one of these classes, so callers can catch
``EtherCATError`` (everything) or something narrower. No ``IndexError`` or
``struct.error`` is meant to escape the library.
"""

from __future__ import annotations

import builtins

__all__ = [
    "AlStatusError",
    "CaptureError",
    "ConfigError",
    "EsiError",
    "EtherCATError",
    "FrameError",
    "FrameTooLargeError",
    "LinkClosedError",
    "LinkError",
    "MailboxError",
    "MailboxErrorReply",
    "PermissionError",
    "SdoAbort",
    "SiiError",
    "StateTimeoutError",
    "TimeoutError",
    "TopologyMismatchError",
    "WorkingCounterError",
]


class EtherCATError(Exception):
    """Base class of every pyethercat error."""


# --- wire / codec errors -----------------------------------------------------


class FrameError(EtherCATError, ValueError):
    """A frame or datagram is malformed (truncated, lying length word, ...).

    ``offset`` is the byte offset in the frame where the problem was found,
    when known.
    """

    def __init__(self, message: str, offset: int | None = None) -> None:
        self.offset = offset
        if offset is not None:
            message = f"{message} (at byte {offset})"
        super().__init__(message)


class FrameTooLargeError(FrameError):
    """Datagrams do not fit into one Ethernet frame (1514 bytes / 1486 data bytes)."""


class CaptureError(EtherCATError, ValueError):
    """A capture file (pcap / pcapng) is malformed or uses an unsupported feature."""


class SiiError(EtherCATError, ValueError):
    """An SII (EEPROM) image is malformed or inconsistent."""


class MailboxError(EtherCATError):
    """A mailbox frame is malformed or a mailbox transfer failed."""


class MailboxErrorReply(MailboxError):
    """The slave answered with a mailbox error reply (mailbox type 0)."""

    def __init__(self, code: int, name: str) -> None:
        self.code = code
        self.name = name
        super().__init__(f"mailbox error 0x{code:04X}: {name}")


class SdoAbort(MailboxError):
    """An SDO transfer was aborted (by the slave or by us)."""

    def __init__(self, code: int, name: str, index: int = 0, subindex: int = 0) -> None:
        self.code = code
        self.name = name
        self.index = index
        self.subindex = subindex
        super().__init__(f"SDO abort 0x{code:08X} at 0x{index:04X}:{subindex:02X}: {name}")


class EsiError(EtherCATError, ValueError):
    """An ESI (or ENI) XML file is malformed, unsafe or not understood."""

    def __init__(self, message: str, path: str | None = None, line: int | None = None) -> None:
        self.path = path
        self.line = line
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        super().__init__(f"{where}{message}")


class ConfigError(EtherCATError, ValueError):
    """A configuration (topology file, expected network, PDO layout) is invalid."""


# --- link errors ---------------------------------------------------------------


class LinkError(EtherCATError, OSError):
    """The link (network interface, socket) failed."""


class PermissionError(LinkError, builtins.PermissionError):  # noqa: A001 - deliberate name
    """Opening a raw socket needs privileges we do not have."""


class LinkClosedError(LinkError):
    """The link was closed (by us or by the peer)."""


# --- master runtime errors -----------------------------------------------------


class TimeoutError(EtherCATError, builtins.TimeoutError):  # noqa: A001 - deliberate name
    """No (valid) reply arrived in time."""


class WorkingCounterError(EtherCATError):
    """A datagram came back with an unexpected working counter."""

    def __init__(self, message: str, expected: int, actual: int) -> None:
        self.expected = expected
        self.actual = actual
        super().__init__(f"{message}: working counter {actual}, expected {expected}")


class AlStatusError(EtherCATError):
    """A slave refused or left a requested AL state; carries the AL status code."""

    def __init__(self, message: str, code: int, code_name: str) -> None:
        self.code = code
        self.code_name = code_name
        super().__init__(f"{message}: AL status code 0x{code:04X} ({code_name})")


class StateTimeoutError(TimeoutError):
    """Slaves did not reach a requested state in time."""


class TopologyMismatchError(ConfigError):
    """The scanned network does not match the expected configuration."""
