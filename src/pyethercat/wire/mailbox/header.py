"""Mailbox header (6 bytes), mailbox types, error replies and counters.

Layout (all little-endian; Wireshark ``packet-ecatmb.h`` ``ETHERCAT_MBOX_HEADER``,
SOES ``soes/esc.h`` ``_MBXh``)::

    0  u16  length    bytes after this header
    2  u16  address   originator (master -> slave) / destination (slave -> master)
    4  bits 5:0 channel, bits 7:6 priority
    5  bits 3:0 type, bits 6:4 counter, bit 7 reserved

The mailbox is written into SM0 (and read from SM1) as a whole: the frame is
padded to the SyncManager length, because the ESC only flips the buffer state
when the last byte of the area is accessed.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from pyethercat.errors import MailboxError, MailboxErrorReply

__all__ = [
    "MAILBOX_HEADER_SIZE",
    "MAILBOX_ERROR_NAMES",
    "MAILBOX_ERROR_SERVICE",
    "MailboxType",
    "MailboxHeader",
    "MailboxErrorCode",
    "mailbox_error_name",
    "encode_mailbox",
    "decode_mailbox",
    "pad_mailbox",
    "encode_mailbox_error",
    "decode_mailbox_error",
    "next_counter",
    "is_repeated_counter",
]

MAILBOX_HEADER_SIZE = 6
"""Size of the mailbox header in bytes."""

MAILBOX_ERROR_SERVICE = 0x0001
"""First u16 of a type-0 (error reply) body: 'mailbox command'."""

_HDR = struct.Struct("<HHBB")


class MailboxType(IntEnum):
    """Mailbox protocol (header byte 5, bits 3:0)."""

    ERR = 0x0
    AOE = 0x1
    EOE = 0x2
    COE = 0x3
    FOE = 0x4
    SOE = 0x5
    VOE = 0xF
    # Mixed-case aliases, as the protocols are usually spelled.
    AoE = 0x1
    EoE = 0x2
    CoE = 0x3
    FoE = 0x4
    SoE = 0x5
    VoE = 0xF


class MailboxErrorCode(IntEnum):
    """Detail code of a mailbox error reply (type 0; SOES ``soes/esc.h`` ``MBXERR_*``)."""

    SYNTAX = 0x0001
    UNSUPPORTED_PROTOCOL = 0x0002
    INVALID_CHANNEL = 0x0003
    SERVICE_NOT_SUPPORTED = 0x0004
    INVALID_HEADER = 0x0005
    SIZE_TOO_SHORT = 0x0006
    NO_MORE_MEMORY = 0x0007
    INVALID_SIZE = 0x0008
    SERVICE_IN_WORK = 0x0009  # KickCAT only; kept so such replies get a name


MAILBOX_ERROR_NAMES: dict[int, str] = {
    MailboxErrorCode.SYNTAX: "syntax of the mailbox header is wrong",
    MailboxErrorCode.UNSUPPORTED_PROTOCOL: "mailbox protocol not supported",
    MailboxErrorCode.INVALID_CHANNEL: "mailbox channel invalid",
    MailboxErrorCode.SERVICE_NOT_SUPPORTED: "service in mailbox protocol not supported",
    MailboxErrorCode.INVALID_HEADER: "invalid mailbox protocol header",
    MailboxErrorCode.SIZE_TOO_SHORT: "received mailbox data too short",
    MailboxErrorCode.NO_MORE_MEMORY: "slave out of memory for the mailbox service",
    MailboxErrorCode.INVALID_SIZE: "mailbox data length inconsistent",
    MailboxErrorCode.SERVICE_IN_WORK: "mailbox service in work",
}


def mailbox_error_name(code: int) -> str:
    """Human-readable name of a mailbox error code (unknown codes say so)."""
    return MAILBOX_ERROR_NAMES.get(code, f"unknown mailbox error 0x{code:04X}")


@dataclass(frozen=True, slots=True)
class MailboxHeader:
    """The 6-byte mailbox header.

    ``type`` is a :class:`MailboxType` when the value is a known protocol and a
    plain int otherwise (a slave must be able to answer "unsupported protocol",
    so unknown types decode rather than fail).
    """

    length: int
    type: MailboxType | int
    counter: int = 0
    address: int = 0
    channel: int = 0
    priority: int = 0
    reserved: int = 0

    def __post_init__(self) -> None:
        _check_range("length", self.length, 0xFFFF)
        _check_range("address", self.address, 0xFFFF)
        _check_range("channel", self.channel, 0x3F)
        _check_range("priority", self.priority, 0x3)
        _check_range("type", int(self.type), 0xF)
        _check_range("counter", self.counter, 0x7)
        _check_range("reserved", self.reserved, 0x1)

    def encode(self) -> bytes:
        """The 6 header bytes."""
        return _HDR.pack(
            self.length,
            self.address,
            self.channel | (self.priority << 6),
            int(self.type) | (self.counter << 4) | (self.reserved << 7),
        )

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> MailboxHeader:
        """Parse the first 6 bytes of ``data``; raises :class:`MailboxError` if short."""
        if len(data) < MAILBOX_HEADER_SIZE:
            raise MailboxError(f"mailbox header needs {MAILBOX_HEADER_SIZE} bytes, got {len(data)}")
        length, address, b4, b5 = _HDR.unpack_from(data, 0)
        # Every field comes out of a bit mask, so it is in range: skip the checks of
        # __post_init__ (this runs for every mailbox message, on both sides).
        hdr = object.__new__(cls)
        _set = object.__setattr__
        _set(hdr, "length", length)
        _set(hdr, "type", _TYPES.get(b5 & 0x0F, b5 & 0x0F))
        _set(hdr, "counter", (b5 >> 4) & 0x7)
        _set(hdr, "address", address)
        _set(hdr, "channel", b4 & 0x3F)
        _set(hdr, "priority", b4 >> 6)
        _set(hdr, "reserved", b5 >> 7)
        return hdr


#: Known mailbox types by value (a dict look-up is cheaper than the enum call).
_TYPES: dict[int, MailboxType | int] = {t.value: t for t in MailboxType}


def _check_range(name: str, value: int, maximum: int) -> None:
    if not 0 <= value <= maximum:
        raise MailboxError(f"mailbox header {name} {value} out of range 0..{maximum}")


def pad_mailbox(frame: bytes | bytearray, size: int) -> bytes:
    """Pad ``frame`` with zeros to ``size`` bytes (the SM length).

    Raises :class:`MailboxError` if the frame does not fit.
    """
    if len(frame) > size:
        raise MailboxError(
            f"mailbox of {len(frame)} bytes does not fit the {size}-byte SyncManager"
        )
    return bytes(frame) + bytes(size - len(frame))


def encode_mailbox(
    mtype: MailboxType | int,
    payload: bytes | bytearray,
    *,
    counter: int = 0,
    address: int = 0,
    channel: int = 0,
    priority: int = 0,
    size: int | None = None,
) -> bytes:
    """Header + ``payload``, padded to ``size`` (the SM length) when given."""
    length = len(payload)
    kind = int(mtype)
    if not (length <= 0xFFFF and 0 <= address <= 0xFFFF and 0 <= channel <= 0x3F
            and 0 <= priority <= 0x3 and 0 <= kind <= 0xF and 0 <= counter <= 0x7):
        # Out of range: the header's own checks name the field.
        MailboxHeader(length=length, type=mtype, counter=counter, address=address,
                      channel=channel, priority=priority)
    # (packed directly, as MailboxHeader.encode does: every mailbox message passes here)
    frame = _HDR.pack(length, address, channel | (priority << 6), kind | (counter << 4)
                      ) + bytes(payload)
    if size is not None:
        return pad_mailbox(frame, size)
    return frame


def decode_mailbox(data: bytes | bytearray | memoryview) -> tuple[MailboxHeader, bytes]:
    """Split a mailbox buffer (possibly padded to the SM length) into header and payload.

    The payload is exactly ``header.length`` bytes; raises :class:`MailboxError`
    when the length word points past the end of ``data``.
    """
    header = MailboxHeader.decode(data)
    end = MAILBOX_HEADER_SIZE + header.length
    if end > len(data):
        raise MailboxError(
            f"mailbox length {header.length} exceeds the {len(data) - MAILBOX_HEADER_SIZE}"
            " data bytes present"
        )
    return header, bytes(data[MAILBOX_HEADER_SIZE:end])


def encode_mailbox_error(code: int) -> bytes:
    """Payload (4 bytes) of a mailbox error reply carrying ``code``."""
    if not 0 <= code <= 0xFFFF:
        raise MailboxError(f"mailbox error code {code} out of range")
    return struct.pack("<HH", MAILBOX_ERROR_SERVICE, code)


def decode_mailbox_error(payload: bytes | bytearray | memoryview) -> MailboxErrorReply:
    """Turn the payload of a type-0 mailbox into a :class:`MailboxErrorReply`.

    The exception is returned, not raised: the caller decides (a master raises
    it, a diagnostic tool prints it).
    """
    if len(payload) < 4:
        raise MailboxError(f"mailbox error reply needs 4 bytes, got {len(payload)}")
    _service, code = struct.unpack_from("<HH", payload, 0)
    return MailboxErrorReply(code, mailbox_error_name(code))


def next_counter(counter: int) -> int:
    """The mailbox counter after ``counter``: 1..7 then 1 again; 0 (unused) -> 1."""
    if not 0 <= counter <= 7:
        raise MailboxError(f"mailbox counter {counter} out of range 0..7")
    return 1 if counter >= 7 else counter + 1


def is_repeated_counter(previous: int, counter: int) -> bool:
    """True when a received mailbox repeats the previous one (same non-zero counter)."""
    return counter != 0 and counter == previous
