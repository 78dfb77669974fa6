"""SoE services as state machines, and the encodings of an IDN's elements.

Read: one request (opcode 1) with the element flags and the IDN; the drive
answers with read responses (opcode 2), fragmented when the data does not fit
one mailbox (incomplete bit set, fragments-left in the IDN field; the last
fragment carries the IDN). Write: the data goes in write requests (opcode 3),
fragmented the same way; the drive answers once, after the last fragment
(opcode 4). An answer with the error bit carries an SoE error code. (SOEM
``src/ec_soe.c`` ``ecx_SoEread``/``ecx_SoEwrite``, IgH ``master/fsm_soe.c``.)

Elements (IEC 61800-7-204 parameter structure; SOEM ``include/soem/ec_soe.h``):
data state u16, name and unit as text lists, the attribute u32
(:class:`SoeAttribute`), minimum/maximum/value/default in the length the
attribute gives, or as a list (current length u16, maximum length u16, data).
Several element flags in one request are answered in flag order.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from pyethercat.errors import MailboxError, SoeAbort, SoeTimeoutError
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE
from pyethercat.wire.mailbox.soe import (
    SOE_HEADER_SIZE,
    SoeElement,
    SoeMessage,
    SoeOpCode,
    SoeReassembler,
    format_idn,
    soe_error_name,
    soe_write_fragments,
)

__all__ = [
    "DEFAULT_SOE_TIMEOUT",
    "SoeAttribute",
    "SoeDataType",
    "SoeReadClient",
    "SoeWriteClient",
    "decode_soe_list",
    "decode_soe_text",
    "encode_soe_list",
    "encode_soe_text",
    "soe_abort",
    "soe_error_response",
    "soe_read_response_fragments",
]

#: Seconds an SoE service may take (IgH's EC_SOE_RESPONSE_TIMEOUT is 1 s per answer).
DEFAULT_SOE_TIMEOUT = 1.0


class SoeDataType(IntEnum):
    """Data type of an IDN (attribute bits 22:20)."""

    BINARY = 0
    UNSIGNED = 1
    SIGNED = 2
    HEX = 3
    STRING = 4
    IDN = 5
    FLOAT = 6
    PARAMETER = 7


@dataclass(frozen=True, slots=True)
class SoeAttribute:
    """The attribute element (u32) of an IDN.

    ``length`` is the size of one value in bytes (1, 2, 4 or 8; of one list
    element when ``is_list``); ``write_protected`` says in which of PRE-OP,
    SAFE-OP and OP writing the value is refused.
    """

    length: int = 2
    data_type: SoeDataType = SoeDataType.UNSIGNED
    is_list: bool = False
    command: bool = False
    conversion_factor: int = 1
    decimals: int = 0
    write_protected_preop: bool = False
    write_protected_safeop: bool = False
    write_protected_op: bool = False

    _LENGTHS = {1: 0, 2: 1, 4: 2, 8: 3}

    def __post_init__(self) -> None:
        if self.length not in self._LENGTHS:
            raise MailboxError(f"SoE attribute length {self.length} is not 1, 2, 4 or 8")
        if not 0 <= self.conversion_factor <= 0xFFFF or not 0 <= self.decimals <= 15:
            raise MailboxError("SoE attribute conversion factor or decimals out of range")

    def encode(self) -> bytes:
        """The 4 attribute bytes."""
        word = (self.conversion_factor | self._LENGTHS[self.length] << 16
                | int(self.is_list) << 18 | int(self.command) << 19
                | int(self.data_type) << 20 | self.decimals << 24
                | int(self.write_protected_preop) << 28 | int(self.write_protected_safeop) << 29
                | int(self.write_protected_op) << 30)
        return struct.pack("<I", word)

    @classmethod
    def decode(cls, raw: bytes) -> SoeAttribute:
        """Parse 4 attribute bytes."""
        if len(raw) < 4:
            raise MailboxError(f"SoE attribute needs 4 bytes, got {len(raw)}")
        (w,) = struct.unpack_from("<I", raw, 0)
        return cls(1 << ((w >> 16) & 3), SoeDataType((w >> 20) & 7), bool(w >> 18 & 1),
                   bool(w >> 19 & 1), w & 0xFFFF, (w >> 24) & 0xF, bool(w >> 28 & 1),
                   bool(w >> 29 & 1), bool(w >> 30 & 1))


def encode_soe_list(data: bytes, max_length: int | None = None) -> bytes:
    """A list element: current length u16, maximum length u16 (bytes), then the data."""
    cap = len(data) if max_length is None else max_length
    if not len(data) <= cap <= 0xFFFF:
        raise MailboxError(f"SoE list of {len(data)} bytes does not fit maximum {cap}")
    return struct.pack("<HH", len(data), cap) + bytes(data)


def decode_soe_list(raw: bytes) -> tuple[bytes, int]:
    """(data, maximum length) of a list element; refuses a current length past the end."""
    if len(raw) < 4:
        raise MailboxError(f"SoE list needs 4 bytes of lengths, got {len(raw)}")
    cur, cap = struct.unpack_from("<HH", raw, 0)
    if 4 + cur > len(raw):
        raise MailboxError(f"SoE list says {cur} bytes, {len(raw) - 4} follow")
    return bytes(raw[4:4 + cur]), cap


def encode_soe_text(text: str, max_length: int | None = None) -> bytes:
    """A text element (name, unit): a list of characters."""
    return encode_soe_list(text.encode("latin-1", errors="replace"), max_length)


def decode_soe_text(raw: bytes) -> str:
    """The characters of a text element."""
    data, _cap = decode_soe_list(raw)
    return data.decode("latin-1")


def soe_abort(code: int, idn: int, drive: int = 0) -> SoeAbort:
    """The typed error for SoE error ``code`` at ``idn``."""
    return SoeAbort(code, soe_error_name(code), format_idn(idn), drive)


def soe_error_response(opcode: int, idn: int, code: int, *, drive: int = 0,
                       elements: int = SoeElement.VALUE) -> SoeMessage:
    """The answer of a drive refusing a request: the response opcode with the error bit."""
    return SoeMessage(opcode, idn, elements, drive, False, code, b"")


def soe_read_response_fragments(idn: int, data: bytes, mailbox_size: int, *, drive: int = 0,
                                elements: int = SoeElement.VALUE) -> list[SoeMessage]:
    """Read responses carrying ``data`` for a send mailbox of ``mailbox_size`` bytes."""
    return [SoeMessage(SoeOpCode.READ_RESPONSE, m.idn, m.elements, m.drive, m.incomplete, None,
                       m.data)
            for m in soe_write_fragments(idn, data, mailbox_size, drive=drive,
                                         elements=elements)]


def soe_fragment_room(mailbox_size: int) -> int:
    """Data bytes one SoE frame carries in a mailbox of ``mailbox_size`` bytes."""
    return mailbox_size - MAILBOX_HEADER_SIZE - SOE_HEADER_SIZE


class _SoeClient:
    def __init__(self, idn: int, elements: int, drive: int, timeout: float) -> None:
        if not 0 <= idn <= 0xFFFF or not 0 <= elements <= 0xFF or not 0 <= drive <= 7:
            raise MailboxError(f"SoE request out of range (IDN {idn}, elements {elements}, "
                               f"drive {drive})")
        self.idn = idn
        self.elements = elements
        self.drive = drive
        self.timeout = timeout
        self.deadline: float | None = None
        self.done = False

    def check_deadline(self, now: float) -> None:
        """Raise :class:`SoeTimeoutError` once the service took longer than ``timeout``."""
        if self.done or self.deadline is None or now < self.deadline:
            return
        self.done = True
        raise SoeTimeoutError(f"SoE {format_idn(self.idn)} (drive {self.drive}): no answer "
                              f"within {self.timeout:g} s")

    def _check_reply(self, msg: SoeMessage, opcode: int) -> None:
        if self.done:
            raise MailboxError("SoE service already finished")
        if msg.error_code is not None:
            self.done = True
            raise soe_abort(msg.error_code, self.idn, self.drive)
        if msg.opcode != opcode or msg.drive != self.drive:
            self.done = True
            raise MailboxError(f"SoE {format_idn(self.idn)}: unexpected answer (opcode "
                               f"{msg.opcode}, drive {msg.drive})")


class SoeReadClient(_SoeClient):
    """Master side of reading elements of an IDN: ``start`` then ``receive`` each frame."""

    def __init__(self, idn: int, *, elements: int = SoeElement.VALUE, drive: int = 0,
                 timeout: float = DEFAULT_SOE_TIMEOUT) -> None:
        super().__init__(idn, elements, drive, timeout)
        self._reasm = SoeReassembler()
        self.data = b""

    def start(self, now: float) -> SoeMessage:
        """The read request."""
        self.deadline = now + self.timeout
        return SoeMessage(SoeOpCode.READ_REQUEST, self.idn, self.elements, self.drive)

    def receive(self, msg: SoeMessage, now: float) -> None:
        """One read response (fragment); ``done`` and ``data`` once complete."""
        self._check_reply(msg, SoeOpCode.READ_RESPONSE)
        try:
            whole = self._reasm.feed(msg)
        except MailboxError:
            self.done = True
            raise
        if whole is None:
            self.deadline = now + self.timeout
            return
        if whole.idn != self.idn:
            self.done = True
            raise MailboxError(f"SoE read of {format_idn(self.idn)} answered for "
                               f"{format_idn(whole.idn)}")
        self.data = whole.data
        self.done = True


class SoeWriteClient(_SoeClient):
    """Master side of writing an element of an IDN.

    ``requests`` are the fragments to send one after the other (the drive
    answers none but the last); ``receive`` takes that answer.
    """

    def __init__(self, idn: int, data: bytes, *, mailbox_size: int,
                 elements: int = SoeElement.VALUE, drive: int = 0,
                 timeout: float = DEFAULT_SOE_TIMEOUT) -> None:
        super().__init__(idn, elements, drive, timeout)
        self.requests = soe_write_fragments(idn, bytes(data), mailbox_size, drive=drive,
                                            elements=elements)

    def start(self, now: float) -> list[SoeMessage]:
        """The write requests (all fragments); the deadline runs from the last one."""
        self.deadline = now + self.timeout
        return self.requests

    def receive(self, msg: SoeMessage, now: float) -> None:
        """The drive's answer to the last fragment."""
        self._check_reply(msg, SoeOpCode.WRITE_RESPONSE)
        if msg.idn != self.idn:
            self.done = True
            raise MailboxError(f"SoE write of {format_idn(self.idn)} answered for "
                               f"{format_idn(msg.idn)}")
        self.done = True
