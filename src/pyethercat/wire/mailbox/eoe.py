"""EoE (Ethernet over EtherCAT, mailbox type 2) codecs.

Layout as SOEM ``include/soem/ec_eoe.h`` (``EOE_HDR_*``), IgH ``master/ethernet.c``
and Wireshark ``packet-ecatmb.h`` (``EoeHeaderInfoUnion``) have it.

Header (4 bytes after the mailbox header), little-endian words::

    word 1: bits 3:0 frame type, 7:4 port, 8 last fragment, 9 time appended,
            10 time requested
    word 2: fragments: bits 5:0 fragment number, 11:6 offset (32-byte units;
            fragment 0: complete size / 32), 15:12 frame number
            responses: result code

IPv4 addresses in Set/Get IP parameter (IP, subnet mask, gateway, DNS
server) are 32-bit little-endian words, so their octets are on the wire in
reverse order (192.168.0.1 as ``01 00 A8 C0``): IgH ``master/fsm_eoe.c``
writes them with ``memcpy_swap32``, SOEM/SOES with ``EOE_ip_uint32_to_byte``
(``byte_ip[3]`` = first octet), Wireshark's ``packet-ecatmb.c`` reads them
little-endian, and TwinCAT's request in the corpus capture
``ethercrab_twincat-akd-nc-mode.pcapng`` carries its mask 255.255.255.0 as
``00 FF FF FF``. ``encode()`` returns the
mailbox payload; :func:`decode_eoe` is the inverse. :func:`eoe_fragment` and
:class:`EoeReassembler` split and rebuild Ethernet frames.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from ipaddress import IPv4Address
from typing import ClassVar, TypeAlias

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.fragments import FragmentReassembler
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    "EOE_HEADER_SIZE",
    "EOE_BLOCK",
    "EoeFrameType",
    "EoeResult",
    "EOE_RESULT_NAMES",
    "eoe_result_name",
    "EoeIpFlags",
    "EoeIpParameters",
    "EoeFragment",
    "EoeTimestampResponse",
    "EoeSetIpRequest",
    "EoeSetIpResponse",
    "EoeSetAddressFilterRequest",
    "EoeSetAddressFilterResponse",
    "EoeGetIpRequest",
    "EoeGetIpResponse",
    "EoeGetAddressFilterRequest",
    "EoeGetAddressFilterResponse",
    "EoeMessage",
    "decode_eoe",
    "eoe_fragment",
    "eoe_fragment_size",
    "EoeReassembler",
]

EOE_HEADER_SIZE = 4
EOE_BLOCK = 32
"""Fragment offsets count 32-byte blocks."""
_DNS_NAME_SIZE = 32
_FIXED_IP_BODY = 4 + 6 + 4 * 4 + _DNS_NAME_SIZE  # 58 bytes, IgH/Wireshark layout
_TIME_SIZE = 4

_F_LAST = 0x0100
_F_TIME_APPENDED = 0x0200
_F_TIME_REQUESTED = 0x0400


class EoeFrameType(IntEnum):
    """EoE frame types (word 1 bits 3:0)."""

    FRAGMENT = 0
    TIMESTAMP_RESPONSE = 1
    SET_IP_REQUEST = 2  # a.k.a. init request
    SET_IP_RESPONSE = 3
    SET_ADDRESS_FILTER_REQUEST = 4
    SET_ADDRESS_FILTER_RESPONSE = 5
    GET_IP_REQUEST = 6
    GET_IP_RESPONSE = 7
    GET_ADDRESS_FILTER_REQUEST = 8
    GET_ADDRESS_FILTER_RESPONSE = 9
    INIT_REQUEST = 2
    INIT_RESPONSE = 3


class EoeResult(IntEnum):
    """EoE result codes (SOEM ``ec_eoe.h`` ``EOE_RESULT_*``)."""

    SUCCESS = 0x0000
    UNSPECIFIED_ERROR = 0x0001
    UNSUPPORTED_FRAME_TYPE = 0x0002
    NO_IP_SUPPORT = 0x0201
    DHCP_NOT_SUPPORTED = 0x0202
    NO_FILTER_SUPPORT = 0x0401


EOE_RESULT_NAMES: dict[int, str] = {
    EoeResult.SUCCESS: "success",
    EoeResult.UNSPECIFIED_ERROR: "unspecified error",
    EoeResult.UNSUPPORTED_FRAME_TYPE: "unsupported frame type",
    EoeResult.NO_IP_SUPPORT: "no IP support",
    EoeResult.DHCP_NOT_SUPPORTED: "DHCP not supported",
    EoeResult.NO_FILTER_SUPPORT: "no address filter support",
}


def eoe_result_name(code: int) -> str:
    """Name of an EoE result code."""
    return EOE_RESULT_NAMES.get(code, f"unknown EoE result 0x{code:04X}")


class EoeIpFlags(IntFlag):
    """Which fields a set-IP request carries."""

    MAC = 0x01
    IP = 0x02
    SUBNET = 0x04
    GATEWAY = 0x08
    DNS_SERVER = 0x10
    DNS_NAME = 0x20


def _check(what: str, value: int, maximum: int) -> None:
    if not 0 <= value <= maximum:
        raise MailboxError(f"EoE {what} {value} out of range 0..{maximum}")


def _word1(frame_type: int, port: int, flags: int = 0) -> int:
    return frame_type | (port << 4) | flags


def _header(frame_type: int, port: int, word2: int, flags: int = 0) -> bytes:
    return struct.pack("<HH", _word1(frame_type, port, flags), word2)


@dataclass(frozen=True, slots=True)
class EoeIpParameters:
    """Body of a set-IP request / get-IP response. ``None`` = field absent."""

    mac: bytes | None = None
    ip: IPv4Address | None = None
    subnet: IPv4Address | None = None
    gateway: IPv4Address | None = None
    dns_server: IPv4Address | None = None
    dns_name: str | None = None

    def __post_init__(self) -> None:
        if self.mac is not None:
            object.__setattr__(self, "mac", bytes(self.mac))
            if len(self.mac) != 6:
                raise MailboxError(f"EoE MAC address needs 6 bytes, got {len(self.mac)}")
        if self.dns_name is not None:
            # latin-1 maps bytes 1:1, so any name a slave sends decodes and re-encodes
            try:
                raw = self.dns_name.encode("latin-1")
            except UnicodeEncodeError:
                raise MailboxError(f"EoE DNS name {self.dns_name!r} is not latin-1") from None
            if len(raw) > _DNS_NAME_SIZE or b"\x00" in raw:
                raise MailboxError(
                    f"EoE DNS name {self.dns_name!r} longer than 32 bytes or has NUL"
                )

    @property
    def flags(self) -> EoeIpFlags:
        """Flag word for the fields present."""
        f = EoeIpFlags(0)
        for flag, value in self._fields():
            if value is not None:
                f |= flag
        return f

    def _fields(self) -> tuple[tuple[EoeIpFlags, object], ...]:
        return (
            (EoeIpFlags.MAC, self.mac),
            (EoeIpFlags.IP, self.ip),
            (EoeIpFlags.SUBNET, self.subnet),
            (EoeIpFlags.GATEWAY, self.gateway),
            (EoeIpFlags.DNS_SERVER, self.dns_server),
            (EoeIpFlags.DNS_NAME, self.dns_name),
        )

    def encode(self, *, packed: bool = False) -> bytes:
        """Flags + fields. Default: the fixed 58-byte layout (absent fields zero);
        ``packed=True``: only present fields, in order (SOEM's layout)."""
        out = bytearray(struct.pack("<I", self.flags))
        for _flag, value in self._fields():
            if value is None and packed:
                continue
            out += _field_bytes(_flag, value)
        return bytes(out)

    @classmethod
    def decode(cls, body: bytes) -> EoeIpParameters:
        """Parse either layout: 58+ bytes = fixed, otherwise packed by the flags."""
        if len(body) < 4:
            raise MailboxError(f"EoE IP parameters need 4 flag bytes, got {len(body)}")
        flags = struct.unpack_from("<I", body, 0)[0]
        fixed = len(body) >= _FIXED_IP_BODY
        if not fixed:
            need = 4 + sum(_FIELD_SIZES[f] for f in _FIELD_ORDER if flags & f)
            if len(body) < need:
                raise MailboxError(
                    f"EoE IP parameters with flags 0x{flags:02X} need {need} bytes, got {len(body)}"
                )
        pos = 4
        values: list[object] = []
        for flag in _FIELD_ORDER:
            size = _FIELD_SIZES[flag]
            present = bool(flags & flag)
            if present:
                values.append(_field_value(flag, body[pos : pos + size]))
            else:
                values.append(None)
            if present or fixed:
                pos += size
        mac, ip, subnet, gateway, dns, name = values
        return cls(
            mac if isinstance(mac, bytes) else None,
            ip if isinstance(ip, IPv4Address) else None,
            subnet if isinstance(subnet, IPv4Address) else None,
            gateway if isinstance(gateway, IPv4Address) else None,
            dns if isinstance(dns, IPv4Address) else None,
            name if isinstance(name, str) else None,
        )


_FIELD_ORDER = (
    EoeIpFlags.MAC,
    EoeIpFlags.IP,
    EoeIpFlags.SUBNET,
    EoeIpFlags.GATEWAY,
    EoeIpFlags.DNS_SERVER,
    EoeIpFlags.DNS_NAME,
)
_FIELD_SIZES = {
    EoeIpFlags.MAC: 6,
    EoeIpFlags.IP: 4,
    EoeIpFlags.SUBNET: 4,
    EoeIpFlags.GATEWAY: 4,
    EoeIpFlags.DNS_SERVER: 4,
    EoeIpFlags.DNS_NAME: _DNS_NAME_SIZE,
}


def _field_bytes(flag: EoeIpFlags, value: object) -> bytes:
    size = _FIELD_SIZES[flag]
    if value is None:
        return bytes(size)
    if isinstance(value, IPv4Address):
        return value.packed[::-1]  # a little-endian word (module text)
    if isinstance(value, str):
        return value.encode("latin-1").ljust(size, b"\x00")
    assert isinstance(value, bytes)
    return value


def _field_value(flag: EoeIpFlags, raw: bytes) -> object:
    if flag is EoeIpFlags.MAC:
        return raw
    if flag is EoeIpFlags.DNS_NAME:
        return raw.split(b"\x00", 1)[0].decode("latin-1")
    return IPv4Address(bytes(raw[::-1]))


@dataclass(frozen=True, slots=True)
class EoeFragment:
    """One fragment of an Ethernet frame (frame type 0).

    ``offset`` is in 32-byte blocks: for fragment 0 the complete frame size
    (rounded up), for later fragments the byte offset of their data.
    ``timestamp`` (a u32) may follow the data of the last fragment.
    """

    data: bytes
    fragment_number: int = 0
    offset: int = 0
    frame_number: int = 0
    last: bool = True
    port: int = 0
    timestamp: int | None = None
    time_requested: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", bytes(self.data))
        _check("fragment number", self.fragment_number, 0x3F)
        _check("fragment offset", self.offset, 0x3F)
        _check("frame number", self.frame_number, 0xF)
        _check("port", self.port, 0xF)
        if self.timestamp is not None:
            _check("timestamp", self.timestamp, 0xFFFFFFFF)
            if not self.last:
                raise MailboxError("EoE timestamp can only follow the last fragment")

    @property
    def complete_size(self) -> int | None:
        """Announced frame buffer size in bytes (fragment 0 only)."""
        return self.offset * EOE_BLOCK if self.fragment_number == 0 else None

    @property
    def byte_offset(self) -> int:
        """Byte offset of this fragment's data in the frame (0 for fragment 0)."""
        return 0 if self.fragment_number == 0 else self.offset * EOE_BLOCK

    def encode(self) -> bytes:
        """EoE header + data (+ timestamp)."""
        flags = (_F_LAST if self.last else 0) | (_F_TIME_REQUESTED if self.time_requested else 0)
        tail = b""
        if self.timestamp is not None:
            flags |= _F_TIME_APPENDED
            tail = struct.pack("<I", self.timestamp)
        word2 = self.fragment_number | (self.offset << 6) | (self.frame_number << 12)
        return _header(EoeFrameType.FRAGMENT, self.port, word2, flags) + self.data + tail


@dataclass(frozen=True, slots=True)
class _EoeResultOnly:
    result: int = EoeResult.SUCCESS
    port: int = 0

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.SET_IP_RESPONSE

    def __post_init__(self) -> None:
        _check("result", self.result, 0xFFFF)
        _check("port", self.port, 0xF)

    @property
    def result_name(self) -> str:
        """Name of the result code."""
        return eoe_result_name(self.result)

    def encode(self) -> bytes:
        """EoE header with the result in word 2."""
        return _header(self.FRAME_TYPE, self.port, self.result)


@dataclass(frozen=True, slots=True)
class EoeSetIpResponse(_EoeResultOnly):
    """Answer to a set-IP request."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.SET_IP_RESPONSE


@dataclass(frozen=True, slots=True)
class EoeSetAddressFilterResponse(_EoeResultOnly):
    """Answer to a set-address-filter request."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.SET_ADDRESS_FILTER_RESPONSE


@dataclass(frozen=True, slots=True)
class _EoePortOnly:
    port: int = 0

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.GET_IP_REQUEST

    def __post_init__(self) -> None:
        _check("port", self.port, 0xF)

    def encode(self) -> bytes:
        """EoE header only."""
        return _header(self.FRAME_TYPE, self.port, 0)


@dataclass(frozen=True, slots=True)
class EoeGetIpRequest(_EoePortOnly):
    """Ask for the IP parameters (body unverified: none sent)."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.GET_IP_REQUEST


@dataclass(frozen=True, slots=True)
class EoeGetAddressFilterRequest(_EoePortOnly):
    """Ask for the address filter (body unverified: none sent)."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.GET_ADDRESS_FILTER_REQUEST


@dataclass(frozen=True, slots=True)
class EoeSetIpRequest:
    """Set IP parameters (frame type 2). Encoded in the fixed layout unless ``packed``."""

    params: EoeIpParameters
    port: int = 0
    packed: bool = False

    def __post_init__(self) -> None:
        _check("port", self.port, 0xF)

    def encode(self) -> bytes:
        """EoE header + flags + fields."""
        return _header(EoeFrameType.SET_IP_REQUEST, self.port, 0) + self.params.encode(
            packed=self.packed
        )


@dataclass(frozen=True, slots=True)
class EoeGetIpResponse:
    """IP parameters of the slave (layout assumed equal to the set-IP body)."""

    params: EoeIpParameters
    result: int = EoeResult.SUCCESS
    port: int = 0
    packed: bool = False

    def __post_init__(self) -> None:
        _check("result", self.result, 0xFFFF)
        _check("port", self.port, 0xF)

    def encode(self) -> bytes:
        """EoE header (result in word 2) + flags + fields."""
        return _header(EoeFrameType.GET_IP_RESPONSE, self.port, self.result) + self.params.encode(
            packed=self.packed
        )


@dataclass(frozen=True, slots=True)
class _EoeRawBody:
    data: bytes = b""
    port: int = 0
    word2: int = 0

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.SET_ADDRESS_FILTER_REQUEST

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", bytes(self.data))
        _check("port", self.port, 0xF)
        _check("word 2", self.word2, 0xFFFF)

    def encode(self) -> bytes:
        """EoE header + raw body."""
        return _header(self.FRAME_TYPE, self.port, self.word2) + self.data


@dataclass(frozen=True, slots=True)
class EoeSetAddressFilterRequest(_EoeRawBody):
    """Set MAC address filters. Body kept raw (its layout is unverified)."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.SET_ADDRESS_FILTER_REQUEST


@dataclass(frozen=True, slots=True)
class EoeGetAddressFilterResponse(_EoeRawBody):
    """Address filter of the slave; ``word2`` is the result. Body kept raw."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.GET_ADDRESS_FILTER_RESPONSE


@dataclass(frozen=True, slots=True)
class EoeTimestampResponse(_EoeRawBody):
    """Timestamp response (frame type 1). Body kept raw."""

    FRAME_TYPE: ClassVar[EoeFrameType] = EoeFrameType.TIMESTAMP_RESPONSE


EoeMessage: TypeAlias = (
    EoeFragment
    | EoeTimestampResponse
    | EoeSetIpRequest
    | EoeSetIpResponse
    | EoeSetAddressFilterRequest
    | EoeSetAddressFilterResponse
    | EoeGetIpRequest
    | EoeGetIpResponse
    | EoeGetAddressFilterRequest
    | EoeGetAddressFilterResponse
)


def decode_eoe(payload: bytes | bytearray | memoryview) -> EoeMessage:
    """Typed message from an EoE mailbox payload; raises :class:`MailboxError`."""
    payload = bytes(payload)
    if len(payload) < EOE_HEADER_SIZE:
        raise MailboxError(f"EoE header needs {EOE_HEADER_SIZE} bytes, got {len(payload)}")
    w1, w2 = struct.unpack_from("<HH", payload, 0)
    ftype = w1 & 0xF
    port = (w1 >> 4) & 0xF
    body = payload[EOE_HEADER_SIZE:]
    if ftype == EoeFrameType.FRAGMENT:
        last = bool(w1 & _F_LAST)
        timestamp: int | None = None
        if w1 & _F_TIME_APPENDED and last:
            if len(body) < _TIME_SIZE:
                raise MailboxError("EoE fragment announces a timestamp but is shorter than 4 bytes")
            timestamp = struct.unpack_from("<I", body, len(body) - _TIME_SIZE)[0]
            body = body[:-_TIME_SIZE]
        return EoeFragment(
            body,
            w2 & 0x3F,
            (w2 >> 6) & 0x3F,
            w2 >> 12,
            last,
            port,
            timestamp,
            bool(w1 & _F_TIME_REQUESTED),
        )
    if ftype == EoeFrameType.SET_IP_REQUEST:
        params = EoeIpParameters.decode(body)
        return EoeSetIpRequest(params, port, packed=len(body) < _FIXED_IP_BODY)
    if ftype == EoeFrameType.SET_IP_RESPONSE:
        return EoeSetIpResponse(w2, port)
    if ftype == EoeFrameType.SET_ADDRESS_FILTER_RESPONSE:
        return EoeSetAddressFilterResponse(w2, port)
    if ftype == EoeFrameType.GET_IP_REQUEST:
        return EoeGetIpRequest(port)
    if ftype == EoeFrameType.GET_ADDRESS_FILTER_REQUEST:
        return EoeGetAddressFilterRequest(port)
    if ftype == EoeFrameType.GET_IP_RESPONSE:
        params = EoeIpParameters.decode(body)
        return EoeGetIpResponse(params, w2, port, packed=len(body) < _FIXED_IP_BODY)
    if ftype == EoeFrameType.SET_ADDRESS_FILTER_REQUEST:
        return EoeSetAddressFilterRequest(body, port, w2)
    if ftype == EoeFrameType.GET_ADDRESS_FILTER_RESPONSE:
        return EoeGetAddressFilterResponse(body, port, w2)
    if ftype == EoeFrameType.TIMESTAMP_RESPONSE:
        return EoeTimestampResponse(body, port, w2)
    raise MailboxError(f"unknown EoE frame type {ftype}")


def eoe_fragment_size(mailbox_size: int) -> int:
    """Data bytes in every fragment but the last: a multiple of 32 that fits the mailbox."""
    size = (mailbox_size - MAILBOX_HEADER_SIZE - EOE_HEADER_SIZE) // EOE_BLOCK * EOE_BLOCK
    if size < EOE_BLOCK:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for EoE fragments")
    return size


def eoe_fragment(
    frame: bytes,
    mailbox_size: int,
    frame_number: int = 0,
    *,
    port: int = 0,
    timestamp: int | None = None,
) -> list[EoeFragment]:
    """Split an Ethernet frame into EoE fragments for a mailbox of ``mailbox_size`` bytes.

    Every fragment but the last carries a multiple of 32 bytes; fragment 0
    announces the frame size (rounded up to 32), later ones their byte offset.
    Raises :class:`MailboxError` when the frame cannot be described (more than
    63 blocks or 64 fragments).
    """
    frame = bytes(frame)
    _check("frame number", frame_number, 0xF)
    chunk = eoe_fragment_size(mailbox_size)
    room_last = mailbox_size - MAILBOX_HEADER_SIZE - EOE_HEADER_SIZE
    if timestamp is not None:
        room_last -= _TIME_SIZE
    blocks = (len(frame) + EOE_BLOCK - 1) // EOE_BLOCK
    if blocks > 0x3F:
        raise MailboxError(f"Ethernet frame of {len(frame)} bytes is too long for EoE")
    parts: list[bytes] = []
    pos = 0
    while len(frame) - pos > room_last:
        # A fragment that is not the last carries a multiple of 32 bytes, also when
        # the rest would fit but for the appended timestamp (then it carries less,
        # possibly nothing, and the last one takes the rest with the timestamp).
        rest = len(frame) - pos
        take = chunk if rest > chunk else rest // EOE_BLOCK * EOE_BLOCK
        parts.append(frame[pos : pos + take])
        pos += take
        if take < chunk:
            break  # the last fragment has room for the rest and the timestamp
    parts.append(frame[pos:])
    if len(parts[-1]) > room_last:
        # (a 32-byte fragment size: a rest of 29-31 bytes and the timestamp never fit)
        raise MailboxError(f"Ethernet frame of {len(frame)} bytes and its timestamp do not "
                           f"fit EoE fragments of a {mailbox_size}-byte mailbox")
    if len(parts) > 0x40:
        raise MailboxError(f"Ethernet frame needs {len(parts)} EoE fragments, at most 64")
    out: list[EoeFragment] = []
    pos = 0
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        out.append(
            EoeFragment(
                part,
                fragment_number=i,
                offset=blocks if i == 0 else pos // EOE_BLOCK,
                frame_number=frame_number,
                last=last,
                port=port,
                timestamp=timestamp if last else None,
            )
        )
        pos += len(part)
    return out


class EoeReassembler:
    """Rebuild Ethernet frames from EoE fragments; pure, one frame at a time.

    ``feed(fragment)`` returns the complete frame after its last fragment,
    else ``None``. Fragment 0 always starts a new frame (an unfinished one is
    dropped and counted in ``dropped``). A fragment that does not continue
    the current frame (wrong fragment number, frame number or offset, or
    overflowing the announced size) raises :class:`MailboxError` and resets
    (the rules are :class:`~pyethercat.wire.mailbox.fragments.FragmentReassembler`'s).
    """

    def __init__(self) -> None:
        self._core = FragmentReassembler("EoE reassembly", key_name="frame number",
                                         sequence_name="fragment", step=1)
        self.timestamp: int | None = None
        self.port = 0

    @property
    def in_progress(self) -> bool:
        """True while a frame is partly received."""
        return self._core.in_progress

    @property
    def dropped(self) -> int:
        """Frames given up because fragment 0 of the next one came first."""
        return self._core.dropped

    def reset(self) -> None:
        """Drop any partial frame."""
        self._core.reset()

    def feed(self, fragment: EoeFragment) -> bytes | None:
        """Add one fragment."""
        first = fragment.fragment_number == 0
        if first:
            self.port = fragment.port
        # capacity 0 means the sender did not announce a size: it is not checked
        frame = self._core.feed(
            fragment.data, key=fragment.frame_number, sequence=fragment.fragment_number,
            last=fragment.last, first=first,
            offset=None if first else fragment.offset * EOE_BLOCK,
            capacity=fragment.offset * EOE_BLOCK if first else 0)
        if frame is not None:
            self.timestamp = fragment.timestamp
        return frame
