"""ETG.8200 mailbox gateway datagrams: decoding requests, encoding replies, addressing.

A gateway request is a UDP datagram (port 0x88A4 = 34980) holding the 2-byte
EtherCAT header with type 5 (mailbox) and one complete mailbox: the 6-byte
mailbox header, then the protocol data. The mailbox header's address field
names the target (IgH ``mailbox_gateway/README`` and ``master/master.c``
``ec_master_mbox_gateway``; KickCAT ``lib/master/src/Gateway.cc``):

- 0: the master itself (its object dictionary, ETG.1510);
- a slave's configured station address (KickCAT, ETG.1510 0x8nnn:01);
- 1000 + ring position (IgH's ``EC_MBG_SLAVE_ADDR_OFFSET``).

The reply is the slave's answer in the same framing, its mailbox header
carrying the requester's address again. What cannot be decoded raises
:class:`GatewayError` with the reason; a gateway drops such datagrams and
counts them (neither IgH nor KickCAT answer a bad request).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from pyethercat.errors import FrameError
from pyethercat.wire.frame import ECAT_HEADER_SIZE, FrameType, ecat_header
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE, MailboxHeader

__all__ = [
    "GATEWAY_PORT",
    "IGH_ADDRESS_OFFSET",
    "MASTER_ADDRESS",
    "GatewayError",
    "GatewayRequest",
    "decode_gateway_request",
    "encode_gateway_reply",
    "gateway_target",
]

#: UDP (and TCP) port of the mailbox gateway, 0x88A4 (ETG.8200; IgH SVR_PORT, KickCAT).
GATEWAY_PORT = 0x88A4
#: Mailbox address of the master's own object dictionary.
MASTER_ADDRESS = 0
#: IgH addresses slaves as ring position + 1000.
IGH_ADDRESS_OFFSET = 1000


class GatewayError(FrameError):
    """A gateway datagram that cannot be served; ``reason`` is a short key for counting."""

    def __init__(self, message: str, reason: str) -> None:
        self.reason = reason
        super().__init__(message)


@dataclass(frozen=True, slots=True)
class GatewayRequest:
    """A decoded request: its mailbox header and the whole mailbox (header + data)."""

    header: MailboxHeader
    mailbox: bytes

    @property
    def address(self) -> int:
        """Target address (mailbox header word 2)."""
        return self.header.address

    @property
    def payload(self) -> bytes:
        """The protocol data after the mailbox header."""
        return self.mailbox[MAILBOX_HEADER_SIZE:]


def decode_gateway_request(datagram: bytes | bytearray | memoryview) -> GatewayRequest:
    """Check and decode one gateway datagram; :class:`GatewayError` when unusable."""
    raw = bytes(datagram)
    if len(raw) < ECAT_HEADER_SIZE + MAILBOX_HEADER_SIZE:
        raise GatewayError(f"datagram of {len(raw)} bytes is shorter than the EtherCAT and "
                           "mailbox headers", "short")
    (word,) = struct.unpack_from("<H", raw, 0)
    length, ftype = word & 0x07FF, word >> 12
    if ftype != FrameType.MAILBOX:
        raise GatewayError(f"EtherCAT frame type {ftype}, a gateway request has type 5",
                           "type")
    if word & 0x0800:
        raise GatewayError("reserved bit 11 of the EtherCAT header is set", "header")
    if ECAT_HEADER_SIZE + length > len(raw):
        raise GatewayError(f"EtherCAT header says {length} bytes, {len(raw) - 2} follow",
                           "length")
    body = raw[ECAT_HEADER_SIZE:ECAT_HEADER_SIZE + length]
    if len(body) < MAILBOX_HEADER_SIZE:
        raise GatewayError(f"mailbox of {len(body)} bytes has no complete header", "short")
    header = MailboxHeader.decode(body)
    if header.length == 0 or MAILBOX_HEADER_SIZE + header.length > len(body):
        raise GatewayError(f"mailbox length {header.length} does not fit the "
                           f"{len(body) - MAILBOX_HEADER_SIZE} bytes after its header",
                           "length")
    return GatewayRequest(header, body[:MAILBOX_HEADER_SIZE + header.length])


def encode_gateway_reply(mailbox: bytes) -> bytes:
    """A reply datagram: EtherCAT header (type 5) + the mailbox."""
    return struct.pack("<H", ecat_header(len(mailbox), FrameType.MAILBOX)) + bytes(mailbox)


def gateway_target(address: int, stations: Sequence[int]) -> int | None:
    """Ring position a request address names, -1 for the master, None for nobody.

    ``stations`` are the slaves' configured station addresses in ring order.
    A station address wins over IgH's 1000 + position where both could apply.
    """
    if address == MASTER_ADDRESS:
        return -1
    for position, station in enumerate(stations):
        if station == address:
            return position
    position = address - IGH_ADDRESS_OFFSET
    if 0 <= position < len(stations):
        return position
    return None
