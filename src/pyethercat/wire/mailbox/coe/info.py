"""SDO information service (CoE service 8): OD list, object and entry descriptions.

Frame: CoE header, then opcode (bits 6:0) + incomplete (bit 7), a reserved
byte, fragments-left u16, then the service data. Long responses are cut into
fragments (ETG.1000.6 SDO information service; the same layout in SOEM
``src/ec_coe.c`` ``ecx_readODlist``/``ecx_readOEsingle`` and IgH
``master/fsm_coe.c``).

Each message is declared by its service data: ``LAYOUT`` is the struct format
of the leading fields (in field order), ``TAIL`` what the last field holds
(``"text"``, ``"words"`` or nothing). Encoding, decoding and range checks
follow from that; only the entry description, whose optional parts depend on
its value-info bits, adds code of its own.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import IntEnum, IntFlag
from typing import Any, ClassVar, Self, TypeAlias, cast

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox.coe.header import (
    COE_HEADER_SIZE,
    CoeHeader,
    CoeService,
    check,
    coe_header_bytes,
    need,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.fragments import FragmentReassembler
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    "SDO_INFO_HEADER_SIZE",
    "SdoInfoOpCode",
    "OdListType",
    "ObjectCode",
    "ValueInfo",
    "ObjectAccess",
    "SdoInfoGetOdListRequest",
    "SdoInfoGetOdListResponse",
    "SdoInfoGetObjectDescriptionRequest",
    "SdoInfoGetObjectDescriptionResponse",
    "SdoInfoGetEntryDescriptionRequest",
    "SdoInfoGetEntryDescriptionResponse",
    "SdoInfoError",
    "SdoInfoFragment",
    "SdoInfoMessage",
    "SdoInfoReassembler",
    "encode_sdo_info_fragments",
    "decode_sdo_info_body",
]

SDO_INFO_HEADER_SIZE = 4
"""Opcode byte, reserved byte, fragments-left word."""


class SdoInfoOpCode(IntEnum):
    """SDO information service opcodes."""

    GET_OD_LIST_REQUEST = 0x01
    GET_OD_LIST_RESPONSE = 0x02
    GET_OBJECT_DESCRIPTION_REQUEST = 0x03
    GET_OBJECT_DESCRIPTION_RESPONSE = 0x04
    GET_ENTRY_DESCRIPTION_REQUEST = 0x05
    GET_ENTRY_DESCRIPTION_RESPONSE = 0x06
    SDO_INFO_ERROR = 0x07


class OdListType(IntEnum):
    """List types of the get-OD-list service."""

    LENGTHS = 0
    ALL = 1
    RXPDO_MAPPABLE = 2
    TXPDO_MAPPABLE = 3
    BACKUP = 4
    SETTINGS = 5


class ObjectCode(IntEnum):
    """Object codes in an object description."""

    NULL = 0
    DOMAIN = 2
    DEFTYPE = 5
    DEFSTRUCT = 6
    VAR = 7
    ARRAY = 8
    RECORD = 9


class ValueInfo(IntFlag):
    """Value-info bits of the get-entry-description service."""

    ACCESS_RIGHTS = 0x01
    OBJECT_CATEGORY = 0x02
    MAPPABLE = 0x04
    UNIT_TYPE = 0x08
    DEFAULT_VALUE = 0x10
    MINIMUM_VALUE = 0x20
    MAXIMUM_VALUE = 0x40


class ObjectAccess(IntFlag):
    """Object-access bits of an entry description."""

    READ_PREOP = 0x0001
    READ_SAFEOP = 0x0002
    READ_OP = 0x0004
    WRITE_PREOP = 0x0008
    WRITE_SAFEOP = 0x0010
    WRITE_OP = 0x0020
    RXPDO_MAPPABLE = 0x0040
    TXPDO_MAPPABLE = 0x0080
    BACKUP = 0x0100
    SETTINGS = 0x0200
    READ = 0x0007
    WRITE = 0x0038
    READ_WRITE = 0x003F


# --- the declarative base ------------------------------------------------------------

_LIMITS = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF}


@dataclass(frozen=True, slots=True)
class _Spec:
    """What a message class's declaration says, worked out once per class."""

    layout: struct.Struct
    fixed: tuple[tuple[str, int], ...]  # (field name, maximum) of the leading fields
    tail: str | None  # name of the field after them


_SPECS: dict[type, _Spec] = {}


def _spec(cls: type[_InfoMessage]) -> _Spec:
    got = _SPECS.get(cls)
    if got is None:
        codes = cls.LAYOUT.lstrip("<")
        names = [f.name for f in fields(cast(Any, cls))]
        fixed = tuple(zip(names, (_LIMITS[c] for c in codes), strict=False))
        tail = names[len(codes)] if cls.TAIL and len(names) > len(codes) else None
        got = _SPECS[cls] = _Spec(struct.Struct(cls.LAYOUT), fixed, tail)
    return got


class _InfoMessage:
    """Shared behaviour of the SDO information messages (see the module text)."""

    __slots__ = ()

    OPCODE: ClassVar[SdoInfoOpCode]
    #: struct format of the leading fields, in field order
    LAYOUT: ClassVar[str]
    #: what the field after them holds: "text" (UTF-8), "words" (u16 list) or ""
    TAIL: ClassVar[str] = ""

    def __post_init__(self) -> None:
        spec = _spec(type(self))
        for name, maximum in spec.fixed:
            check(name.replace("_", " "), getattr(self, name), maximum)
        if self.TAIL == "words" and spec.tail is not None:
            words = tuple(getattr(self, spec.tail))
            object.__setattr__(self, spec.tail, words)
            for w in words:
                check("list entry", w, 0xFFFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        spec = _spec(type(self))
        return spec.layout.pack(*(getattr(self, n) for n, _ in spec.fixed)) + self._tail()

    def _tail(self) -> bytes:
        spec = _spec(type(self))
        if spec.tail is None:
            return b""
        value = getattr(self, spec.tail)
        if self.TAIL == "words":
            return struct.pack(f"<{len(value)}H", *value)
        return str(value).encode("utf-8")

    @classmethod
    def _untail(cls, head: tuple[int, ...], rest: bytes) -> tuple[Any, ...]:
        """Constructor arguments that follow the leading fields, from the bytes after them."""
        if cls.TAIL == "words":
            if len(rest) % 2:
                raise MailboxError(f"SDO information {cls.OPCODE.name}: odd length "
                                   f"{len(rest) + struct.calcsize(cls.LAYOUT)}")
            return (struct.unpack(f"<{len(rest) // 2}H", rest),)
        if cls.TAIL == "text":
            return (_text(rest),)
        return ()

    def encode(self) -> bytes:
        """Single-frame CoE payload (see :func:`encode_sdo_info_fragments` for long ones)."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> Self:
        """Parse the (reassembled) service data."""
        spec = _spec(cls)
        need(body, spec.layout.size, f"SDO information {cls.OPCODE.name.lower()}")
        head = spec.layout.unpack_from(body, 0)
        build: Callable[..., Self] = cls
        return build(*head, *cls._untail(head, bytes(body[spec.layout.size:])))


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace")


# --- the messages ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SdoInfoGetOdListRequest(_InfoMessage):
    """Ask for a list of object indices (or, list type 0, the five list lengths)."""

    list_type: int = OdListType.ALL

    OPCODE = SdoInfoOpCode.GET_OD_LIST_REQUEST
    LAYOUT = "<H"


@dataclass(frozen=True, slots=True)
class SdoInfoGetOdListResponse(_InfoMessage):
    """Object indices of one list; for list type 0 the five list lengths."""

    list_type: int
    indices: tuple[int, ...] = ()

    OPCODE = SdoInfoOpCode.GET_OD_LIST_RESPONSE
    LAYOUT = "<H"
    TAIL = "words"


@dataclass(frozen=True, slots=True)
class SdoInfoGetObjectDescriptionRequest(_InfoMessage):
    """Ask for the description of one object."""

    index: int

    OPCODE = SdoInfoOpCode.GET_OBJECT_DESCRIPTION_REQUEST
    LAYOUT = "<H"


@dataclass(frozen=True, slots=True)
class SdoInfoGetObjectDescriptionResponse(_InfoMessage):
    """Data type, maximum subindex, object code and name of an object."""

    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str = ""

    OPCODE = SdoInfoOpCode.GET_OBJECT_DESCRIPTION_RESPONSE
    LAYOUT = "<HHBB"
    TAIL = "text"


@dataclass(frozen=True, slots=True)
class SdoInfoGetEntryDescriptionRequest(_InfoMessage):
    """Ask for the description of one entry (subindex); ``value_info`` picks optional parts."""

    index: int
    subindex: int
    value_info: int = 0

    OPCODE = SdoInfoOpCode.GET_ENTRY_DESCRIPTION_REQUEST
    LAYOUT = "<HBB"


#: The optional parts of an entry description, in wire order: (value-info bit, field).
#: The unit type is a u16; default, minimum and maximum have the entry's size.
_ENTRY_OPTIONAL = (
    (ValueInfo.UNIT_TYPE, "unit_type"),
    (ValueInfo.DEFAULT_VALUE, "default_value"),
    (ValueInfo.MINIMUM_VALUE, "minimum_value"),
    (ValueInfo.MAXIMUM_VALUE, "maximum_value"),
)


@dataclass(frozen=True, slots=True)
class SdoInfoGetEntryDescriptionResponse(_InfoMessage):
    """Entry description. Optional parts are present exactly when their value-info bit is set.

    Default/minimum/maximum are raw bytes of ⌈bit_length/8⌉ bytes each.
    """

    index: int
    subindex: int
    value_info: int
    data_type: int
    bit_length: int
    object_access: int
    description: str = ""
    unit_type: int | None = None
    default_value: bytes | None = None
    minimum_value: bytes | None = None
    maximum_value: bytes | None = None

    OPCODE = SdoInfoOpCode.GET_ENTRY_DESCRIPTION_RESPONSE
    LAYOUT = "<HBBHHH"
    TAIL = "text"

    def __post_init__(self) -> None:
        _InfoMessage.__post_init__(self)
        for bit, name in _ENTRY_OPTIONAL:
            value = getattr(self, name)
            if (value is not None) != bool(self.value_info & bit):
                raise MailboxError(f"entry description: {name} present iff value-info "
                                   f"bit 0x{int(bit):02X} set")
            if value is None:
                continue
            if bit == ValueInfo.UNIT_TYPE:
                check("unit type", value, 0xFFFF)
                continue
            value = bytes(value)
            object.__setattr__(self, name, value)
            if len(value) != self.value_size:
                raise MailboxError(f"entry description: {name} has {len(value)} bytes, "
                                   f"needs {self.value_size}")

    @property
    def value_size(self) -> int:
        """Bytes of each of default/minimum/maximum: ⌈bit_length/8⌉."""
        return (self.bit_length + 7) // 8

    def _tail(self) -> bytes:
        out = b"" if self.unit_type is None else struct.pack("<H", self.unit_type)
        for value in (self.default_value, self.minimum_value, self.maximum_value):
            if value is not None:
                out += value
        return out + self.description.encode("utf-8")

    @classmethod
    def _untail(cls, head: tuple[int, ...], rest: bytes) -> tuple[Any, ...]:
        vinfo, bitlen = head[2], head[4]
        size = (bitlen + 7) // 8
        pos = 0
        parts: list[int | bytes | None] = []
        for bit, name in _ENTRY_OPTIONAL:
            if not vinfo & bit:
                parts.append(None)
                continue
            n = 2 if bit == ValueInfo.UNIT_TYPE else size
            need(rest, pos + n, f"entry description {name.replace('_', ' ')}")
            raw = rest[pos:pos + n]
            parts.append(struct.unpack("<H", raw)[0] if bit == ValueInfo.UNIT_TYPE else raw)
            pos += n
        return (_text(rest[pos:]), *parts)


@dataclass(frozen=True, slots=True)
class SdoInfoError(_InfoMessage):
    """SDO information error: an abort code."""

    code: int

    OPCODE = SdoInfoOpCode.SDO_INFO_ERROR
    LAYOUT = "<I"

    @property
    def name(self) -> str:
        """Text of the abort code."""
        return sdo_abort_name(self.code)

    def to_error(self, index: int = 0, subindex: int = 0) -> SdoAbort:
        """As a :class:`pyethercat.errors.SdoAbort` exception."""
        return SdoAbort(self.code, self.name, index, subindex)


SdoInfoMessage: TypeAlias = (
    SdoInfoGetOdListRequest
    | SdoInfoGetOdListResponse
    | SdoInfoGetObjectDescriptionRequest
    | SdoInfoGetObjectDescriptionResponse
    | SdoInfoGetEntryDescriptionRequest
    | SdoInfoGetEntryDescriptionResponse
    | SdoInfoError
)

_INFO_CLASSES: dict[int, type[SdoInfoMessage]] = {
    cls.OPCODE: cls
    for cls in (
        SdoInfoGetOdListRequest,
        SdoInfoGetOdListResponse,
        SdoInfoGetObjectDescriptionRequest,
        SdoInfoGetObjectDescriptionResponse,
        SdoInfoGetEntryDescriptionRequest,
        SdoInfoGetEntryDescriptionResponse,
        SdoInfoError,
    )
}


# --- fragments ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SdoInfoFragment:
    """One SDO-information frame that is part of a fragmented response.

    :func:`~pyethercat.wire.mailbox.coe.decode_coe` returns this when the
    incomplete bit is set; feed the raw payloads of a fragmented response to
    :class:`SdoInfoReassembler`.
    """

    opcode: int
    incomplete: bool
    fragments_left: int
    data: bytes

    def __post_init__(self) -> None:
        check("SDO info opcode", self.opcode, 0x7F)
        check("fragments left", self.fragments_left, 0xFFFF)
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """CoE header + SDO info header + this fragment's data."""
        return (
            coe_header_bytes(CoeService.SDO_INFORMATION)
            + struct.pack("<BBH", self.opcode | (0x80 if self.incomplete else 0), 0,
                          self.fragments_left)
            + self.data
        )

    @classmethod
    def from_payload(cls, payload: bytes | bytearray | memoryview) -> SdoInfoFragment:
        """Parse a CoE payload of service 8 into its header fields and raw data."""
        header = CoeHeader.decode(payload)
        if header.service != CoeService.SDO_INFORMATION:
            raise MailboxError(f"expected CoE service 8 (SDO information), got {header.service}")
        need(payload, COE_HEADER_SIZE + SDO_INFO_HEADER_SIZE, "SDO information header")
        op, _res, left = struct.unpack_from("<BBH", payload, COE_HEADER_SIZE)
        return cls(op & 0x7F, bool(op & 0x80), left,
                   bytes(payload[COE_HEADER_SIZE + SDO_INFO_HEADER_SIZE:]))


def _info_frame(opcode: int, body: bytes) -> bytes:
    return SdoInfoFragment(opcode, False, 0, body).encode()


def decode_sdo_info_body(opcode: int, body: bytes) -> SdoInfoMessage:
    """Typed SDO-information message from an opcode and its complete service data."""
    cls = _INFO_CLASSES.get(opcode)
    if cls is None:
        raise MailboxError(f"unknown SDO information opcode 0x{opcode:02X}")
    return cls.from_body(bytes(body))


def encode_sdo_info_fragments(message: SdoInfoMessage, mailbox_size: int) -> list[bytes]:
    """CoE payloads of ``message`` split to fit a mailbox of ``mailbox_size`` bytes.

    Every fragment but the last has the incomplete bit set; fragments-left
    counts down to 0. Fragment data is cut at even lengths so OD-list words
    are not split across frames.
    """
    room = mailbox_size - MAILBOX_HEADER_SIZE - COE_HEADER_SIZE - SDO_INFO_HEADER_SIZE
    room &= ~1
    if room < 2:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for SDO information")
    body = message.body()
    chunks = [body[i : i + room] for i in range(0, len(body), room)] or [b""]
    count = len(chunks)
    if count - 1 > 0xFFFF:
        raise MailboxError(f"SDO information response needs {count} fragments, too many")
    return [
        SdoInfoFragment(message.OPCODE, i < count - 1, count - 1 - i, chunk).encode()
        for i, chunk in enumerate(chunks)
    ]


class SdoInfoReassembler:
    """Collect the fragments of one SDO-information response; pure, no clock.

    ``feed(payload)`` takes the raw CoE payload (service 8) and returns the
    typed message once the last fragment arrived, else ``None``. A broken
    sequence (opcode changes, fragments-left does not count down by one)
    raises :class:`MailboxError` and resets (the rules are
    :class:`~pyethercat.wire.mailbox.fragments.FragmentReassembler`'s). An SDO
    info error ends the transfer at any time.
    """

    def __init__(self) -> None:
        self._core = FragmentReassembler("SDO information", key_name="opcode",
                                         sequence_name="fragments-left", step=-1)

    @property
    def in_progress(self) -> bool:
        """True while fragments are outstanding."""
        return self._core.in_progress

    def reset(self) -> None:
        """Forget any partial response."""
        self._core.reset()

    def feed(self, payload: bytes | bytearray | memoryview) -> SdoInfoMessage | None:
        """Add one frame; returns the complete message or ``None``."""
        frag = SdoInfoFragment.from_payload(payload)
        if frag.opcode == SdoInfoOpCode.SDO_INFO_ERROR:
            self.reset()
            return decode_sdo_info_body(frag.opcode, frag.data)
        body = self._core.feed(frag.data, key=frag.opcode, sequence=frag.fragments_left,
                               last=not frag.incomplete)
        if body is None:
            return None
        return decode_sdo_info_body(frag.opcode, body)
