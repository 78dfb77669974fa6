"""SoE (Servo drive profile over EtherCAT, mailbox type 5) codecs.

Layout as SOEM ``include/soem/ec_soe.h``, IgH ``master/fsm_soe.c`` and Wireshark
``packet-ecatmb.h`` (``SoeHeaderControlUnion``) have it; IDN meanings from IEC 61800-7-204.

Header (4 bytes after the mailbox header)::

    0  bits 2:0 opcode, bit 3 incomplete, bit 4 error, bits 7:5 drive number
    1  element flags (data state, name, attribute, unit, min, max, value, default)
    2  u16 IDN, or fragments left while incomplete = 1

With the error bit set, a u16 SoE error code follows the header.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.fragments import FragmentReassembler
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    "SOE_HEADER_SIZE",
    "SoeOpCode",
    "SoeElement",
    "SOE_ERROR_NAMES",
    "soe_error_name",
    "SoeMessage",
    "decode_soe",
    "parse_idn",
    "format_idn",
    "soe_write_fragments",
    "SoeReassembler",
]

SOE_HEADER_SIZE = 4
_HDR = struct.Struct("<BBH")


class SoeOpCode(IntEnum):
    """SoE opcodes."""

    READ_REQUEST = 1
    READ_RESPONSE = 2
    WRITE_REQUEST = 3
    WRITE_RESPONSE = 4
    NOTIFICATION = 5
    EMERGENCY = 6
    SLAVE_INFO = 7  # unverified in public code; named so it decodes


class SoeElement(IntFlag):
    """Element flags (header byte 1): which parts of an IDN are addressed."""

    DATA_STATE = 0x01
    NAME = 0x02
    ATTRIBUTE = 0x04
    UNIT = 0x08
    MINIMUM = 0x10
    MAXIMUM = 0x20
    VALUE = 0x40
    DEFAULT = 0x80


SOE_ERROR_NAMES: dict[int, str] = {
    0x0000: "no error",
    0x1001: "no IDN",
    0x1009: "invalid access to element 1",
    0x2001: "no name",
    0x2002: "name transmission too short",
    0x2003: "name transmission too long",
    0x2004: "name cannot be changed (read only)",
    0x2005: "name is write-protected at this time",
    0x3002: "attribute transmission too short",
    0x3003: "attribute transmission too long",
    0x3004: "attribute cannot be changed (read only)",
    0x3005: "attribute is write-protected at this time",
    0x4001: "no unit",
    0x4002: "unit transmission too short",
    0x4003: "unit transmission too long",
    0x4004: "unit cannot be changed (read only)",
    0x4005: "unit is write-protected at this time",
    0x5001: "no minimum input value",
    0x5002: "minimum input value transmission too short",
    0x5003: "minimum input value transmission too long",
    0x5004: "minimum input value cannot be changed (read only)",
    0x5005: "minimum input value is write-protected at this time",
    0x6001: "no maximum input value",
    0x6002: "maximum input value transmission too short",
    0x6003: "maximum input value transmission too long",
    0x6004: "maximum input value cannot be changed (read only)",
    0x6005: "maximum input value is write-protected at this time",
    0x7002: "operation data transmission too short",
    0x7003: "operation data transmission too long",
    0x7004: "operation data cannot be changed (read only)",
    0x7005: "operation data is write-protected at this time",
    0x7006: "operation data is smaller than the minimum input value",
    0x7007: "operation data is greater than the maximum input value",
    0x7008: "invalid operation data: configured IDN not supported",
    0x7009: "operation data write-protected by a password",
    0x700A: "operation data is write-protected (configured cyclically)",
    0x700B: "invalid indirect addressing",
    0x700C: "operation data is write-protected due to other settings",
    0x700D: "reserved",
    0x7010: "procedure command already active",
    0x7011: "procedure command not interruptible",
    0x7012: "procedure command not executable at this time",
    0x7013: "procedure command not executable (invalid or false parameters)",
    0x7014: "no data state",
    0x8001: "no default value",
    0x8002: "default value transmission too long",
    0x8004: "default value cannot be changed (read only)",
    0x800A: "invalid drive number",
    0x800B: "general error",
    0x800C: "no element addressed",
}


def soe_error_name(code: int) -> str:
    """Name of an SoE error code."""
    return SOE_ERROR_NAMES.get(code, f"unknown SoE error 0x{code:04X}")


_IDN_RE = re.compile(r"^\s*([SP])-([0-7])-(\d{1,4})\s*$", re.IGNORECASE)


def parse_idn(text: str) -> int:
    """``"S-0-0024"`` -> 0x0018, ``"P-0-0001"`` -> 0x8001; also accepts plain numbers.

    Raises :class:`MailboxError` for text that is not an IDN.
    """
    m = _IDN_RE.match(text)
    if m:
        block = int(m.group(3))
        if block > 4095:
            raise MailboxError(f"IDN {text!r}: data block {block} > 4095")
        return (0x8000 if m.group(1).upper() == "P" else 0) | (int(m.group(2)) << 12) | block
    try:
        value = int(text.strip(), 0)
    except ValueError:
        raise MailboxError(f"{text!r} is not an IDN (expected S-x-nnnn or P-x-nnnn)") from None
    if not 0 <= value <= 0xFFFF:
        raise MailboxError(f"IDN {value} out of range 0..0xFFFF")
    return value


def format_idn(idn: int) -> str:
    """0x0018 -> ``"S-0-0024"``; 0x8001 -> ``"P-0-0001"``."""
    if not 0 <= idn <= 0xFFFF:
        raise MailboxError(f"IDN {idn} out of range 0..0xFFFF")
    kind = "P" if idn & 0x8000 else "S"
    return f"{kind}-{(idn >> 12) & 7}-{idn & 0xFFF:04d}"


@dataclass(frozen=True, slots=True)
class SoeMessage:
    """One SoE frame.

    ``idn`` holds the IDN, or the number of fragments left when ``incomplete``.
    ``error_code`` is not None exactly when the error bit is set.
    """

    opcode: int
    idn: int = 0
    elements: int = SoeElement.VALUE
    drive: int = 0
    incomplete: bool = False
    error_code: int | None = None
    data: bytes = b""

    def __post_init__(self) -> None:
        for what, value, maximum in (
            ("opcode", self.opcode, 7),
            ("IDN", self.idn, 0xFFFF),
            ("elements", self.elements, 0xFF),
            ("drive number", self.drive, 7),
        ):
            if not 0 <= value <= maximum:
                raise MailboxError(f"SoE {what} {value} out of range 0..{maximum}")
        if self.error_code is not None and not 0 <= self.error_code <= 0xFFFF:
            raise MailboxError(f"SoE error code {self.error_code} out of range")
        object.__setattr__(self, "data", bytes(self.data))

    @property
    def fragments_left(self) -> int:
        """Fragments still to come (meaningful while ``incomplete``)."""
        return self.idn if self.incomplete else 0

    @property
    def idn_text(self) -> str:
        """The IDN as S-x-nnnn / P-x-nnnn."""
        return format_idn(self.idn)

    @property
    def error_name(self) -> str | None:
        """Name of the error code, if any."""
        return None if self.error_code is None else soe_error_name(self.error_code)

    def encode(self) -> bytes:
        """SoE header (+ error code) + data."""
        b0 = (
            self.opcode
            | (0x08 if self.incomplete else 0)
            | (0x10 if self.error_code is not None else 0)
            | (self.drive << 5)
        )
        out = _HDR.pack(b0, self.elements, self.idn)
        if self.error_code is not None:
            out += struct.pack("<H", self.error_code)
        return out + self.data


def decode_soe(payload: bytes | bytearray | memoryview) -> SoeMessage:
    """Typed message from an SoE mailbox payload; raises :class:`MailboxError`."""
    payload = bytes(payload)
    if len(payload) < SOE_HEADER_SIZE:
        raise MailboxError(f"SoE header needs {SOE_HEADER_SIZE} bytes, got {len(payload)}")
    b0, elements, idn = _HDR.unpack_from(payload, 0)
    opcode = b0 & 7
    if opcode == 0:
        raise MailboxError("SoE opcode 0 is not defined")
    pos = SOE_HEADER_SIZE
    error: int | None = None
    if b0 & 0x10:
        if len(payload) < pos + 2:
            raise MailboxError("SoE frame with error bit set but no error code")
        error = struct.unpack_from("<H", payload, pos)[0]
        pos += 2
    return SoeMessage(opcode, idn, elements, b0 >> 5, bool(b0 & 0x08), error, payload[pos:])


def soe_write_fragments(
    idn: int,
    data: bytes,
    mailbox_size: int,
    *,
    drive: int = 0,
    elements: int = SoeElement.VALUE,
) -> list[SoeMessage]:
    """Write requests carrying ``data``, fragmented for a mailbox of ``mailbox_size``.

    Every fragment but the last has incomplete = 1 and fragments-left in the
    IDN field; the last carries the IDN (as IgH does).
    """
    room = mailbox_size - MAILBOX_HEADER_SIZE - SOE_HEADER_SIZE
    if room < 1:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for SoE")
    data = bytes(data)
    chunks = [data[i : i + room] for i in range(0, len(data), room)] or [b""]
    n = len(chunks)
    if n - 1 > 0xFFFF:
        raise MailboxError("SoE write needs too many fragments")
    return [
        SoeMessage(
            SoeOpCode.WRITE_REQUEST,
            idn if i == n - 1 else n - 1 - i,
            elements,
            drive,
            i < n - 1,
            None,
            chunk,
        )
        for i, chunk in enumerate(chunks)
    ]


class SoeReassembler:
    """Join fragmented SoE frames (read responses or write requests); pure.

    ``feed(msg)`` returns the complete message (last fragment's header, all
    data) or ``None`` while fragments are outstanding. A frame with the error
    bit ends the transfer and is returned as is. Opcode changes or a
    fragments-left count that does not decrease raise :class:`MailboxError`
    (the rules are :class:`~pyethercat.wire.mailbox.fragments.FragmentReassembler`'s).
    """

    def __init__(self) -> None:
        self._core = FragmentReassembler("SoE fragment", key_name="opcode",
                                         sequence_name="fragments-left", step=-1, strict=False)

    @property
    def in_progress(self) -> bool:
        """True while fragments are outstanding."""
        return self._core.in_progress

    def reset(self) -> None:
        """Forget a partial message."""
        self._core.reset()

    def feed(self, msg: SoeMessage) -> SoeMessage | None:
        """Add one frame."""
        if msg.error_code is not None:
            self.reset()
            return msg
        # the last fragment carries the IDN where the others count down
        data = self._core.feed(msg.data, key=msg.opcode, last=not msg.incomplete,
                               sequence=msg.fragments_left if msg.incomplete else None)
        if data is None:
            return None
        return SoeMessage(msg.opcode, msg.idn, msg.elements, msg.drive, False, None, data)
