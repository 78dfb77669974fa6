"""FoE (File access over EtherCAT, mailbox type 4) codecs.

Layout as Wireshark ``packet-ecatmb.h`` (``ETHERCAT_FOE_HEADER``), IgH
``master/fsm_foe.c`` and SOES ``soes/esc_foe.c`` have it.

Header (6 bytes after the mailbox header)::

    0  u8   opcode
    1  u8   reserved
    2  u32  RRQ/WRQ: password; DATA/ACK: packet number; ERR: error code;
            BUSY: done (u16) + entire (u16)
    6  ...  RRQ/WRQ: file name; DATA: file data; ERR/BUSY: optional text

``encode()`` returns the mailbox payload (FoE header first); :func:`decode_foe`
is the inverse.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar, TypeAlias

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    "FOE_HEADER_SIZE",
    "FoeOpCode",
    "FoeErrorCode",
    "FOE_ERROR_NAMES",
    "foe_error_name",
    "FoeReadRequest",
    "FoeWriteRequest",
    "FoeData",
    "FoeAck",
    "FoeError",
    "FoeBusy",
    "FoeMessage",
    "decode_foe",
    "foe_data_size",
    "foe_split",
    "foe_packet_matches",
]

FOE_HEADER_SIZE = 6
_HDR = struct.Struct("<BBI")


class FoeOpCode(IntEnum):
    """FoE opcodes."""

    RRQ = 1
    WRQ = 2
    DATA = 3
    ACK = 4
    ERR = 5
    BUSY = 6


class FoeErrorCode(IntEnum):
    """FoE error codes (SOES ``soes/esc.h`` ``FOE_ERR_*``; KickCAT ``FoE/protocol.h``)."""

    NOT_DEFINED = 0x8000
    NOT_FOUND = 0x8001
    ACCESS_DENIED = 0x8002
    DISK_FULL = 0x8003
    ILLEGAL = 0x8004
    PACKET_NUMBER_WRONG = 0x8005
    ALREADY_EXISTS = 0x8006
    NO_USER = 0x8007
    BOOTSTRAP_ONLY = 0x8008
    NOT_BOOTSTRAP = 0x8009
    NO_RIGHTS = 0x800A
    PROGRAM_ERROR = 0x800B
    CHECKSUM_ERROR = 0x800C


FOE_ERROR_NAMES: dict[int, str] = {
    FoeErrorCode.NOT_DEFINED: "not defined",
    FoeErrorCode.NOT_FOUND: "not found",
    FoeErrorCode.ACCESS_DENIED: "access denied",
    FoeErrorCode.DISK_FULL: "disk full",
    FoeErrorCode.ILLEGAL: "illegal",
    FoeErrorCode.PACKET_NUMBER_WRONG: "packet number wrong",
    FoeErrorCode.ALREADY_EXISTS: "already exists",
    FoeErrorCode.NO_USER: "no user",
    FoeErrorCode.BOOTSTRAP_ONLY: "bootstrap only",
    FoeErrorCode.NOT_BOOTSTRAP: "not in bootstrap",
    FoeErrorCode.NO_RIGHTS: "no rights",
    FoeErrorCode.PROGRAM_ERROR: "program error",
    FoeErrorCode.CHECKSUM_ERROR: "checksum error",
}


def foe_error_name(code: int) -> str:
    """Name of an FoE error code."""
    return FOE_ERROR_NAMES.get(code, f"unknown FoE error 0x{code:08X}")


def _check(what: str, value: int, maximum: int) -> None:
    if not 0 <= value <= maximum:
        raise MailboxError(f"FoE {what} {value} out of range 0..{maximum}")


def _name_bytes(name: str) -> bytes:
    return name.encode("utf-8")


def _name_text(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace")


@dataclass(frozen=True, slots=True)
class _FoeRequest:
    filename: str
    password: int = 0

    OPCODE: ClassVar[FoeOpCode] = FoeOpCode.RRQ

    def __post_init__(self) -> None:
        _check("password", self.password, 0xFFFFFFFF)

    def encode(self) -> bytes:
        """FoE header + file name (no terminator)."""
        return _HDR.pack(self.OPCODE, 0, self.password) + _name_bytes(self.filename)


@dataclass(frozen=True, slots=True)
class FoeReadRequest(_FoeRequest):
    """Master asks to read a file from the slave."""

    OPCODE: ClassVar[FoeOpCode] = FoeOpCode.RRQ


@dataclass(frozen=True, slots=True)
class FoeWriteRequest(_FoeRequest):
    """Master asks to write a file to the slave."""

    OPCODE: ClassVar[FoeOpCode] = FoeOpCode.WRQ


@dataclass(frozen=True, slots=True)
class FoeData:
    """One packet of file data (numbered from 1)."""

    packet: int
    data: bytes = b""

    def __post_init__(self) -> None:
        _check("packet number", self.packet, 0xFFFFFFFF)
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """FoE header + data."""
        return _HDR.pack(FoeOpCode.DATA, 0, self.packet) + self.data


@dataclass(frozen=True, slots=True)
class FoeAck:
    """Acknowledge a DATA packet (0 accepts a write request)."""

    packet: int

    def __post_init__(self) -> None:
        _check("packet number", self.packet, 0xFFFFFFFF)

    def encode(self) -> bytes:
        """FoE header only."""
        return _HDR.pack(FoeOpCode.ACK, 0, self.packet)


@dataclass(frozen=True, slots=True)
class FoeError:
    """Error: ends the transfer. ``text`` is optional."""

    code: int
    text: str = ""

    def __post_init__(self) -> None:
        _check("error code", self.code, 0xFFFFFFFF)

    @property
    def name(self) -> str:
        """Name of the error code."""
        return foe_error_name(self.code)

    def encode(self) -> bytes:
        """FoE header + text."""
        return _HDR.pack(FoeOpCode.ERR, 0, self.code) + _name_bytes(self.text)


@dataclass(frozen=True, slots=True)
class FoeBusy:
    """Slave not ready: resend. ``done``/``entire`` give progress."""

    done: int = 0
    entire: int = 0
    text: str = ""

    def __post_init__(self) -> None:
        _check("busy done", self.done, 0xFFFF)
        _check("busy entire", self.entire, 0xFFFF)

    def encode(self) -> bytes:
        """FoE header + optional text."""
        return struct.pack("<BBHH", FoeOpCode.BUSY, 0, self.done, self.entire) + _name_bytes(
            self.text
        )


FoeMessage: TypeAlias = FoeReadRequest | FoeWriteRequest | FoeData | FoeAck | FoeError | FoeBusy


def decode_foe(payload: bytes | bytearray | memoryview) -> FoeMessage:
    """Typed message from an FoE mailbox payload; raises :class:`MailboxError`."""
    payload = bytes(payload)
    if len(payload) < FOE_HEADER_SIZE:
        raise MailboxError(f"FoE header needs {FOE_HEADER_SIZE} bytes, got {len(payload)}")
    opcode, _reserved, word = _HDR.unpack_from(payload, 0)
    rest = payload[FOE_HEADER_SIZE:]
    if opcode == FoeOpCode.RRQ:
        return FoeReadRequest(_name_text(rest), word)
    if opcode == FoeOpCode.WRQ:
        return FoeWriteRequest(_name_text(rest), word)
    if opcode == FoeOpCode.DATA:
        # (the word is a u32 off the wire: in range; skip __post_init__, the hot path
        # of every packet on both sides)
        data = object.__new__(FoeData)
        object.__setattr__(data, "packet", word)
        object.__setattr__(data, "data", rest)
        return data
    if opcode == FoeOpCode.ACK:
        ack = object.__new__(FoeAck)
        object.__setattr__(ack, "packet", word)
        return ack
    if opcode == FoeOpCode.ERR:
        return FoeError(word, _name_text(rest))
    if opcode == FoeOpCode.BUSY:
        done, entire = struct.unpack_from("<HH", payload, 2)
        return FoeBusy(done, entire, _name_text(rest))
    raise MailboxError(f"unknown FoE opcode {opcode}")


def foe_data_size(mailbox_size: int) -> int:
    """File bytes in a full DATA packet for a mailbox of ``mailbox_size`` bytes."""
    size = mailbox_size - MAILBOX_HEADER_SIZE - FOE_HEADER_SIZE
    if size < 1:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for FoE")
    return size


def foe_split(data: bytes, mailbox_size: int, first_packet: int = 1) -> list[FoeData]:
    """The DATA packets that send ``data``: full packets, then a short last one.

    When the length is a multiple of the full size (or zero) a final empty
    packet marks the end, as IgH's sender does.
    """
    size = foe_data_size(mailbox_size)
    packets = [
        FoeData(first_packet + i, data[off : off + size])
        for i, off in enumerate(range(0, len(data), size))
    ]
    if len(data) % size == 0:
        packets.append(FoeData(first_packet + len(packets), b""))
    return packets


def foe_packet_matches(expected: int, received: int) -> bool:
    """``received`` (as on the wire) is packet ``expected``, in any width senders use.

    The field is a u32 (IgH, SOES), Wireshark and KickCAT read a u16, and
    devices in the field wrap at 256 (ribalda/ethercat issue 10): the number
    matches modulo 2^32, 2^16 or 2^8.
    """
    if received == expected:
        return True  # (the usual case, without the loop)
    return any(received == expected % m for m in _PACKET_WIDTHS)


_PACKET_WIDTHS = (1 << 32, 1 << 16, 1 << 8)
