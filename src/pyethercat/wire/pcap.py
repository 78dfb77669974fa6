"""Capture file codec: classic pcap and pcapng (sans-IO).

The codec turns bytes into typed :class:`CaptureRecord` objects and back. It opens
no files: the writers take a binary stream that somebody else opened, the
readers take a binary stream or a ``bytes`` object. Time stamps are integer
nanoseconds since the Unix epoch and are passed in by the caller (this module
keeps no clock).

Supported:

* classic pcap, microsecond (``A1B2C3D4``) and nanosecond (``A1B23C4D``) magic,
  both byte orders on read; written little-endian (host order of every Linux
  machine this project runs on, and what libpcap writes there).
* pcapng: Section Header, Interface Description, Enhanced Packet, Simple Packet
  and the obsolete Packet block; every other block type is skipped. Both byte
  orders on read, several sections per file, ``if_tsresol`` (powers of 10 and
  of 2) and ``if_tsoffset``. Written little-endian with nanosecond resolution
  and the packet direction in ``epb_flags``.

Every malformed input raises :class:`pyethercat.errors.CaptureError` naming the
byte offset.
"""

from __future__ import annotations

import enum
import io
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import BinaryIO

from pyethercat.errors import CaptureError

__all__ = [
    "LINKTYPE_ETHERNET",
    "PCAP_MAGIC_US",
    "PCAP_MAGIC_NS",
    "PCAPNG_SHB_TYPE",
    "CaptureFormat",
    "PacketDirection",
    "CaptureRecord",
    "detect_format",
    "encode_pcap_header",
    "encode_pcap_record",
    "encode_pcapng_shb",
    "encode_pcapng_idb",
    "encode_pcapng_epb",
    "PcapWriter",
    "PcapngWriter",
    "read_pcap",
    "read_pcapng",
    "read_capture",
    "parse_capture",
]

LINKTYPE_ETHERNET = 1
"""Link type of IEEE 802.3 Ethernet frames (the only one EtherCAT needs)."""

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAPNG_SHB_TYPE = 0x0A0D0D0A
_PCAPNG_BOM = 0x1A2B3C4D

# pcapng block types
_BT_IDB = 0x00000001
_BT_PB = 0x00000002  # obsolete Packet Block
_BT_SPB = 0x00000003
_BT_EPB = 0x00000006

# pcapng option codes
_OPT_END = 0
_OPT_IF_NAME = 2
_OPT_IF_TSRESOL = 9
_OPT_IF_TSOFFSET = 14
_OPT_EPB_FLAGS = 2

_DEFAULT_SNAPLEN = 262144
# A record longer than this is certainly a lying length field, not a packet.
_MAX_RECORD = 16 * 1024 * 1024


class CaptureFormat(enum.Enum):
    """The two container formats this module reads and writes."""

    PCAP = "pcap"
    PCAPNG = "pcapng"


class PacketDirection(enum.IntEnum):
    """Packet direction as stored in the pcapng ``epb_flags`` option (bits 0-1)."""

    UNKNOWN = 0
    INBOUND = 1
    OUTBOUND = 2


@dataclass(frozen=True, slots=True)
class CaptureRecord:
    """One captured packet.

    ``timestamp_ns`` is nanoseconds since the Unix epoch. ``orig_len`` is the
    length on the wire (``len(data)`` unless the capture was truncated by a
    snap length). ``interface_id`` is the pcapng interface (0 for pcap).
    """

    timestamp_ns: int
    data: bytes
    interface_id: int = 0
    linktype: int = LINKTYPE_ETHERNET
    orig_len: int | None = None
    direction: PacketDirection = PacketDirection.UNKNOWN

    @property
    def wire_len(self) -> int:
        """Length of the packet on the wire."""
        return len(self.data) if self.orig_len is None else self.orig_len


def detect_format(head: bytes) -> CaptureFormat:
    """Tell pcap from pcapng by the first four bytes of a file."""
    if len(head) < 4:
        raise CaptureError(f"capture too short to hold a file header ({len(head)} bytes)")
    (le,) = struct.unpack_from("<I", head)
    (be,) = struct.unpack_from(">I", head)
    if le == PCAPNG_SHB_TYPE:
        return CaptureFormat.PCAPNG
    if PCAP_MAGIC_US in (le, be) or PCAP_MAGIC_NS in (le, be):
        return CaptureFormat.PCAP
    raise CaptureError(f"not a pcap or pcapng file (magic {head[:4].hex()})")


# --- encoders ------------------------------------------------------------------


def encode_pcap_header(
    linktype: int = LINKTYPE_ETHERNET, snaplen: int = _DEFAULT_SNAPLEN, nanosecond: bool = True
) -> bytes:
    """The 24-byte classic pcap file header (little-endian)."""
    magic = PCAP_MAGIC_NS if nanosecond else PCAP_MAGIC_US
    return struct.pack("<IHHiIII", magic, 2, 4, 0, 0, snaplen, linktype)


def encode_pcap_record(timestamp_ns: int, data: bytes, nanosecond: bool = True) -> bytes:
    """One classic pcap record (16-byte header + data), little-endian."""
    if timestamp_ns < 0:
        raise CaptureError(f"negative time stamp {timestamp_ns} ns")
    sec, frac = divmod(timestamp_ns, 1_000_000_000)
    if not nanosecond:
        frac //= 1000
    if sec > 0xFFFFFFFF:
        raise CaptureError(f"time stamp {timestamp_ns} ns does not fit classic pcap")
    return struct.pack("<IIII", sec, frac, len(data), len(data)) + bytes(data)


def _pad4(n: int) -> int:
    return (-n) & 3


def _option(code: int, value: bytes) -> bytes:
    return struct.pack("<HH", code, len(value)) + value + b"\x00" * _pad4(len(value))


def _block(block_type: int, body: bytes) -> bytes:
    total = 12 + len(body)
    return struct.pack("<II", block_type, total) + body + struct.pack("<I", total)


def encode_pcapng_shb() -> bytes:
    """A pcapng Section Header Block (version 1.0, section length unknown)."""
    body = struct.pack("<IHHq", _PCAPNG_BOM, 1, 0, -1)
    return _block(PCAPNG_SHB_TYPE, body)


def encode_pcapng_idb(
    linktype: int = LINKTYPE_ETHERNET, name: str | None = None, snaplen: int = _DEFAULT_SNAPLEN
) -> bytes:
    """A pcapng Interface Description Block with nanosecond time stamps."""
    opts = b""
    if name:
        opts += _option(_OPT_IF_NAME, name.encode())
    opts += _option(_OPT_IF_TSRESOL, b"\x09")
    opts += _option(_OPT_END, b"")
    return _block(_BT_IDB, struct.pack("<HHI", linktype, 0, snaplen) + opts)


def encode_pcapng_epb(
    timestamp_ns: int,
    data: bytes,
    interface_id: int = 0,
    direction: PacketDirection = PacketDirection.UNKNOWN,
) -> bytes:
    """A pcapng Enhanced Packet Block (time stamp in ns, see :func:`encode_pcapng_idb`)."""
    if timestamp_ns < 0:
        raise CaptureError(f"negative time stamp {timestamp_ns} ns")
    if timestamp_ns >> 64:
        raise CaptureError(f"time stamp {timestamp_ns} ns does not fit 64 bits")
    data = bytes(data)
    body = struct.pack(
        "<IIIII",
        interface_id,
        timestamp_ns >> 32,
        timestamp_ns & 0xFFFFFFFF,
        len(data),
        len(data),
    )
    body += data + b"\x00" * _pad4(len(data))
    if direction != PacketDirection.UNKNOWN:
        body += _option(_OPT_EPB_FLAGS, struct.pack("<I", int(direction)))
        body += _option(_OPT_END, b"")
    return _block(_BT_EPB, body)


class PcapWriter:
    """Writes a classic pcap file to a binary stream (header written at once)."""

    def __init__(
        self,
        stream: BinaryIO,
        linktype: int = LINKTYPE_ETHERNET,
        nanosecond: bool = True,
        snaplen: int = _DEFAULT_SNAPLEN,
    ) -> None:
        self.stream = stream
        self.nanosecond = nanosecond
        stream.write(encode_pcap_header(linktype, snaplen, nanosecond))

    def write(
        self,
        timestamp_ns: int,
        data: bytes,
        interface_id: int = 0,
        direction: PacketDirection = PacketDirection.UNKNOWN,
    ) -> None:
        """Append one packet. Interface and direction do not exist in pcap and are ignored."""
        self.stream.write(encode_pcap_record(timestamp_ns, data, self.nanosecond))

    def write_record(self, record: CaptureRecord) -> None:
        """Append a :class:`CaptureRecord`."""
        self.write(record.timestamp_ns, record.data)


class PcapngWriter:
    """Writes a pcapng file to a binary stream.

    The Section Header Block is written at once, plus one Interface Description
    Block per name in ``interfaces``; more can be added with :meth:`add_interface`.
    """

    def __init__(
        self,
        stream: BinaryIO,
        interfaces: tuple[str, ...] | list[str] = ("eth0",),
        linktype: int = LINKTYPE_ETHERNET,
    ) -> None:
        self.stream = stream
        self._count = 0
        stream.write(encode_pcapng_shb())
        for name in interfaces:
            self.add_interface(name, linktype)

    @property
    def interface_count(self) -> int:
        """Number of interfaces described so far."""
        return self._count

    def add_interface(self, name: str | None, linktype: int = LINKTYPE_ETHERNET) -> int:
        """Describe one more interface; returns its interface id."""
        self.stream.write(encode_pcapng_idb(linktype, name))
        self._count += 1
        return self._count - 1

    def write(
        self,
        timestamp_ns: int,
        data: bytes,
        interface_id: int = 0,
        direction: PacketDirection = PacketDirection.UNKNOWN,
    ) -> None:
        """Append one packet as an Enhanced Packet Block."""
        if not 0 <= interface_id < self._count:
            raise CaptureError(f"interface id {interface_id} not described (have {self._count})")
        self.stream.write(encode_pcapng_epb(timestamp_ns, data, interface_id, direction))

    def write_record(self, record: CaptureRecord) -> None:
        """Append a :class:`CaptureRecord`."""
        self.write(record.timestamp_ns, record.data, record.interface_id, record.direction)


# --- decoders ------------------------------------------------------------------


class _Source:
    """Reads exact byte counts from a stream and tracks the offset for messages."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.offset = 0

    def read(self, n: int, what: str, allow_eof: bool = False) -> bytes | None:
        data = self.stream.read(n) if n else b""
        if data is None:  # non-blocking stream without data: treat as truncation
            data = b""
        if len(data) != n:
            if allow_eof and not data:
                return None
            raise CaptureError(
                f"truncated {what}: need {n} bytes, file has {len(data)} (at byte {self.offset})"
            )
        self.offset += n
        return data

    def need(self, n: int, what: str) -> bytes:
        data = self.read(n, what)
        assert data is not None
        return data


def read_pcap(stream: BinaryIO) -> Iterator[CaptureRecord]:
    """Yield the records of a classic pcap file read from ``stream``."""
    src = _Source(stream)
    head = src.need(24, "pcap file header")
    (magic_le,) = struct.unpack_from("<I", head)
    (magic_be,) = struct.unpack_from(">I", head)
    if magic_le in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
        order, magic = "<", magic_le
    elif magic_be in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
        order, magic = ">", magic_be
    else:
        raise CaptureError(f"not a pcap file (magic {head[:4].hex()}) (at byte 0)")
    major, _minor, _zone, _sigfigs, _snaplen, network = struct.unpack_from(
        order + "HHiIII", head, 4
    )
    if major != 2:
        raise CaptureError(f"unsupported pcap version {major} (at byte 4)")
    linktype = network & 0xFFFF  # upper bits carry FCS information
    frac_ns = 1 if magic == PCAP_MAGIC_NS else 1000
    rec_fmt = order + "IIII"
    while True:
        where = src.offset
        rh = src.read(16, "pcap record header", allow_eof=True)
        if rh is None:
            return
        sec, frac, incl, orig = struct.unpack(rec_fmt, rh)
        if incl > _MAX_RECORD:
            raise CaptureError(f"pcap record length {incl} is not plausible (at byte {where})")
        if frac * frac_ns >= 1_000_000_000:
            raise CaptureError(
                f"pcap record fraction of second {frac} out of range (at byte {where})"
            )
        data = src.need(incl, "pcap record data")
        yield CaptureRecord(
            timestamp_ns=sec * 1_000_000_000 + frac * frac_ns,
            data=data,
            interface_id=0,
            linktype=linktype,
            orig_len=orig,
        )


@dataclass(slots=True)
class _Interface:
    linktype: int
    snaplen: int
    # time stamp unit: value * num // den nanoseconds
    num: int = 1000
    den: int = 1
    offset_s: int = 0


def _parse_tsresol(value: int) -> tuple[int, int]:
    exp = value & 0x7F
    if value & 0x80:  # power of two
        return 1_000_000_000, 1 << exp
    if exp <= 9:
        return 10 ** (9 - exp), 1
    return 1, 10 ** (exp - 9)


def _options(body: bytes, start: int, order: str, base: int) -> Iterator[tuple[int, bytes]]:
    """Yield (code, value) of a pcapng option list; ``base`` is the file offset of ``body``."""
    pos = start
    while pos + 4 <= len(body):
        code, length = struct.unpack_from(order + "HH", body, pos)
        if code == _OPT_END:
            return
        end = pos + 4 + length
        if end > len(body):
            raise CaptureError(f"pcapng option {code} runs past its block (at byte {base + pos})")
        yield code, body[pos + 4 : end]
        pos = end + _pad4(length)


def read_pcapng(stream: BinaryIO) -> Iterator[CaptureRecord]:
    """Yield the packets of a pcapng file read from ``stream``; unknown blocks are skipped."""
    src = _Source(stream)
    order = "<"
    interfaces: list[_Interface] = []
    first = True
    while True:
        where = src.offset
        head = src.read(8, "pcapng block header", allow_eof=True)
        if head is None:
            if first:
                raise CaptureError("empty pcapng file (at byte 0)")
            return
        (btype_le,) = struct.unpack_from("<I", head)
        if btype_le == PCAPNG_SHB_TYPE:
            # The byte order of a section is only known from its BOM field.
            bom_raw = src.need(4, "pcapng section header")
            if struct.unpack("<I", bom_raw)[0] == _PCAPNG_BOM:
                order = "<"
            elif struct.unpack(">I", bom_raw)[0] == _PCAPNG_BOM:
                order = ">"
            else:
                raise CaptureError(
                    f"pcapng section header has a bad byte-order magic {bom_raw.hex()} (at byte {where + 8})"
                )
            (total,) = struct.unpack_from(order + "I", head, 4)
            if total < 28 or total % 4 or total > _MAX_RECORD:
                raise CaptureError(
                    f"pcapng section header length {total} is invalid (at byte {where})"
                )
            body = bom_raw + src.need(total - 16, "pcapng section header")
            major = struct.unpack_from(order + "H", body, 4)[0]
            if major != 1:
                raise CaptureError(f"unsupported pcapng version {major} (at byte {where + 12})")
            interfaces = []
            btype = PCAPNG_SHB_TYPE
        else:
            if first:
                raise CaptureError(
                    f"pcapng file does not start with a section header (at byte {where})"
                )
            btype, total = struct.unpack(order + "II", head)
            if total < 12 or total % 4 or total > _MAX_RECORD:
                raise CaptureError(f"pcapng block length {total} is invalid (at byte {where})")
            body = src.need(total - 12, f"pcapng block of type 0x{btype:08X}")
        first = False
        trailer = src.need(4, "pcapng block trailer")
        (total2,) = struct.unpack(order + "I", trailer)
        if total2 != total:
            raise CaptureError(
                f"pcapng block length {total} and trailing length {total2} differ (at byte {where})"
            )
        base = where + 8
        if btype == PCAPNG_SHB_TYPE:
            continue
        if btype == _BT_IDB:
            if len(body) < 8:
                raise CaptureError(f"pcapng interface block too short (at byte {where})")
            linktype, _res, snaplen = struct.unpack_from(order + "HHI", body)
            iface = _Interface(linktype, snaplen)
            for code, value in _options(body, 8, order, base):
                if code == _OPT_IF_TSRESOL and len(value) >= 1:
                    iface.num, iface.den = _parse_tsresol(value[0])
                elif code == _OPT_IF_TSOFFSET and len(value) >= 8:
                    iface.offset_s = struct.unpack_from(order + "q", value)[0]
            interfaces.append(iface)
        elif btype in (_BT_EPB, _BT_PB):
            if len(body) < 20:
                raise CaptureError(f"pcapng packet block too short (at byte {where})")
            if btype == _BT_EPB:
                if_id, ts_hi, ts_lo, cap, orig = struct.unpack_from(order + "IIIII", body)
            else:
                if_id, _drops, ts_hi, ts_lo, cap, orig = struct.unpack_from(order + "HHIIII", body)
            if if_id >= len(interfaces):
                raise CaptureError(
                    f"pcapng packet names interface {if_id}, only {len(interfaces)} described (at byte {where})"
                )
            if 20 + cap > len(body):
                raise CaptureError(
                    f"pcapng packet length {cap} runs past its block (at byte {where})"
                )
            iface = interfaces[if_id]
            direction = PacketDirection.UNKNOWN
            if btype == _BT_EPB:
                for code, value in _options(body, 20 + cap + _pad4(cap), order, base):
                    if code == _OPT_EPB_FLAGS and len(value) >= 4:
                        bits = struct.unpack_from(order + "I", value)[0] & 3
                        direction = PacketDirection(bits) if bits != 3 else PacketDirection.UNKNOWN
            ts = (ts_hi << 32) | ts_lo
            yield CaptureRecord(
                timestamp_ns=ts * iface.num // iface.den + iface.offset_s * 1_000_000_000,
                data=bytes(body[20 : 20 + cap]),
                interface_id=if_id,
                linktype=iface.linktype,
                orig_len=orig,
                direction=direction,
            )
        elif btype == _BT_SPB:
            if not interfaces:
                raise CaptureError(f"pcapng simple packet before any interface (at byte {where})")
            if len(body) < 4:
                raise CaptureError(f"pcapng simple packet block too short (at byte {where})")
            (orig,) = struct.unpack_from(order + "I", body)
            iface = interfaces[0]
            cap = min(orig, len(body) - 4)
            if iface.snaplen:
                cap = min(cap, iface.snaplen)
            yield CaptureRecord(
                timestamp_ns=0,
                data=bytes(body[4 : 4 + cap]),
                interface_id=0,
                linktype=iface.linktype,
                orig_len=orig,
            )
        # any other block type (name resolution, statistics, custom, ...) is skipped


class _Prefixed(io.RawIOBase):
    """A stream that first returns already-read bytes, then the rest of ``inner``."""

    def __init__(self, head: bytes, inner: BinaryIO) -> None:
        self._head = head
        self._inner = inner

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0:
            out = self._head + self._inner.read()
            self._head = b""
            return out
        out = self._head[:n]
        self._head = self._head[n:]
        if len(out) < n:
            more = self._inner.read(n - len(out))
            if more:
                out += more
        return out


def read_capture(stream: BinaryIO) -> Iterator[CaptureRecord]:
    """Yield the records of a pcap or pcapng stream (format detected by magic)."""
    head = stream.read(4) or b""
    fmt = detect_format(head)
    joined: BinaryIO = _Prefixed(head, stream)  # type: ignore[assignment]
    if fmt is CaptureFormat.PCAPNG:
        yield from read_pcapng(joined)
    else:
        yield from read_pcap(joined)


def parse_capture(data: bytes) -> list[CaptureRecord]:
    """All records of a pcap or pcapng file held in memory."""
    return list(read_capture(io.BytesIO(data)))
