"""Typed errors raised by pyethercat.

Every failure a user can meet is one of these classes, so callers can catch
``EtherCATError`` (everything) or something narrower. No ``IndexError`` or
``struct.error`` is meant to escape the library.
"""

from __future__ import annotations

import builtins

__all__ = [
    "AlStatusError",
    "BootMailboxConfigError",
    "BootstrapNotSupportedError",
    "CaptureError",
    "ConfigError",
    "DriveError",
    "DriveFaultError",
    "DriveTimeoutError",
    "EngineDiedError",
    "EsiError",
    "EtherCATError",
    "FrameError",
    "FoeAbort",
    "FoeAccessDenied",
    "FoeAlreadyExists",
    "FoeBootstrapOnly",
    "FoeChecksumError",
    "FoeDiskFull",
    "FoeIllegal",
    "FoeNoRights",
    "FoeNoUser",
    "FoeNotDefined",
    "FoeNotFound",
    "FoeNotInBootstrap",
    "FoePacketNumberWrong",
    "FoeProgramError",
    "FoeTimeoutError",
    "FrameTooLargeError",
    "LinkClosedError",
    "LinkDownError",
    "LinkError",
    "MailboxError",
    "MailboxErrorReply",
    "PermissionError",
    "SdoAbort",
    "SiiError",
    "SoeAbort",
    "SoeTimeoutError",
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


class FoeAbort(MailboxError):
    """An FoE transfer ended with an FoE error (ERR opcode), sent by the slave or by us.

    ``code`` is the FoE error code (0x8000-0x800C), ``name`` its text from
    the shared table, ``text`` the optional text the sender added. Each
    standard code has its own subclass (:class:`FoeNotFound`, ...);
    :meth:`for_code` picks it.
    """

    #: The FoE error code the subclass stands for (None: any).
    CODE: int | None = None

    def __init__(self, code: int, name: str, text: str = "", *, by_master: bool = False) -> None:
        self.code = code
        self.name = name
        self.text = text
        self.by_master = by_master
        who = "we aborted" if by_master else "slave says"
        extra = f": {text}" if text else ""
        super().__init__(f"FoE error 0x{code:04X} ({who}: {name}){extra}")

    @classmethod
    def for_code(cls, code: int, name: str, text: str = "", *,
                 by_master: bool = False) -> FoeAbort:
        """The subclass instance for ``code`` (plain :class:`FoeAbort` for other codes)."""
        sub = _FOE_CLASSES.get(code, FoeAbort)
        return sub(code, name, text, by_master=by_master)


class FoeNotDefined(FoeAbort):
    """FoE error 0x8000: not defined (vendor-specific failure)."""

    CODE = 0x8000


class FoeNotFound(FoeAbort):
    """FoE error 0x8001: the file does not exist."""

    CODE = 0x8001


class FoeAccessDenied(FoeAbort):
    """FoE error 0x8002: access denied."""

    CODE = 0x8002


class FoeDiskFull(FoeAbort):
    """FoE error 0x8003: disk full (the file is larger than the slave takes)."""

    CODE = 0x8003


class FoeIllegal(FoeAbort):
    """FoE error 0x8004: illegal (request out of sequence, or refused)."""

    CODE = 0x8004


class FoePacketNumberWrong(FoeAbort):
    """FoE error 0x8005: packet number wrong."""

    CODE = 0x8005


class FoeAlreadyExists(FoeAbort):
    """FoE error 0x8006: the file already exists."""

    CODE = 0x8006


class FoeNoUser(FoeAbort):
    """FoE error 0x8007: no user."""

    CODE = 0x8007


class FoeBootstrapOnly(FoeAbort):
    """FoE error 0x8008: allowed in BOOT (bootstrap) state only."""

    CODE = 0x8008


class FoeNotInBootstrap(FoeAbort):
    """FoE error 0x8009: not allowed in BOOT (bootstrap) state."""

    CODE = 0x8009


class FoeNoRights(FoeAbort):
    """FoE error 0x800A: no rights (wrong password)."""

    CODE = 0x800A


class FoeProgramError(FoeAbort):
    """FoE error 0x800B: program error (the slave failed to store the file)."""

    CODE = 0x800B


class FoeChecksumError(FoeAbort):
    """FoE error 0x800C: checksum error (a firmware image failed its check)."""

    CODE = 0x800C


_FOE_CLASSES: dict[int, type[FoeAbort]] = {
    c.CODE: c for c in (FoeNotDefined, FoeNotFound, FoeAccessDenied, FoeDiskFull, FoeIllegal,
                        FoePacketNumberWrong, FoeAlreadyExists, FoeNoUser, FoeBootstrapOnly,
                        FoeNotInBootstrap, FoeNoRights, FoeProgramError, FoeChecksumError)
    if c.CODE is not None}


class SoeAbort(MailboxError):
    """An SoE service failed: the drive answered with the error bit and an SoE error code."""

    def __init__(self, code: int, name: str, idn: str = "", drive: int = 0) -> None:
        self.code = code
        self.name = name
        self.idn = idn
        self.drive = drive
        where = f" at {idn}" if idn else ""
        super().__init__(f"SoE error 0x{code:04X}{where} (drive {drive}): {name}")


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


class LinkDownError(LinkError):
    """The link is down for now (interface down, no carrier, segment unreachable).

    Not final: the same link works again once the medium is back.
    """


# --- master runtime errors -----------------------------------------------------


class EngineDiedError(LinkClosedError):
    """The isolated cyclic engine's process ended without being asked to (killed, crashed):
    no process data is exchanged any more; every access says so until the runner is stopped."""


class TimeoutError(EtherCATError, builtins.TimeoutError):  # noqa: A001 - deliberate name
    """No (valid) reply arrived in time."""


class WorkingCounterError(EtherCATError):
    """A datagram came back with an unexpected working counter."""

    def __init__(self, message: str, expected: int, actual: int) -> None:
        self.expected = expected
        self.actual = actual
        super().__init__(f"{message}: working counter {actual}, expected {expected}")


class AlStatusError(EtherCATError):
    """A slave refused or left a requested AL state; carries the AL status code.

    :meth:`for_code` gives the subclass of the codes that have one (the
    bootstrap refusals 0x0013 and 0x0015).
    """

    def __init__(self, message: str, code: int, code_name: str) -> None:
        self.code = code
        self.code_name = code_name
        super().__init__(f"{message}: AL status code 0x{code:04X} ({code_name})")

    @classmethod
    def for_code(cls, message: str, code: int, code_name: str) -> AlStatusError:
        """An :class:`AlStatusError`, of the code's own subclass where there is one."""
        sub: type[AlStatusError] = {0x0013: BootstrapNotSupportedError,
                                    0x0015: BootMailboxConfigError}.get(code, AlStatusError)
        return sub(message, code, code_name)


class FoeTimeoutError(TimeoutError):
    """An FoE packet was not answered within its time-out (the transfer is abandoned)."""


class SoeTimeoutError(TimeoutError):
    """An SoE request was not answered in time."""


class BootstrapNotSupportedError(AlStatusError):
    """The slave refused BOOT: AL status code 0x0013, bootstrap not supported."""


class BootMailboxConfigError(AlStatusError):
    """The slave refused BOOT: AL status code 0x0015, invalid mailbox configuration (BOOT)."""


class StateTimeoutError(TimeoutError):
    """Slaves did not reach a requested state in time."""


class TopologyMismatchError(ConfigError):
    """The scanned network does not match the expected configuration."""


class DriveError(EtherCATError):
    """A CiA 402 drive did not do what it was asked (``pyethercat.master.cia402``)."""


class DriveTimeoutError(DriveError, TimeoutError):
    """A drive did not reach a state, mode or target in time."""


class DriveFaultError(DriveError):
    """A drive went to Fault while it was asked to do something; ``code`` is its 0x603F."""

    def __init__(self, message: str, code: int | None = None) -> None:
        self.code = code
        super().__init__(message)
