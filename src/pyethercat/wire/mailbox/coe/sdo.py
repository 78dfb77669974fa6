"""SDO messages (CoE services 2 and 3): initiate, segments and abort, both directions.

Every class has ``encode()`` returning the mailbox payload (CoE header
included); :func:`decode_sdo` is the inverse for the bytes after the CoE
header. The command specifier layout is CiA 301's SDO protocol as
IEC 61158-6-12:2019 5.6.2.1.1 carries it (SOEM ``src/ec_coe.c``, IgH
``master/fsm_coe.c``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar, Self, TypeAlias

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox.coe.header import (
    SDO_HEADER_SIZE,
    CoeService,
    check,
    coe_header_bytes,
    need,
    sdo_abort_name,
)

__all__ = [
    "SdoInitiateDownloadRequest",
    "SdoInitiateDownloadResponse",
    "SdoDownloadSegmentRequest",
    "SdoDownloadSegmentResponse",
    "SdoInitiateUploadRequest",
    "SdoInitiateUploadResponse",
    "SdoUploadSegmentRequest",
    "SdoUploadSegmentResponse",
    "SdoAbortTransfer",
    "SdoMessage",
    "check_address",
    "decode_sdo",
]

SEGMENT_MIN_DATA = 7
"""A segment frame always has room for 7 data bytes."""

# Command specifier: bits 7:5 command; initiate: bit4 complete access, bits 3:2 n,
# bit1 expedited, bit0 size indicated; segments: bit4 toggle, bits 3:1 n, bit0 last.
_CS_SIZE = 0x01
_CS_EXPEDITED = 0x02
_CS_CA = 0x10
_CS_TOGGLE = 0x10
_CS_LAST = 0x01

# client (request) command specifiers
_CCS_DOWNLOAD_SEGMENT = 0
_CCS_INITIATE_DOWNLOAD = 1
_CCS_INITIATE_UPLOAD = 2
_CCS_UPLOAD_SEGMENT = 3
_CCS_ABORT = 4
# server (response) command specifiers
_SCS_UPLOAD_SEGMENT = 0
_SCS_DOWNLOAD_SEGMENT = 1
_SCS_INITIATE_UPLOAD = 2
_SCS_INITIATE_DOWNLOAD = 3
_SCS_ABORT = 4

_SDO = struct.Struct("<BHBI")


def check_address(index: int, subindex: int) -> None:
    """Raise :class:`MailboxError` unless index and subindex fit their fields."""
    check("SDO index", index, 0xFFFF)
    check("SDO subindex", subindex, 0xFF)


@dataclass(frozen=True, slots=True)
class _SdoInitiateWithData:
    """Shared shape of an initiate download request and an initiate upload response.

    ``expedited``: data (1..4 bytes) rides in the 4-byte field. Otherwise a
    normal transfer: the field holds ``complete_size`` (the whole object, all
    segments), and ``data`` is the part carried in this frame.
    """

    index: int
    subindex: int
    data: bytes
    expedited: bool = True
    size_indicated: bool = True
    complete_size: int | None = None
    complete_access: bool = False

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_INITIATE_DOWNLOAD

    def __post_init__(self) -> None:
        check_address(self.index, self.subindex)
        object.__setattr__(self, "data", bytes(self.data))
        n = len(self.data)
        if self.expedited:
            if self.size_indicated and not 1 <= n <= 4:
                raise MailboxError(f"expedited SDO carries 1..4 bytes, got {n}")
            if not self.size_indicated and n != 4:
                raise MailboxError(
                    f"expedited SDO without size indication carries 4 bytes, got {n}"
                )
            if self.complete_size not in (None, n):
                raise MailboxError("expedited SDO: complete_size must equal len(data)")
            object.__setattr__(self, "complete_size", n)
        else:
            size = n if self.complete_size is None else self.complete_size
            check("SDO complete size", size, 0xFFFFFFFF)
            if not self.size_indicated and size != n:
                raise MailboxError(
                    "SDO without size indication: complete_size must equal len(data)"
                )
            if n > size:
                raise MailboxError(f"SDO frame carries {n} bytes, more than complete size {size}")
            object.__setattr__(self, "complete_size", size)

    @property
    def total_size(self) -> int:
        """Complete size of the object (equals len(data) for expedited transfers)."""
        assert self.complete_size is not None
        return self.complete_size

    def encode(self) -> bytes:
        """CoE header + SDO frame."""
        cs = (self.COMMAND << 5) | (_CS_CA if self.complete_access else 0)
        if self.size_indicated:
            cs |= _CS_SIZE
        if self.expedited:
            cs |= _CS_EXPEDITED
            if self.size_indicated:
                cs |= (4 - len(self.data)) << 2
            field4 = self.data.ljust(4, b"\x00")
            return (
                coe_header_bytes(self.SERVICE)
                + struct.pack("<BHB", cs, self.index, self.subindex)
                + field4
            )
        size = self.total_size if self.size_indicated else 0
        return (
            coe_header_bytes(self.SERVICE)
            + _SDO.pack(cs, self.index, self.subindex, size)
            + self.data
        )

    @classmethod
    def _decode(cls, body: bytes) -> Self:
        cs, index, subindex, size = _SDO.unpack_from(body, 0)
        ca = bool(cs & _CS_CA)
        s = bool(cs & _CS_SIZE)
        if cs & _CS_EXPEDITED:
            n = (cs >> 2) & 3 if s else 0
            return cls(index, subindex, body[4 : 8 - n], True, s, None, ca)
        data = body[8:]
        if s:
            data = data[:size]  # tolerate padding after the object
            return cls(index, subindex, data, False, True, size, ca)
        return cls(index, subindex, data, False, False, None, ca)


@dataclass(frozen=True, slots=True)
class SdoInitiateDownloadRequest(_SdoInitiateWithData):
    """Master -> slave: write an object (expedited or the first part of a normal transfer)."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_INITIATE_DOWNLOAD


@dataclass(frozen=True, slots=True)
class SdoInitiateUploadResponse(_SdoInitiateWithData):
    """Slave -> master: the object read (expedited, or the first part + complete size)."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_RESPONSE
    COMMAND: ClassVar[int] = _SCS_INITIATE_UPLOAD


@dataclass(frozen=True, slots=True)
class _SdoAddressOnly:
    """Frames that carry only index, subindex and the complete-access flag."""

    index: int
    subindex: int
    complete_access: bool = False

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_INITIATE_UPLOAD

    def __post_init__(self) -> None:
        check_address(self.index, self.subindex)

    def encode(self) -> bytes:
        """CoE header + 8-byte SDO frame."""
        cs = (self.COMMAND << 5) | (_CS_CA if self.complete_access else 0)
        return coe_header_bytes(self.SERVICE) + _SDO.pack(cs, self.index, self.subindex, 0)

    @classmethod
    def _decode(cls, body: bytes) -> Self:
        cs, index, subindex, _ = _SDO.unpack_from(body, 0)
        return cls(index, subindex, bool(cs & _CS_CA))


@dataclass(frozen=True, slots=True)
class SdoInitiateUploadRequest(_SdoAddressOnly):
    """Master -> slave: read an object."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_INITIATE_UPLOAD


@dataclass(frozen=True, slots=True)
class SdoInitiateDownloadResponse(_SdoAddressOnly):
    """Slave -> master: download accepted (expedited: done; normal: send segments)."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_RESPONSE
    COMMAND: ClassVar[int] = _SCS_INITIATE_DOWNLOAD


@dataclass(frozen=True, slots=True)
class _SdoSegmentWithData:
    """A segment carrying data: download segment request / upload segment response.

    Segments shorter than 7 bytes are padded to 7 and say how many bytes are
    unused (bits 3:1); longer ones simply make the mailbox longer.
    """

    toggle: bool
    last: bool
    data: bytes

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_DOWNLOAD_SEGMENT

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """CoE header + command byte + data (at least 7 bytes, padded)."""
        unused = max(0, SEGMENT_MIN_DATA - len(self.data))
        cs = (
            (self.COMMAND << 5)
            | (_CS_TOGGLE if self.toggle else 0)
            | (unused << 1)
            | (_CS_LAST if self.last else 0)
        )
        return coe_header_bytes(self.SERVICE) + bytes([cs]) + self.data + bytes(unused)

    @classmethod
    def _decode(cls, body: bytes) -> Self:
        cs = body[0]
        if len(body) == 1 + SEGMENT_MIN_DATA:
            # only a minimum-size frame uses the unused-bytes count (CiA 301 segment
            # protocol; SOEM ec_coe.c ecx_SDOread reads it the same way)
            data = body[1 : 1 + SEGMENT_MIN_DATA - ((cs >> 1) & 7)]
        else:
            data = body[1:]
        return cls(bool(cs & _CS_TOGGLE), bool(cs & _CS_LAST), data)


@dataclass(frozen=True, slots=True)
class SdoDownloadSegmentRequest(_SdoSegmentWithData):
    """Master -> slave: one segment of a normal download."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_DOWNLOAD_SEGMENT


@dataclass(frozen=True, slots=True)
class SdoUploadSegmentResponse(_SdoSegmentWithData):
    """Slave -> master: one segment of a normal upload."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_RESPONSE
    COMMAND: ClassVar[int] = _SCS_UPLOAD_SEGMENT


@dataclass(frozen=True, slots=True)
class _SdoToggleOnly:
    toggle: bool

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_UPLOAD_SEGMENT

    def encode(self) -> bytes:
        """CoE header + command byte + 7 reserved bytes."""
        cs = (self.COMMAND << 5) | (_CS_TOGGLE if self.toggle else 0)
        return coe_header_bytes(self.SERVICE) + bytes([cs]) + bytes(SEGMENT_MIN_DATA)

    @classmethod
    def _decode(cls, body: bytes) -> Self:
        return cls(bool(body[0] & _CS_TOGGLE))


@dataclass(frozen=True, slots=True)
class SdoUploadSegmentRequest(_SdoToggleOnly):
    """Master -> slave: send the next upload segment."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_REQUEST
    COMMAND: ClassVar[int] = _CCS_UPLOAD_SEGMENT


@dataclass(frozen=True, slots=True)
class SdoDownloadSegmentResponse(_SdoToggleOnly):
    """Slave -> master: download segment received (echoes the toggle)."""

    SERVICE: ClassVar[CoeService] = CoeService.SDO_RESPONSE
    COMMAND: ClassVar[int] = _SCS_DOWNLOAD_SEGMENT


@dataclass(frozen=True, slots=True)
class SdoAbortTransfer:
    """Abort an SDO transfer (either side). Sent in service 2 (SDO request) by default."""

    index: int
    subindex: int
    code: int
    service: CoeService = CoeService.SDO_REQUEST

    def __post_init__(self) -> None:
        check_address(self.index, self.subindex)
        check("SDO abort code", self.code, 0xFFFFFFFF)
        if self.service not in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE):
            raise MailboxError(f"SDO abort travels in service 2 or 3, not {self.service}")

    @property
    def name(self) -> str:
        """Text of the abort code."""
        return sdo_abort_name(self.code)

    def to_error(self) -> SdoAbort:
        """The :class:`pyethercat.errors.SdoAbort` exception for this abort."""
        return SdoAbort(self.code, self.name, self.index, self.subindex)

    def encode(self) -> bytes:
        """CoE header + 8-byte SDO frame with the abort code in bytes 4-7."""
        return coe_header_bytes(self.service) + _SDO.pack(
            _CCS_ABORT << 5, self.index, self.subindex, self.code
        )

SdoMessage: TypeAlias = (
    SdoInitiateDownloadRequest
    | SdoInitiateDownloadResponse
    | SdoDownloadSegmentRequest
    | SdoDownloadSegmentResponse
    | SdoInitiateUploadRequest
    | SdoInitiateUploadResponse
    | SdoUploadSegmentRequest
    | SdoUploadSegmentResponse
    | SdoAbortTransfer
)


def decode_sdo(service: CoeService | int, body: bytes) -> SdoMessage:
    """Typed SDO message from the bytes after the CoE header of service 2 or 3."""
    need(body, SDO_HEADER_SIZE, "SDO frame")
    command = body[0] >> 5
    if command == _CCS_ABORT:  # same value for both directions
        _, index, subindex, code = _SDO.unpack_from(body, 0)
        return SdoAbortTransfer(index, subindex, code, CoeService(service))
    if service == CoeService.SDO_REQUEST:
        if command == _CCS_INITIATE_DOWNLOAD:
            return SdoInitiateDownloadRequest._decode(body)
        if command == _CCS_DOWNLOAD_SEGMENT:
            return SdoDownloadSegmentRequest._decode(body)
        if command == _CCS_INITIATE_UPLOAD:
            return SdoInitiateUploadRequest._decode(body)
        if command == _CCS_UPLOAD_SEGMENT:
            return SdoUploadSegmentRequest._decode(body)
    else:
        if command == _SCS_INITIATE_UPLOAD:
            return SdoInitiateUploadResponse._decode(body)
        if command == _SCS_UPLOAD_SEGMENT:
            return SdoUploadSegmentResponse._decode(body)
        if command == _SCS_INITIATE_DOWNLOAD:
            return SdoInitiateDownloadResponse._decode(body)
        if command == _SCS_DOWNLOAD_SEGMENT:
            return SdoDownloadSegmentResponse._decode(body)
    kind = "request" if service == CoeService.SDO_REQUEST else "response"
    raise MailboxError(
        f"unsupported SDO {kind} command specifier 0x{body[0]:02X} (command {command})"
    )
