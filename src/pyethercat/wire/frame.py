"""Ethernet + EtherCAT frame codec (IEC 61158-4-12, ETG.1000.4; Wireshark ``packet-ethercat-frame.c``).

Frames travel as raw Ethernet (EtherType 0x88A4) or as the payload of a UDP
datagram on port 34980; in both cases the EtherCAT part is a 16-bit header
(11-bit length, type) followed by datagrams (type 1) or one mailbox (type 5).
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from pyethercat.errors import FrameError, FrameTooLargeError
from pyethercat.wire.datagram import (
    MAX_PAYLOAD,
    Datagram,
    datagrams_size,
    decode_datagrams,
    encode_datagram_into,
)

__all__ = [
    "BROADCAST_MAC",
    "ECAT_HEADER_SIZE",
    "ECAT_LENGTH_MASK",
    "ECAT_RESERVED_BIT",
    "ECAT_TYPE_SHIFT",
    "ETHERTYPE_ETHERCAT",
    "ETHERTYPE_VLAN",
    "ETH_HEADER_SIZE",
    "LOCALLY_ADMINISTERED_BIT",
    "MASTER_MAC",
    "MAX_FRAME_SIZE",
    "MIN_FRAME_SIZE",
    "SECONDARY_MAC",
    "SECONDARY_MARK",
    "UDP_PORT",
    "WIRE_EXTRA_BYTES",
    "WIRE_NS_PER_BYTE",
    "EtherCATFrame",
    "FrameBuilder",
    "FrameType",
    "NotEtherCATError",
    "decode_ecat_payload",
    "decode_frame",
    "decode_udp_payload",
    "ecat_header",
    "ecat_offset",
    "encode_ecat_payload",
    "encode_frame",
    "encode_mailbox_frame",
    "encode_udp_payload",
    "ethernet_frame",
    "first_index",
    "is_ethercat",
    "returned_source_mac",
    "untagged",
]

ETHERTYPE_ETHERCAT = 0x88A4
ETHERTYPE_VLAN = 0x8100
#: EtherCAT over UDP (and the mailbox gateway) listen on this port.
UDP_PORT = 34980
BROADCAST_MAC = b"\xff" * 6
#: Default source MACs of the master's primary and secondary (redundancy) port.
#: Unicast and not locally administered, so a returned frame (which slaves mark
#: with the locally-administered bit) is told apart from our own. SOEM's
#: 01:01:... defaults are group addresses, which Wireshark flags as invalid
#: sources; the second 16-bit word differs between the two ports as in SOEM
#: (``priMAC``/``secMAC``): a ring master XORs ``SECONDARY_MARK`` into it in the
#: copies it sends on its second port, so a copy that comes back tells which port
#: it was sent on (slaves change only the locally administered bit of byte 0).
MASTER_MAC = b"\x10\x10\x10\x10\x10\x10"
SECONDARY_MARK = b"\x04\x04"
SECONDARY_MAC = b"\x10\x10\x14\x14\x10\x10"
ETH_HEADER_SIZE = 14
ECAT_HEADER_SIZE = 2
#: Minimum Ethernet frame without FCS; shorter frames are zero-padded.
MIN_FRAME_SIZE = 60
#: Maximum Ethernet frame without FCS.
MAX_FRAME_SIZE = 1514
ECAT_LENGTH_MASK = 0x07FF
ECAT_RESERVED_BIT = 0x0800
ECAT_TYPE_SHIFT = 12
#: The bit a slave sets in the first source-MAC byte of a frame it returns.
LOCALLY_ADMINISTERED_BIT = 0x02
#: Nanoseconds one byte takes on a 100 Mbit/s (100BASE-TX) wire.
WIRE_NS_PER_BYTE = 80
#: Preamble and start delimiter (8), FCS (4), inter-frame gap (12): bytes on the wire
#: besides the frame itself (IEEE 802.3 clause 4).
WIRE_EXTRA_BYTES = 24


class FrameType(enum.IntEnum):
    """EtherCAT header type field."""

    DATAGRAMS = 1
    ADS = 2
    RAW_IO = 3
    NETWORK_VARIABLES = 4
    MAILBOX = 5


class NotEtherCATError(FrameError):
    """The Ethernet frame is not an EtherCAT frame (other EtherType)."""


@dataclass(slots=True)
class EtherCATFrame:
    """A decoded EtherCAT frame.

    ``datagrams`` is filled for type-1 frames, ``mailbox`` holds the body of a
    type-5 (mailbox gateway) frame, ``body`` the raw body of any other type.
    """

    frame_type: int
    datagrams: list[Datagram] = field(default_factory=list)
    mailbox: bytes | None = None
    body: bytes = b""
    dst: bytes = BROADCAST_MAC
    src: bytes = MASTER_MAC
    #: Bytes after the EtherCAT length (padding) in the received frame.
    padding: int = 0
    #: Bytes inside the EtherCAT length after the last datagram (only a
    #: ``strict=False`` decode accepts them; TwinCAT sends one).
    trailing: int = 0


def ecat_header(length: int, frame_type: int = FrameType.DATAGRAMS) -> int:
    """The 16-bit EtherCAT header word."""
    if length > ECAT_LENGTH_MASK:
        raise FrameTooLargeError(f"EtherCAT length {length} exceeds the 11-bit field")
    return (length & ECAT_LENGTH_MASK) | ((frame_type & 0xF) << ECAT_TYPE_SHIFT)


def encode_ecat_payload(datagrams: Sequence[Datagram]) -> bytes:
    """EtherCAT header + datagrams (the UDP payload form, without padding)."""
    size = datagrams_size(datagrams)
    if not datagrams:
        raise FrameError("a frame needs at least one datagram")
    if size > MAX_PAYLOAD:
        raise FrameTooLargeError(
            f"{len(datagrams)} datagrams need {size} bytes, a frame holds {MAX_PAYLOAD}")
    buf = bytearray(ECAT_HEADER_SIZE + size)
    struct.pack_into("<H", buf, 0, ecat_header(size))
    offset = ECAT_HEADER_SIZE
    last = len(datagrams) - 1
    for i, dgram in enumerate(datagrams):
        offset = encode_datagram_into(buf, offset, dgram, i != last)
    return bytes(buf)


def encode_frame(datagrams: Sequence[Datagram], src: bytes = MASTER_MAC,
                 dst: bytes = BROADCAST_MAC) -> bytes:
    """A complete Ethernet frame (without FCS), zero-padded to 60 bytes."""
    payload = encode_ecat_payload(datagrams)
    return ethernet_frame(payload, src, dst)


def encode_mailbox_frame(mailbox: bytes, src: bytes = MASTER_MAC,
                         dst: bytes = BROADCAST_MAC) -> bytes:
    """A type-5 (mailbox gateway) frame carrying one complete mailbox."""
    if len(mailbox) > MAX_PAYLOAD:
        raise FrameTooLargeError(f"mailbox of {len(mailbox)} bytes does not fit a frame")
    payload = struct.pack("<H", ecat_header(len(mailbox), FrameType.MAILBOX)) + mailbox
    return ethernet_frame(payload, src, dst)


def ethernet_frame(payload: bytes, src: bytes = MASTER_MAC,
                   dst: bytes = BROADCAST_MAC) -> bytes:
    """An Ethernet frame (EtherType 0x88A4) around an EtherCAT payload, zero-padded to 60 bytes."""
    if len(src) != 6 or len(dst) != 6:
        raise FrameError("MAC addresses are 6 bytes")
    frame = dst + src + struct.pack(">H", ETHERTYPE_ETHERCAT) + payload
    if len(frame) < MIN_FRAME_SIZE:
        frame += bytes(MIN_FRAME_SIZE - len(frame))
    return frame


def ecat_offset(raw: bytes | bytearray | memoryview) -> int | None:
    """Where the EtherCAT header starts in an Ethernet frame, or ``None`` if it is no EtherCAT.

    14 for an untagged frame, 18 behind one IEEE 802.1Q VLAN tag (EtherType
    0x8100); the EtherType 0x88A4 follows the MAC addresses or the tag.
    """
    if len(raw) < ETH_HEADER_SIZE:
        return None
    ethertype = (raw[12] << 8) | raw[13]
    if ethertype == ETHERTYPE_VLAN and len(raw) >= ETH_HEADER_SIZE + 4:
        ethertype = (raw[16] << 8) | raw[17]
        return ETH_HEADER_SIZE + 4 if ethertype == ETHERTYPE_ETHERCAT else None
    return ETH_HEADER_SIZE if ethertype == ETHERTYPE_ETHERCAT else None


def is_ethercat(raw: bytes | bytearray | memoryview) -> bool:
    """Whether an Ethernet frame carries EtherCAT (optionally VLAN-tagged)."""
    return ecat_offset(raw) is not None


def untagged(raw: bytes) -> bytes:
    """The frame without its VLAN tag, so that offsets match the frame as it was sent."""
    if len(raw) >= ETH_HEADER_SIZE + 4 and ((raw[12] << 8) | raw[13]) == ETHERTYPE_VLAN:
        return raw[:12] + raw[16:]
    return raw


def first_index(raw: bytes | bytearray | memoryview) -> int | None:
    """Index byte of the first datagram of an EtherCAT frame (``None``: no datagram there)."""
    start = ecat_offset(raw)
    if start is None or len(raw) < start + ECAT_HEADER_SIZE + 2:
        return None
    return raw[start + ECAT_HEADER_SIZE + 1]


def decode_frame(raw: bytes | bytearray | memoryview, strict: bool = True) -> EtherCATFrame:
    """Decode an Ethernet frame holding EtherCAT.

    Raises :class:`NotEtherCATError` for other EtherTypes and
    :class:`FrameError` for malformed EtherCAT content. ``strict=False``
    tolerates bytes after the last datagram inside the EtherCAT length
    (TwinCAT sends such frames; ESCs ignore the extra bytes).
    """
    view = memoryview(raw)
    if len(view) < ETH_HEADER_SIZE:
        raise FrameError(f"Ethernet frame of {len(view)} bytes is shorter than its 14-byte header", 0)
    start = ETH_HEADER_SIZE
    ethertype = (view[12] << 8) | view[13]
    if ethertype == ETHERTYPE_VLAN:
        if len(view) < ETH_HEADER_SIZE + 4:
            raise FrameError("VLAN-tagged frame truncated", 12)
        ethertype = (view[16] << 8) | view[17]
        start += 4
    if ethertype != ETHERTYPE_ETHERCAT:
        raise NotEtherCATError(f"EtherType 0x{ethertype:04X} is not EtherCAT (0x88A4)", 12)
    frame = decode_ecat_payload(view[start:], base_offset=start, strict=strict)
    frame.dst = bytes(view[0:6])
    frame.src = bytes(view[6:12])
    return frame


def decode_ecat_payload(payload: bytes | bytearray | memoryview, base_offset: int = 0,
                        strict: bool = True) -> EtherCATFrame:
    """Decode the EtherCAT part (header + body), e.g. a UDP payload."""
    view = memoryview(payload)
    if len(view) < ECAT_HEADER_SIZE:
        raise FrameError("EtherCAT header truncated", base_offset)
    (word,) = struct.unpack_from("<H", view, 0)
    length = word & ECAT_LENGTH_MASK
    frame_type = word >> ECAT_TYPE_SHIFT
    if word & ECAT_RESERVED_BIT:
        raise FrameError("reserved bit 11 of the EtherCAT header is set", base_offset)
    body_end = ECAT_HEADER_SIZE + length
    if body_end > len(view):
        raise FrameError(
            f"EtherCAT header says {length} bytes but only {len(view) - ECAT_HEADER_SIZE} follow",
            base_offset)
    body = view[ECAT_HEADER_SIZE:body_end]
    frame = EtherCATFrame(frame_type, padding=len(view) - body_end)
    if frame_type == FrameType.DATAGRAMS:
        frame.datagrams = decode_datagrams(body, base_offset + ECAT_HEADER_SIZE, strict=strict)
        if not strict:
            frame.trailing = length - datagrams_size(frame.datagrams)
    elif frame_type == FrameType.MAILBOX:
        frame.mailbox = bytes(body)
    else:
        try:
            FrameType(frame_type)
        except ValueError:
            raise FrameError(f"unknown EtherCAT frame type {frame_type}", base_offset) from None
        frame.body = bytes(body)
    return frame


def encode_udp_payload(datagrams: Sequence[Datagram]) -> bytes:
    """EtherCAT over UDP: exactly the bytes after the EtherType, without padding."""
    return encode_ecat_payload(datagrams)


def decode_udp_payload(payload: bytes | bytearray | memoryview) -> EtherCATFrame:
    """Decode an EtherCAT-over-UDP payload."""
    return decode_ecat_payload(payload)


class FrameBuilder:
    """Collects datagrams for one frame and refuses what does not fit.

    ``add`` raises :class:`FrameTooLargeError` instead of truncating; use
    ``fits`` to decide when to start a new frame.
    """

    def __init__(self, capacity: int = MAX_PAYLOAD) -> None:
        self.capacity = capacity
        self.datagrams: list[Datagram] = []
        self.used = 0

    def fits(self, dgram: Datagram) -> bool:
        """Whether ``dgram`` still fits into this frame."""
        return self.used + dgram.size <= self.capacity

    @property
    def free(self) -> int:
        """Bytes still free for datagrams (header and WKC included)."""
        return self.capacity - self.used

    def add(self, dgram: Datagram) -> None:
        """Append ``dgram``; :class:`FrameTooLargeError` when it does not fit."""
        if not self.fits(dgram):
            raise FrameTooLargeError(
                f"datagram of {dgram.size} bytes does not fit: {self.free} bytes free in the frame")
        self.datagrams.append(dgram)
        self.used += dgram.size

    def __len__(self) -> int:
        return len(self.datagrams)

    def build(self, src: bytes = MASTER_MAC, dst: bytes = BROADCAST_MAC) -> bytes:
        """The Ethernet frame of the datagrams added so far (see :func:`encode_frame`)."""
        return encode_frame(self.datagrams, src, dst)


def returned_source_mac(src: bytes) -> bytes:
    """The source MAC a slave puts on a frame it returns (locally administered bit set)."""
    return bytes([src[0] | LOCALLY_ADMINISTERED_BIT]) + src[1:]
