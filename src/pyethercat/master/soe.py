"""SoE client (master side): read and write IDN elements of a drive through its mailbox.

:class:`SoeClient` drives :mod:`pyethercat.wire.mailbox.soe_transfer` over one
slave's :class:`~pyethercat.master.mailbox.Mailbox`: reads of any element
(value, name, attribute, unit, minimum, maximum, default, data state),
fragmented answers joined, fragmented writes sent fragment by fragment (the
drive answers the last one), any drive number 0-7. A drive's refusal raises
:class:`~pyethercat.errors.SoeAbort` with the SoE error code and its text; no
answer in time :class:`~pyethercat.errors.SoeTimeoutError`. Requests go
through ``Mailbox.transact``: the first one after the master took the mailbox
over is sent again with the next counter when unanswered (the drive drops a
request whose counter repeats the last one it took, maybe an earlier
session's).

:meth:`SoeClient.read_value` and :meth:`SoeClient.write_value` convert values
by the IDN's attribute (data type, length, list), as IgH's ``soe_read`` shows
them.
"""

from __future__ import annotations

import struct
from typing import ClassVar, Self

from pyethercat.errors import ConfigError, MailboxError
from pyethercat.master.mailbox import ClientContext, Mailbox, ReceivedMessage
from pyethercat.master.transfer import answer_by_deadline, request_by_deadline
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.mailbox.soe import SoeElement, decode_soe, format_idn, parse_idn
from pyethercat.wire.mailbox.soe_transfer import (
    DEFAULT_SOE_TIMEOUT,
    SoeAttribute,
    SoeDataType,
    SoeReadClient,
    SoeWriteClient,
    decode_soe_list,
    decode_soe_text,
    encode_soe_list,
)

__all__ = ["DEFAULT_SOE_TIMEOUT", "IdnLike", "SoeClient", "SoeValue", "decode_soe_value",
           "encode_soe_value", "format_soe_value"]

#: An IDN as a number (0x8001) or as text ("S-0-0024", "P-0-0001").
IdnLike = int | str
#: A converted value: a number, text, or a list of them.
SoeValue = int | float | str | bytes | list[int] | list[float]


def _idn(idn: IdnLike) -> int:
    try:
        return parse_idn(idn if isinstance(idn, str) else str(int(idn)))
    except MailboxError as exc:
        raise ConfigError(str(exc)) from None


def _is_soe(msg: ReceivedMessage) -> bool:
    return bool(msg.header.type == MailboxType.SOE)


_INT_FORMATS = {(1, False): "<B", (2, False): "<H", (4, False): "<I", (8, False): "<Q",
                (1, True): "<b", (2, True): "<h", (4, True): "<i", (8, True): "<q"}


def _decode_scalar(raw: bytes, attr: SoeAttribute) -> int | float:
    if attr.data_type == SoeDataType.FLOAT and attr.length in (4, 8):
        return float(struct.unpack("<f" if attr.length == 4 else "<d", raw[:attr.length])[0])
    signed = attr.data_type == SoeDataType.SIGNED
    return int(struct.unpack(_INT_FORMATS[attr.length, signed], raw[:attr.length])[0])


def _encode_scalar(value: int | float, attr: SoeAttribute) -> bytes:
    if attr.data_type == SoeDataType.FLOAT and attr.length in (4, 8):
        return struct.pack("<f" if attr.length == 4 else "<d", float(value))
    signed = attr.data_type == SoeDataType.SIGNED
    try:
        return struct.pack(_INT_FORMATS[attr.length, signed], int(value))
    except struct.error:
        raise ConfigError(f"value {value} does not fit {attr.length} bytes "
                          f"({'signed' if signed else 'unsigned'})") from None


def decode_soe_value(raw: bytes, attr: SoeAttribute) -> SoeValue:
    """A value element as the attribute describes it (text, number, list of numbers)."""
    if attr.data_type == SoeDataType.STRING:
        return decode_soe_text(raw) if attr.is_list else raw.decode("latin-1")
    if attr.is_list:
        data, _cap = decode_soe_list(raw)
        step = attr.length
        if len(data) % step:
            raise MailboxError(f"SoE list of {len(data)} bytes is no multiple of {step}")
        items = [_decode_scalar(data[i:i + step], attr) for i in range(0, len(data), step)]
        if attr.data_type == SoeDataType.FLOAT:
            return [float(x) for x in items]
        return [int(x) for x in items]
    if len(raw) < attr.length:
        raise MailboxError(f"SoE value of {len(raw)} bytes, the attribute says {attr.length}")
    return _decode_scalar(raw, attr)


def format_soe_value(value: SoeValue, attr: SoeAttribute) -> str:
    """A value as the CLI prints it (IDN lists as S-x-nnnn, hex types in hex)."""
    def one(v: int | float) -> str:
        if attr.data_type == SoeDataType.IDN and isinstance(v, int):
            return format_idn(v)
        if attr.data_type in (SoeDataType.HEX, SoeDataType.BINARY) and isinstance(v, int):
            return f"0x{v:0{2 * attr.length}X}"
        return str(v)

    if isinstance(value, list):
        return " ".join(one(v) for v in value)
    if isinstance(value, str | bytes):
        return value if isinstance(value, str) else value.hex(" ")
    return one(value)


class SoeClient:
    """SoE services of one slave (see the module text)."""

    #: The mailbox type this client speaks (the registry key, see ``master.clients``).
    mailbox_type: ClassVar[MailboxType] = MailboxType.SOE

    @classmethod
    def for_mailbox(cls, mailbox: Mailbox, context: ClientContext) -> Self:
        """The client a master makes for a slave's mailbox."""
        return cls(mailbox)

    def __init__(self, mailbox: Mailbox, *, timeout: float = DEFAULT_SOE_TIMEOUT) -> None:
        self.mailbox = mailbox
        self.label = mailbox.label
        self.timeout = timeout

    def read(self, idn: IdnLike, *, elements: int = SoeElement.VALUE, drive: int = 0,
             timeout: float | None = None) -> bytes:
        """The raw bytes of the elements ``elements`` of ``idn`` (fragments joined)."""
        sm = SoeReadClient(_idn(idn), elements=elements, drive=drive,
                           timeout=timeout or self.timeout)
        mbx = self.mailbox
        what = f"SoE read of {format_idn(sm.idn)} (drive {drive})"
        with mbx.lock:
            mbx.drop(_is_soe)
            first = request_by_deadline(mbx, MailboxType.SOE, sm.start(mbx.clock()).encode(),
                                        _is_soe, what, sm, sm.timeout)
            sm.receive(decode_soe(first.payload), mbx.clock())
            while not sm.done:  # the following fragments
                more = answer_by_deadline(mbx, _is_soe, what, sm, sm.timeout)
                sm.receive(decode_soe(more.payload), mbx.clock())
        return sm.data

    def write(self, idn: IdnLike, data: bytes, *, elements: int = SoeElement.VALUE,
              drive: int = 0, timeout: float | None = None) -> None:
        """Write raw ``data`` to the elements ``elements`` of ``idn`` (fragmented if long)."""
        mbx = self.mailbox
        sm = SoeWriteClient(_idn(idn), bytes(data), mailbox_size=mbx.rx_size,
                            elements=elements, drive=drive, timeout=timeout or self.timeout)
        what = f"SoE write of {format_idn(sm.idn)} (drive {drive})"
        with mbx.lock:
            mbx.drop(_is_soe)
            frags = sm.start(mbx.clock())
            if len(frags) > 1 and not mbx.synced:
                # Only the last fragment is answered, so only it could be sent again
                # with the next counter; a first fragment the drive dropped (its
                # counter repeated an earlier session's last) would be lost. One
                # answered request first puts the counters in sync.
                self.read(sm.idn, elements=SoeElement.ATTRIBUTE, drive=drive)
            for frag in frags[:-1]:
                # SM0 refuses the next fragment until the drive took the last one.
                mbx.send(MailboxType.SOE, frag.encode(), what=what, timeout=sm.timeout)
            sm.deadline = mbx.clock() + sm.timeout
            answer = request_by_deadline(mbx, MailboxType.SOE, frags[-1].encode(), _is_soe,
                                         what, sm, sm.timeout)
            sm.receive(decode_soe(answer.payload), mbx.clock())

    # -- typed access ------------------------------------------------------------------

    def attribute(self, idn: IdnLike, *, drive: int = 0) -> SoeAttribute:
        """The attribute element of ``idn``."""
        return SoeAttribute.decode(self.read(idn, elements=SoeElement.ATTRIBUTE, drive=drive))

    def name(self, idn: IdnLike, *, drive: int = 0) -> str:
        """The name element of ``idn``."""
        return decode_soe_text(self.read(idn, elements=SoeElement.NAME, drive=drive))

    def unit(self, idn: IdnLike, *, drive: int = 0) -> str:
        """The unit element of ``idn``."""
        return decode_soe_text(self.read(idn, elements=SoeElement.UNIT, drive=drive))

    def read_value(self, idn: IdnLike, *, drive: int = 0,
                   attribute: SoeAttribute | None = None) -> SoeValue:
        """The value of ``idn`` converted by its attribute (read first unless given)."""
        attr = attribute if attribute is not None else self.attribute(idn, drive=drive)
        return decode_soe_value(self.read(idn, drive=drive), attr)

    def write_value(self, idn: IdnLike, value: SoeValue, *, drive: int = 0,
                    attribute: SoeAttribute | None = None) -> None:
        """Write ``value`` to ``idn``, encoded by its attribute (read first unless given)."""
        attr = attribute if attribute is not None else self.attribute(idn, drive=drive)
        self.write(idn, encode_soe_value(value, attr), drive=drive)


def encode_soe_value(value: SoeValue, attr: SoeAttribute) -> bytes:
    """The bytes of a value element as the attribute describes it (lists with their lengths)."""
    if isinstance(value, bytes):
        return value
    if isinstance(value, str):
        raw = value.encode("latin-1")
        return encode_soe_list(raw) if attr.is_list else raw
    if isinstance(value, list):
        if not attr.is_list:
            raise ConfigError("the IDN holds no list")
        return encode_soe_list(b"".join(_encode_scalar(v, attr) for v in value))
    return _encode_scalar(value, attr)
