"""SoE server of a simulated slave: a small servo drive profile of IDNs.

:class:`SoeProtocol` is a mailbox protocol server (type 5). It serves the
elements of the IDNs in a :class:`SoeParameters` table (data state, name,
attribute, unit, minimum, maximum, value, default), answers long values in
fragments, collects fragmented writes, and refuses with the SoE error codes
a drive gives (no IDN 0x1001, element missing 0x2001..0x8001, read-only
0x7004, write-protected in this state 0x7005, too short/long 0x7002/0x7003,
below minimum/above maximum 0x7006/0x7007, wrong drive number 0x800A).

:func:`drive_profile` is the profile the simulator's SoE drives carry
(IEC 61800-7-204 IDNs; SOEM ``ec_soe.c`` ``ecx_readIDNmap`` reads 16 and 24 to
size the process data): S-0-0001 control unit cycle time, S-0-0032/0033
operation modes, S-0-0036 velocity command, S-0-0047 position command,
S-0-0051 position feedback, S-0-0016/S-0-0024 the AT and MDT configuration
lists.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from pyethercat.errors import MailboxError
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType
from pyethercat.wire.mailbox.soe import (
    SoeElement,
    SoeMessage,
    SoeOpCode,
    SoeReassembler,
    decode_soe,
)
from pyethercat.wire.mailbox.soe_transfer import (
    SoeAttribute,
    SoeDataType,
    encode_soe_list,
    encode_soe_text,
    soe_error_response,
    soe_read_response_fragments,
)

__all__ = ["SoeParameter", "SoeParameters", "SoeProtocol", "drive_profile"]

# SoE error codes a drive answers with (SOEM src/ec_print.c ec_soeerrorlist, IgH
# master/soe_errors.c).
NO_IDN = 0x1001
NO_NAME = 0x2001
NAME_READ_ONLY = 0x2004
ATTRIBUTE_READ_ONLY = 0x3004
NO_UNIT = 0x4001
UNIT_READ_ONLY = 0x4004
NO_MINIMUM = 0x5001
MINIMUM_READ_ONLY = 0x5004
NO_MAXIMUM = 0x6001
MAXIMUM_READ_ONLY = 0x6004
TOO_SHORT = 0x7002
TOO_LONG = 0x7003
READ_ONLY = 0x7004
WRITE_PROTECTED_NOW = 0x7005
BELOW_MINIMUM = 0x7006
ABOVE_MAXIMUM = 0x7007
NO_DATA_STATE = 0x7014
NO_DEFAULT = 0x8001
DEFAULT_READ_ONLY = 0x8004
INVALID_DRIVE = 0x800A
NO_ELEMENT = 0x800C

_MISSING = {SoeElement.NAME: NO_NAME, SoeElement.UNIT: NO_UNIT, SoeElement.MINIMUM: NO_MINIMUM,
            SoeElement.MAXIMUM: NO_MAXIMUM, SoeElement.DEFAULT: NO_DEFAULT,
            SoeElement.DATA_STATE: NO_DATA_STATE}
_READ_ONLY_ELEMENT = {SoeElement.NAME: NAME_READ_ONLY, SoeElement.ATTRIBUTE: ATTRIBUTE_READ_ONLY,
                      SoeElement.UNIT: UNIT_READ_ONLY, SoeElement.MINIMUM: MINIMUM_READ_ONLY,
                      SoeElement.MAXIMUM: MAXIMUM_READ_ONLY, SoeElement.DEFAULT: DEFAULT_READ_ONLY}


@dataclass
class SoeParameter:
    """One IDN of a drive: its elements. ``value`` is the raw value (a list: its data)."""

    idn: int
    name: str
    attribute: SoeAttribute
    value: bytes
    unit: str | None = None
    minimum: bytes | None = None
    maximum: bytes | None = None
    default: bytes | None = None
    max_list_length: int = 0

    def _number(self, raw: bytes) -> int | float:
        a = self.attribute
        if a.data_type == SoeDataType.FLOAT and a.length in (4, 8):
            return float(struct.unpack("<f" if a.length == 4 else "<d", raw)[0])
        return int.from_bytes(raw, "little", signed=a.data_type == SoeDataType.SIGNED)

    def element(self, flag: int) -> bytes | None:
        """Encoded element ``flag`` (one bit), or None when the IDN has no such element."""
        a = self.attribute
        if flag == SoeElement.DATA_STATE:
            return None
        if flag == SoeElement.NAME:
            return encode_soe_text(self.name)
        if flag == SoeElement.ATTRIBUTE:
            return a.encode()
        if flag == SoeElement.UNIT:
            return None if self.unit is None else encode_soe_text(self.unit)
        raw = {SoeElement.MINIMUM: self.minimum, SoeElement.MAXIMUM: self.maximum,
               SoeElement.DEFAULT: self.default, SoeElement.VALUE: self.value}[SoeElement(flag)]
        if raw is None:
            return None
        if a.is_list:
            return encode_soe_list(raw, max(self.max_list_length, len(raw)))
        return raw

    def check_write(self, data: bytes, state: AlState) -> tuple[int, bytes]:
        """(error code or 0, the value to store) for writing ``data`` to the value."""
        a = self.attribute
        protected = {AlState.PREOP: a.write_protected_preop,
                     AlState.SAFEOP: a.write_protected_safeop, AlState.OP: a.write_protected_op}
        if all(protected.values()):
            return READ_ONLY, b""
        if protected.get(state, False):
            return WRITE_PROTECTED_NOW, b""
        if a.is_list:
            if len(data) < 4:
                return TOO_SHORT, b""
            cur = int.from_bytes(data[:2], "little")
            body = data[4:]
            if cur > len(body):
                return TOO_SHORT, b""
            if len(body) > cur or cur > max(self.max_list_length, len(self.value)):
                return TOO_LONG, b""
            return 0, body[:cur]
        if len(data) < a.length:
            return TOO_SHORT, b""
        if len(data) > a.length:
            return TOO_LONG, b""
        number = self._number(data)
        if self.minimum is not None and number < self._number(self.minimum):
            return BELOW_MINIMUM, b""
        if self.maximum is not None and number > self._number(self.maximum):
            return ABOVE_MAXIMUM, b""
        return 0, data


@dataclass
class SoeParameters:
    """The IDNs of one drive (of a slave's drive number)."""

    parameters: dict[int, SoeParameter] = field(default_factory=dict)

    def add(self, p: SoeParameter) -> SoeParameter:
        self.parameters[p.idn] = p
        return p

    def value(self, idn: int) -> bytes:
        return self.parameters[idn].value

    def set_value(self, idn: int, data: bytes) -> None:
        self.parameters[idn].value = bytes(data)


def _u(n: int, size: int) -> bytes:
    return n.to_bytes(size, "little")


def _s(n: int, size: int) -> bytes:
    return n.to_bytes(size, "little", signed=True)


def drive_profile() -> SoeParameters:
    """The SoE drive profile of the simulator (see the module text)."""
    u16 = SoeAttribute(2, SoeDataType.UNSIGNED, write_protected_safeop=True,
                       write_protected_op=True)
    s32 = SoeAttribute(4, SoeDataType.SIGNED, decimals=0)
    s32_ro = SoeAttribute(4, SoeDataType.SIGNED, write_protected_preop=True,
                          write_protected_safeop=True, write_protected_op=True)
    idn_list = SoeAttribute(2, SoeDataType.IDN, is_list=True, write_protected_safeop=True,
                            write_protected_op=True)
    p = SoeParameters()
    p.add(SoeParameter(1, "Control unit cycle time (TNcyc)", u16, _u(1000, 2), "us",
                       _u(125, 2), _u(65000, 2), _u(1000, 2)))
    p.add(SoeParameter(32, "Primary operation mode", u16, _u(0x000B, 2), None,
                       default=_u(0x000B, 2)))
    p.add(SoeParameter(33, "Secondary operation mode 1", u16, _u(0x0002, 2)))
    p.add(SoeParameter(36, "Velocity command value", s32, _s(0, 4), "rpm",
                       _s(-6000, 4), _s(6000, 4), _s(0, 4)))
    p.add(SoeParameter(47, "Position command value", s32, _s(0, 4), "Inc"))
    p.add(SoeParameter(51, "Position feedback value 1", s32_ro, _s(0, 4), "Inc"))
    p.add(SoeParameter(16, "Configuration list of the AT", idn_list, _u(51, 2), None,
                       max_list_length=256))
    p.add(SoeParameter(24, "Configuration list of the MDT", idn_list, _u(36, 2) + _u(47, 2),
                       None, max_list_length=256))
    return p


class SoeProtocol:
    """Mailbox protocol server for SoE (type 5) of one simulated slave.

    ``drives`` maps drive numbers (0-7) to their parameters. ``send(payload)``
    queues an SoE reply, ``state()`` reads the AL state, ``tx_size()`` the send
    mailbox length (for fragmenting answers).
    """

    type = MailboxType.SOE

    def __init__(self, send: Callable[[bytes], None], state: Callable[[], AlState],
                 tx_size: Callable[[], int], drives: dict[int, SoeParameters] | None = None,
                 on_write: Callable[[int, int], None] | None = None) -> None:
        self.drives = drives if drives is not None else {0: drive_profile()}
        self._send = send
        self._state = state
        self._tx_size = tx_size
        self._reasm = SoeReassembler()
        self.on_write = on_write
        #: Requests answered with an SoE error (code per request, newest last).
        self.errors: list[int] = []

    def reset(self) -> None:
        """The mailbox stopped: forget a fragmented write in progress."""
        self._reasm.reset()

    def on_state_change(self, old: AlState, new: AlState) -> None:
        """Nothing to do: the parameters keep their values through state changes."""

    def handle(self, header: MailboxHeader, payload: bytes) -> None:
        """Serve one SoE request (the mailbox engine calls this)."""
        msg = decode_soe(payload)
        if msg.opcode == SoeOpCode.READ_REQUEST:
            self._read(msg)
        elif msg.opcode == SoeOpCode.WRITE_REQUEST:
            try:
                whole = self._reasm.feed(msg)
            except MailboxError:
                self._error(SoeOpCode.WRITE_RESPONSE, msg, TOO_LONG)
                return
            if whole is not None:  # fragments get no answer (SOEM/IgH wait for the last)
                self._write(whole)
        else:
            raise MailboxError(f"SoE opcode {msg.opcode} is not a request")

    def _error(self, opcode: int, msg: SoeMessage, code: int) -> None:
        self.errors.append(code)
        self._send(soe_error_response(opcode, msg.idn, code, drive=msg.drive,
                                      elements=msg.elements).encode())

    def _parameter(self, opcode: int, msg: SoeMessage) -> SoeParameter | None:
        """The IDN a request addresses; None after answering that drive or IDN is missing."""
        drive = self.drives.get(msg.drive)
        if drive is None:
            self._error(opcode, msg, INVALID_DRIVE)
            return None
        param = drive.parameters.get(msg.idn)
        if param is None:
            self._error(opcode, msg, NO_IDN)
        return param

    def _read(self, msg: SoeMessage) -> None:
        param = self._parameter(SoeOpCode.READ_RESPONSE, msg)
        if param is None:
            return
        if not msg.elements:
            self._error(SoeOpCode.READ_RESPONSE, msg, NO_ELEMENT)
            return
        data = b""
        for bit in range(8):
            flag = 1 << bit
            if not msg.elements & flag:
                continue
            part = param.element(flag)
            if part is None:
                self._error(SoeOpCode.READ_RESPONSE, msg, _MISSING.get(SoeElement(flag), NO_ELEMENT))
                return
            data += part
        for frag in soe_read_response_fragments(msg.idn, data, self._tx_size(), drive=msg.drive,
                                                elements=msg.elements):
            self._send(frag.encode())

    def _write(self, msg: SoeMessage) -> None:
        param = self._parameter(SoeOpCode.WRITE_RESPONSE, msg)
        if param is None:
            return
        if msg.elements != SoeElement.VALUE:
            flag = msg.elements & -msg.elements  # lowest element addressed
            code = _READ_ONLY_ELEMENT.get(SoeElement(flag), NO_ELEMENT) if flag else NO_ELEMENT
            self._error(SoeOpCode.WRITE_RESPONSE, msg, code)
            return
        code, value = param.check_write(msg.data, self._state())
        if code:
            self._error(SoeOpCode.WRITE_RESPONSE, msg, code)
            return
        param.value = value
        if self.on_write is not None:
            self.on_write(msg.drive, msg.idn)
        self._send(SoeMessage(SoeOpCode.WRITE_RESPONSE, msg.idn, msg.elements,
                              msg.drive).encode())
