"""CoE (CANopen over EtherCAT) codecs: CoE header, SDO, SDO information, emergency.

Every message class has ``encode()`` returning the mailbox *payload* (CoE
header included, mailbox header excluded); :func:`decode_coe` is the inverse.
Wrap a payload with :func:`pyethercat.wire.mailbox.header.encode_mailbox`.

Pure state machines for multi-frame SDO transfers live at the end of the
module: clients (master side) and servers (slave side), in the h11 style:
messages in, the next message (or a completion event) out.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import ClassVar, Self, TypeAlias

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.mailbox.datatypes import (
    DATA_TYPE_BITS,
    TYPE_NAMES,
    DataType,
    Value,
    decode_value,
    encode_value,
    format_value,
    parse_type_name,
    parse_value,
)
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = [
    # header
    "COE_HEADER_SIZE",
    "SDO_HEADER_SIZE",
    "CoeService",
    "CoeHeader",
    # aborts
    "SdoAbortCode",
    "SDO_ABORT_CODES",
    "sdo_abort_name",
    # SDO messages
    "SdoInitiateDownloadRequest",
    "SdoInitiateDownloadResponse",
    "SdoDownloadSegmentRequest",
    "SdoDownloadSegmentResponse",
    "SdoInitiateUploadRequest",
    "SdoInitiateUploadResponse",
    "SdoUploadSegmentRequest",
    "SdoUploadSegmentResponse",
    "SdoAbortTransfer",
    "CoePdo",
    "Emergency",
    "EMERGENCY_ERROR_CLASSES",
    "emergency_error_name",
    "ErrorRegister",
    # SDO information
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
    "SdoInfoReassembler",
    "encode_sdo_info_fragments",
    "decode_sdo_info_body",
    # decode
    "CoeMessage",
    "SdoInfoMessage",
    "decode_coe",
    # transfers
    "sdo_initiate_max_data",
    "sdo_segment_max_data",
    "SdoTransferDone",
    "SdoUploadClient",
    "SdoDownloadClient",
    "SdoUploadServer",
    "SdoDownloadServer",
    "SdoDownloadEvent",
    # data types (re-exported from datatypes)
    "DataType",
    "DATA_TYPE_BITS",
    "TYPE_NAMES",
    "Value",
    "encode_value",
    "decode_value",
    "parse_type_name",
    "parse_value",
    "format_value",
]

COE_HEADER_SIZE = 2
"""CoE header bytes (after the mailbox header)."""
SDO_HEADER_SIZE = 8
"""Command byte + index + subindex + 4-byte data/size field."""
SDO_INFO_HEADER_SIZE = 4
"""Opcode byte, reserved byte, fragments-left word."""
_SEGMENT_MIN_DATA = 7  # a segment frame always has room for 7 data bytes


# --- CoE header ----------------------------------------------------------------


class CoeService(IntEnum):
    """CoE service (CoE header bits 15:12)."""

    EMERGENCY = 1
    SDO_REQUEST = 2
    SDO_RESPONSE = 3
    TXPDO = 4
    RXPDO = 5
    TXPDO_REMOTE_REQUEST = 6
    RXPDO_REMOTE_REQUEST = 7
    SDO_INFORMATION = 8


@dataclass(frozen=True, slots=True)
class CoeHeader:
    """The 2-byte CoE header: number (bits 8:0) and service (bits 15:12)."""

    service: CoeService | int
    number: int = 0

    def __post_init__(self) -> None:
        _check("CoE number", self.number, 0x1FF)
        _check("CoE service", int(self.service), 0xF)

    def encode(self) -> bytes:
        """The two header bytes."""
        return struct.pack("<H", self.number | (int(self.service) << 12))

    @classmethod
    def decode(cls, payload: bytes | bytearray | memoryview) -> CoeHeader:
        """Parse the first two bytes of a CoE payload."""
        if len(payload) < COE_HEADER_SIZE:
            raise MailboxError(f"CoE header needs 2 bytes, got {len(payload)}")
        word = payload[0] | (payload[1] << 8)
        # Both fields come out of bit masks: no range checks needed (hot path).
        hdr = object.__new__(cls)
        object.__setattr__(hdr, "service", _SERVICES.get(word >> 12, word >> 12))
        object.__setattr__(hdr, "number", word & 0x1FF)
        return hdr


#: Known CoE services by value (cheaper than the enum call).
_SERVICES: dict[int, CoeService | int] = {s.value: s for s in CoeService}


def _coe_header(service: CoeService | int) -> bytes:
    """The CoE header bytes of a service with number 0 (the SDO and SDO info frames)."""
    got = _HEADER_BYTES.get(service)
    if got is None:
        got = CoeHeader(service).encode()
    return got


_HEADER_BYTES: dict[CoeService | int, bytes] = {
    s: struct.pack("<H", int(s) << 12) for s in CoeService}


def _check(what: str, value: int, maximum: int, minimum: int = 0) -> None:
    if not minimum <= value <= maximum:
        raise MailboxError(f"{what} {value} out of range {minimum}..{maximum}")


# --- SDO abort codes -------------------------------------------------------------


class SdoAbortCode(IntEnum):
    """SDO abort codes (facts sheet 7.5)."""

    TOGGLE_BIT = 0x05030000
    TIMEOUT = 0x05040000
    INVALID_COMMAND = 0x05040001
    INVALID_BLOCK_SIZE = 0x05040002
    INVALID_SEQUENCE = 0x05040003
    CRC_ERROR = 0x05040004
    OUT_OF_MEMORY = 0x05040005
    UNSUPPORTED_ACCESS = 0x06010000
    WRITE_ONLY = 0x06010001
    READ_ONLY = 0x06010002
    SUBINDEX_WRITE = 0x06010003
    CA_VARIABLE_LENGTH = 0x06010004
    OBJECT_TOO_LONG = 0x06010005
    MAPPED_TO_RXPDO = 0x06010006
    NO_OBJECT = 0x06020000
    NOT_MAPPABLE = 0x06040041
    PDO_LENGTH_EXCEEDED = 0x06040042
    PARAMETER_INCOMPATIBLE = 0x06040043
    INTERNAL_INCOMPATIBLE = 0x06040047
    HARDWARE_ERROR = 0x06060000
    LENGTH_MISMATCH = 0x06070010
    LENGTH_TOO_HIGH = 0x06070012
    LENGTH_TOO_LOW = 0x06070013
    NO_SUBINDEX = 0x06090011
    VALUE_RANGE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    MODULE_LIST_MISMATCH = 0x06090033
    MAX_LESS_THAN_MIN = 0x06090036
    RESOURCE_UNAVAILABLE = 0x060A0023
    GENERAL_ERROR = 0x08000000
    TRANSFER_FAILED = 0x08000020
    LOCAL_CONTROL = 0x08000021
    DEVICE_STATE = 0x08000022
    NO_OD = 0x08000023
    NO_DATA = 0x08000024


SDO_ABORT_CODES: dict[int, str] = {
    SdoAbortCode.TOGGLE_BIT: "toggle bit not changed",
    SdoAbortCode.TIMEOUT: "SDO protocol timeout",
    SdoAbortCode.INVALID_COMMAND: "client/server command specifier not valid or unknown",
    SdoAbortCode.INVALID_BLOCK_SIZE: "invalid block size (block mode only)",
    SdoAbortCode.INVALID_SEQUENCE: "invalid sequence number (block mode only)",
    SdoAbortCode.CRC_ERROR: "CRC error (block mode only)",
    SdoAbortCode.OUT_OF_MEMORY: "out of memory",
    SdoAbortCode.UNSUPPORTED_ACCESS: "unsupported access to an object",
    SdoAbortCode.WRITE_ONLY: "attempt to read a write-only object",
    SdoAbortCode.READ_ONLY: "attempt to write a read-only object",
    SdoAbortCode.SUBINDEX_WRITE: "subindex cannot be written, SI0 must be 0 for write access",
    SdoAbortCode.CA_VARIABLE_LENGTH: "SDO complete access not supported for objects of variable length",
    SdoAbortCode.OBJECT_TOO_LONG: "object length exceeds mailbox size",
    SdoAbortCode.MAPPED_TO_RXPDO: "object mapped to RxPDO, SDO download blocked",
    SdoAbortCode.NO_OBJECT: "object does not exist in the object dictionary",
    SdoAbortCode.NOT_MAPPABLE: "object cannot be mapped into the PDO",
    SdoAbortCode.PDO_LENGTH_EXCEEDED: "number and length of mapped objects would exceed PDO length",
    SdoAbortCode.PARAMETER_INCOMPATIBLE: "general parameter incompatibility",
    SdoAbortCode.INTERNAL_INCOMPATIBLE: "general internal incompatibility in the device",
    SdoAbortCode.HARDWARE_ERROR: "access failed due to a hardware error",
    SdoAbortCode.LENGTH_MISMATCH: "data type does not match, length of service parameter does not match",
    SdoAbortCode.LENGTH_TOO_HIGH: "data type does not match, length of service parameter too high",
    SdoAbortCode.LENGTH_TOO_LOW: "data type does not match, length of service parameter too low",
    SdoAbortCode.NO_SUBINDEX: "subindex does not exist",
    SdoAbortCode.VALUE_RANGE: "value range of parameter exceeded",
    SdoAbortCode.VALUE_TOO_HIGH: "value of parameter written too high",
    SdoAbortCode.VALUE_TOO_LOW: "value of parameter written too low",
    SdoAbortCode.MODULE_LIST_MISMATCH: "module list mismatch",
    SdoAbortCode.MAX_LESS_THAN_MIN: "maximum value is less than minimum value",
    SdoAbortCode.RESOURCE_UNAVAILABLE: "resource not available",
    SdoAbortCode.GENERAL_ERROR: "general error",
    SdoAbortCode.TRANSFER_FAILED: "data cannot be transferred or stored to the application",
    SdoAbortCode.LOCAL_CONTROL: "data cannot be transferred or stored to the application because of local control",
    SdoAbortCode.DEVICE_STATE: "data cannot be transferred or stored to the application because of the present device state",
    SdoAbortCode.NO_OD: "object dictionary dynamic generation failed or no object dictionary present",
    SdoAbortCode.NO_DATA: "no data available",
}


def sdo_abort_name(code: int) -> str:
    """Text of an SDO abort code ("unknown SDO abort code 0x..." if not in the table)."""
    return SDO_ABORT_CODES.get(code, f"unknown SDO abort code 0x{code:08X}")


# --- SDO messages ------------------------------------------------------------------

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


def _check_address(index: int, subindex: int) -> None:
    _check("SDO index", index, 0xFFFF)
    _check("SDO subindex", subindex, 0xFF)


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
        _check_address(self.index, self.subindex)
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
            _check("SDO complete size", size, 0xFFFFFFFF)
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
                _coe_header(self.SERVICE)
                + struct.pack("<BHB", cs, self.index, self.subindex)
                + field4
            )
        size = self.total_size if self.size_indicated else 0
        return (
            _coe_header(self.SERVICE)
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
        _check_address(self.index, self.subindex)

    def encode(self) -> bytes:
        """CoE header + 8-byte SDO frame."""
        cs = (self.COMMAND << 5) | (_CS_CA if self.complete_access else 0)
        return _coe_header(self.SERVICE) + _SDO.pack(cs, self.index, self.subindex, 0)

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
        unused = max(0, _SEGMENT_MIN_DATA - len(self.data))
        cs = (
            (self.COMMAND << 5)
            | (_CS_TOGGLE if self.toggle else 0)
            | (unused << 1)
            | (_CS_LAST if self.last else 0)
        )
        return _coe_header(self.SERVICE) + bytes([cs]) + self.data + bytes(unused)

    @classmethod
    def _decode(cls, body: bytes) -> Self:
        cs = body[0]
        if len(body) == 1 + _SEGMENT_MIN_DATA:
            # only a minimum-size frame uses the unused-bytes count (facts 7.4)
            data = body[1 : 1 + _SEGMENT_MIN_DATA - ((cs >> 1) & 7)]
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
        return _coe_header(self.SERVICE) + bytes([cs]) + bytes(_SEGMENT_MIN_DATA)

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
        _check_address(self.index, self.subindex)
        _check("SDO abort code", self.code, 0xFFFFFFFF)
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
        return _coe_header(self.service) + _SDO.pack(
            _CCS_ABORT << 5, self.index, self.subindex, self.code
        )


# --- PDO over mailbox, emergency -------------------------------------------------


@dataclass(frozen=True, slots=True)
class CoePdo:
    """TxPDO/RxPDO (services 4/5) or their remote requests (6/7, no data)."""

    service: CoeService
    number: int
    data: bytes = b""

    def __post_init__(self) -> None:
        if self.service not in _PDO_SERVICES:
            raise MailboxError(f"CoE service {self.service} is not a PDO service")
        _check("PDO number", self.number, 0x1FF)
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """CoE header + PDO data."""
        return CoeHeader(self.service, self.number).encode() + self.data


_PDO_SERVICES = (
    CoeService.TXPDO,
    CoeService.RXPDO,
    CoeService.TXPDO_REMOTE_REQUEST,
    CoeService.RXPDO_REMOTE_REQUEST,
)


class ErrorRegister(IntFlag):
    """Object 0x1001 error register bits (also byte 2 of an emergency)."""

    GENERIC = 0x01
    CURRENT = 0x02
    VOLTAGE = 0x04
    TEMPERATURE = 0x08
    COMMUNICATION = 0x10
    DEVICE_PROFILE = 0x20
    RESERVED = 0x40
    MANUFACTURER = 0x80


# CiA 301 emergency error code classes. Lookup goes exact, then xx00, then x000.
EMERGENCY_ERROR_CLASSES: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2000: "current",
    0x2100: "current, device input side",
    0x2200: "current inside the device",
    0x2300: "current, device output side",
    0x3000: "voltage",
    0x3100: "mains voltage",
    0x3200: "voltage inside the device",
    0x3300: "output voltage",
    0x4000: "temperature",
    0x4100: "ambient temperature",
    0x4200: "device temperature",
    0x5000: "device hardware",
    0x6000: "device software",
    0x6100: "internal software",
    0x6200: "user software",
    0x6300: "data set",
    0x7000: "additional modules",
    0x8000: "monitoring",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x9000: "external error",
    0xF000: "additional functions",
    0xFF00: "device specific",
}


def emergency_error_name(code: int) -> str:
    """Class name of a CANopen emergency error code (most specific match)."""
    for key in (code, code & 0xFFF0, code & 0xFF00, code & 0xF000):
        if key in EMERGENCY_ERROR_CLASSES:
            return EMERGENCY_ERROR_CLASSES[key]
    return f"unknown emergency error code 0x{code:04X}"


@dataclass(frozen=True, slots=True)
class Emergency:
    """CoE emergency (service 1): error code, error register, 5 manufacturer bytes."""

    error_code: int
    error_register: int = 0
    data: bytes = bytes(5)

    def __post_init__(self) -> None:
        _check("emergency error code", self.error_code, 0xFFFF)
        _check("emergency error register", self.error_register, 0xFF)
        object.__setattr__(self, "data", bytes(self.data))
        if len(self.data) != 5:
            raise MailboxError(f"emergency data is 5 bytes, got {len(self.data)}")

    @property
    def name(self) -> str:
        """Error class name from the CANopen table."""
        return emergency_error_name(self.error_code)

    def encode(self) -> bytes:
        """CoE header + 8 bytes."""
        return (
            _coe_header(CoeService.EMERGENCY)
            + struct.pack("<HB", self.error_code, self.error_register)
            + self.data
        )


# --- SDO information -------------------------------------------------------------


class SdoInfoOpCode(IntEnum):
    """SDO information service opcodes (facts 7.6)."""

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


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", errors="replace")


@dataclass(frozen=True, slots=True)
class SdoInfoGetOdListRequest:
    """Ask for a list of object indices (or, list type 0, the five list lengths)."""

    list_type: int = OdListType.ALL

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_OD_LIST_REQUEST

    def __post_init__(self) -> None:
        _check("OD list type", self.list_type, 0xFFFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack("<H", self.list_type)

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetOdListRequest:
        """Parse the service data."""
        _need(body, 2, "get OD list request")
        return cls(struct.unpack_from("<H", body, 0)[0])


@dataclass(frozen=True, slots=True)
class SdoInfoGetOdListResponse:
    """Object indices of one list; for list type 0 the five list lengths."""

    list_type: int
    indices: tuple[int, ...] = ()

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_OD_LIST_RESPONSE

    def __post_init__(self) -> None:
        _check("OD list type", self.list_type, 0xFFFF)
        object.__setattr__(self, "indices", tuple(self.indices))
        for i in self.indices:
            _check("OD list entry", i, 0xFFFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack(f"<H{len(self.indices)}H", self.list_type, *self.indices)

    def encode(self) -> bytes:
        """Single-frame CoE payload (see :func:`encode_sdo_info_fragments` for long lists)."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetOdListResponse:
        """Parse the (reassembled) service data."""
        _need(body, 2, "get OD list response")
        if len(body) % 2:
            raise MailboxError(f"get OD list response has odd length {len(body)}")
        words = struct.unpack(f"<{len(body) // 2}H", body)
        return cls(words[0], tuple(words[1:]))


@dataclass(frozen=True, slots=True)
class SdoInfoGetObjectDescriptionRequest:
    """Ask for the description of one object."""

    index: int

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_OBJECT_DESCRIPTION_REQUEST

    def __post_init__(self) -> None:
        _check("object index", self.index, 0xFFFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack("<H", self.index)

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetObjectDescriptionRequest:
        """Parse the service data."""
        _need(body, 2, "get object description request")
        return cls(struct.unpack_from("<H", body, 0)[0])


@dataclass(frozen=True, slots=True)
class SdoInfoGetObjectDescriptionResponse:
    """Data type, maximum subindex, object code and name of an object."""

    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str = ""

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_OBJECT_DESCRIPTION_RESPONSE

    def __post_init__(self) -> None:
        _check("object index", self.index, 0xFFFF)
        _check("data type", self.data_type, 0xFFFF)
        _check("max subindex", self.max_subindex, 0xFF)
        _check("object code", self.object_code, 0xFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack(
            "<HHBB", self.index, self.data_type, self.max_subindex, self.object_code
        ) + self.name.encode("utf-8")

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetObjectDescriptionResponse:
        """Parse the (reassembled) service data."""
        _need(body, 6, "get object description response")
        index, dtype, maxsub, code = struct.unpack_from("<HHBB", body, 0)
        return cls(index, dtype, maxsub, code, _text(body[6:]))


@dataclass(frozen=True, slots=True)
class SdoInfoGetEntryDescriptionRequest:
    """Ask for the description of one entry (subindex); ``value_info`` picks optional parts."""

    index: int
    subindex: int
    value_info: int = 0

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_ENTRY_DESCRIPTION_REQUEST

    def __post_init__(self) -> None:
        _check_address(self.index, self.subindex)
        _check("value info", self.value_info, 0xFF)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack("<HBB", self.index, self.subindex, self.value_info)

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetEntryDescriptionRequest:
        """Parse the service data."""
        _need(body, 4, "get entry description request")
        return cls(*struct.unpack_from("<HBB", body, 0))


@dataclass(frozen=True, slots=True)
class SdoInfoGetEntryDescriptionResponse:
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

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.GET_ENTRY_DESCRIPTION_RESPONSE

    def __post_init__(self) -> None:
        _check_address(self.index, self.subindex)
        _check("value info", self.value_info, 0xFF)
        _check("data type", self.data_type, 0xFFFF)
        _check("bit length", self.bit_length, 0xFFFF)
        _check("object access", self.object_access, 0xFFFF)
        if (self.unit_type is not None) != bool(self.value_info & ValueInfo.UNIT_TYPE):
            raise MailboxError("entry description: unit_type present iff value-info bit 3 set")
        if self.unit_type is not None:
            _check("unit type", self.unit_type, 0xFFFF)
        size = self.value_size
        for bit, name in (
            (ValueInfo.DEFAULT_VALUE, "default_value"),
            (ValueInfo.MINIMUM_VALUE, "minimum_value"),
            (ValueInfo.MAXIMUM_VALUE, "maximum_value"),
        ):
            value = getattr(self, name)
            if (value is not None) != bool(self.value_info & bit):
                raise MailboxError(f"entry description: {name} present iff value-info bit set")
            if value is not None:
                value = bytes(value)
                object.__setattr__(self, name, value)
                if len(value) != size:
                    raise MailboxError(
                        f"entry description: {name} has {len(value)} bytes, needs {size}"
                    )

    @property
    def value_size(self) -> int:
        """Bytes of each of default/minimum/maximum: ⌈bit_length/8⌉."""
        return (self.bit_length + 7) // 8

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        out = struct.pack(
            "<HBBHHH",
            self.index,
            self.subindex,
            self.value_info,
            self.data_type,
            self.bit_length,
            self.object_access,
        )
        if self.unit_type is not None:
            out += struct.pack("<H", self.unit_type)
        for value in (self.default_value, self.minimum_value, self.maximum_value):
            if value is not None:
                out += value
        return out + self.description.encode("utf-8")

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoGetEntryDescriptionResponse:
        """Parse the (reassembled) service data."""
        _need(body, 10, "get entry description response")
        index, sub, vinfo, dtype, bitlen, access = struct.unpack_from("<HBBHHH", body, 0)
        pos = 10
        unit: int | None = None
        if vinfo & ValueInfo.UNIT_TYPE:
            _need(body, pos + 2, "entry description unit type")
            unit = struct.unpack_from("<H", body, pos)[0]
            pos += 2
        size = (bitlen + 7) // 8
        values: list[bytes | None] = []
        for bit in (ValueInfo.DEFAULT_VALUE, ValueInfo.MINIMUM_VALUE, ValueInfo.MAXIMUM_VALUE):
            if vinfo & bit:
                _need(body, pos + size, "entry description value field")
                values.append(body[pos : pos + size])
                pos += size
            else:
                values.append(None)
        return cls(
            index,
            sub,
            vinfo,
            dtype,
            bitlen,
            access,
            _text(body[pos:]),
            unit,
            values[0],
            values[1],
            values[2],
        )


@dataclass(frozen=True, slots=True)
class SdoInfoError:
    """SDO information error: an abort code."""

    code: int

    OPCODE: ClassVar[SdoInfoOpCode] = SdoInfoOpCode.SDO_INFO_ERROR

    def __post_init__(self) -> None:
        _check("SDO info abort code", self.code, 0xFFFFFFFF)

    @property
    def name(self) -> str:
        """Text of the abort code."""
        return sdo_abort_name(self.code)

    def to_error(self, index: int = 0, subindex: int = 0) -> SdoAbort:
        """As a :class:`pyethercat.errors.SdoAbort` exception."""
        return SdoAbort(self.code, self.name, index, subindex)

    def body(self) -> bytes:
        """Service data after the SDO info header."""
        return struct.pack("<I", self.code)

    def encode(self) -> bytes:
        """Single-frame CoE payload."""
        return _info_frame(self.OPCODE, self.body())

    @classmethod
    def from_body(cls, body: bytes) -> SdoInfoError:
        """Parse the service data."""
        _need(body, 4, "SDO info error")
        return cls(struct.unpack_from("<I", body, 0)[0])


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


@dataclass(frozen=True, slots=True)
class SdoInfoFragment:
    """One SDO-information frame that is part of a fragmented response.

    :func:`decode_coe` returns this when the incomplete bit is set; feed the raw
    payloads of a fragmented response to :class:`SdoInfoReassembler`.
    """

    opcode: int
    incomplete: bool
    fragments_left: int
    data: bytes

    def __post_init__(self) -> None:
        _check("SDO info opcode", self.opcode, 0x7F)
        _check("fragments left", self.fragments_left, 0xFFFF)
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """CoE header + SDO info header + this fragment's data."""
        return (
            _coe_header(CoeService.SDO_INFORMATION)
            + struct.pack(
                "<BBH",
                self.opcode | (0x80 if self.incomplete else 0),
                0,
                self.fragments_left,
            )
            + self.data
        )

    @classmethod
    def from_payload(cls, payload: bytes | bytearray | memoryview) -> SdoInfoFragment:
        """Parse a CoE payload of service 8 into its header fields and raw data."""
        header = CoeHeader.decode(payload)
        if header.service != CoeService.SDO_INFORMATION:
            raise MailboxError(f"expected CoE service 8 (SDO information), got {header.service}")
        _need(payload, COE_HEADER_SIZE + SDO_INFO_HEADER_SIZE, "SDO information header")
        op, _res, left = struct.unpack_from("<BBH", payload, COE_HEADER_SIZE)
        return cls(op & 0x7F, bool(op & 0x80), left, bytes(payload[6:]))


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
    sequence (opcode changes, fragments-left does not count down) raises
    :class:`MailboxError` and resets. An SDO info error ends the transfer at
    any time.
    """

    def __init__(self) -> None:
        self._opcode: int | None = None
        self._left = 0
        self._parts: list[bytes] = []

    @property
    def in_progress(self) -> bool:
        """True while fragments are outstanding."""
        return self._opcode is not None

    def reset(self) -> None:
        """Forget any partial response."""
        self._opcode = None
        self._left = 0
        self._parts = []

    def feed(self, payload: bytes | bytearray | memoryview) -> SdoInfoMessage | None:
        """Add one frame; returns the complete message or ``None``."""
        frag = SdoInfoFragment.from_payload(payload)
        if frag.opcode == SdoInfoOpCode.SDO_INFO_ERROR:
            self.reset()
            return decode_sdo_info_body(frag.opcode, frag.data)
        if self._opcode is None:
            self._opcode = frag.opcode
        else:
            try:
                if frag.opcode != self._opcode:
                    raise MailboxError(
                        f"SDO information fragment with opcode 0x{frag.opcode:02X}"
                        f" inside a 0x{self._opcode:02X} response"
                    )
                if frag.fragments_left != self._left - 1:
                    raise MailboxError(
                        f"SDO information fragments-left {frag.fragments_left},"
                        f" expected {self._left - 1}"
                    )
            except MailboxError:
                self.reset()
                raise
        self._left = frag.fragments_left
        self._parts.append(frag.data)
        if frag.incomplete:
            return None
        opcode = self._opcode
        body = b"".join(self._parts)
        self.reset()
        return decode_sdo_info_body(opcode, body)


def _need(buf: bytes | bytearray | memoryview, n: int, what: str) -> None:
    if len(buf) < n:
        raise MailboxError(f"{what}: needs {n} bytes, got {len(buf)}")


# --- decode ------------------------------------------------------------------------

CoeMessage: TypeAlias = (
    SdoInitiateDownloadRequest
    | SdoInitiateDownloadResponse
    | SdoDownloadSegmentRequest
    | SdoDownloadSegmentResponse
    | SdoInitiateUploadRequest
    | SdoInitiateUploadResponse
    | SdoUploadSegmentRequest
    | SdoUploadSegmentResponse
    | SdoAbortTransfer
    | CoePdo
    | Emergency
    | SdoInfoMessage
    | SdoInfoFragment
)


def decode_coe(payload: bytes | bytearray | memoryview) -> CoeMessage:
    """Typed message from a CoE mailbox payload (CoE header first).

    SDO information frames with the incomplete bit set come back as
    :class:`SdoInfoFragment`; the last fragment of a fragmented response looks
    like a complete frame, so a client in the middle of one uses
    :class:`SdoInfoReassembler` on the raw payloads instead.

    Raises :class:`MailboxError` for anything malformed or unknown (block
    transfer command specifiers included).
    """
    payload = bytes(payload)
    header = CoeHeader.decode(payload)
    body = payload[COE_HEADER_SIZE:]
    service = header.service
    if service in (CoeService.SDO_REQUEST, CoeService.SDO_RESPONSE):
        return _decode_sdo(service, body)
    if service == CoeService.EMERGENCY:
        _need(body, 8, "CoE emergency")
        code, reg = struct.unpack_from("<HB", body, 0)
        return Emergency(code, reg, body[3:8])
    if service in _PDO_SERVICES:
        return CoePdo(CoeService(service), header.number, body)
    if service == CoeService.SDO_INFORMATION:
        frag = SdoInfoFragment.from_payload(payload)
        if frag.incomplete:
            return frag
        return decode_sdo_info_body(frag.opcode, frag.data)
    raise MailboxError(f"unknown CoE service {int(service)}")


def _decode_sdo(service: CoeService | int, body: bytes) -> CoeMessage:
    _need(body, SDO_HEADER_SIZE, "SDO frame")
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


# --- transfers -------------------------------------------------------------------


def sdo_initiate_max_data(mailbox_size: int) -> int:
    """Data bytes an initiate frame (normal transfer) can carry in a mailbox of this size."""
    return mailbox_size - MAILBOX_HEADER_SIZE - COE_HEADER_SIZE - SDO_HEADER_SIZE


def sdo_segment_max_data(mailbox_size: int) -> int:
    """Data bytes a segment frame can carry in a mailbox of this size."""
    return mailbox_size - MAILBOX_HEADER_SIZE - COE_HEADER_SIZE - 1


def _check_mailbox_size(mailbox_size: int) -> None:
    # a mailbox must at least hold a 10-byte CoE/SDO frame plus one data byte
    if mailbox_size < MAILBOX_HEADER_SIZE + COE_HEADER_SIZE + SDO_HEADER_SIZE + 1:
        raise MailboxError(f"mailbox of {mailbox_size} bytes is too small for SDO transfers")


def _split_segments(data: bytes, size: int) -> list[bytes]:
    return [data[i : i + size] for i in range(0, len(data), size)]


@dataclass(frozen=True, slots=True)
class SdoTransferDone:
    """A transfer finished. ``data`` is the uploaded object (empty for downloads)."""

    data: bytes = b""


class _ClientBase:
    def __init__(self, index: int, subindex: int, complete_access: bool) -> None:
        _check_address(index, subindex)
        self.index = index
        self.subindex = subindex
        self.complete_access = complete_access
        self.done = False
        self.abort_request: SdoAbortTransfer | None = None

    def _fail(self, code: int, why: str) -> SdoAbort:
        """Record the abort we must send and build the error to raise."""
        self.abort_request = SdoAbortTransfer(self.index, self.subindex, code)
        self.done = True
        return SdoAbort(code, f"{sdo_abort_name(code)} ({why})", self.index, self.subindex)

    def _check_common(self, msg: object) -> None:
        if self.done:
            raise MailboxError("SDO transfer already finished")
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            raise msg.to_error()


class SdoUploadClient:
    """Master side of one SDO upload (read), expedited, normal or segmented.

    ``start()`` gives the initiate request; ``receive(response)`` gives the
    next request or :class:`SdoTransferDone`. A slave abort raises
    :class:`SdoAbort`; a protocol violation raises :class:`SdoAbort` too and
    leaves the abort to send in ``abort_request``.
    """

    def __init__(self, index: int, subindex: int, *, complete_access: bool = False) -> None:
        self._c = _ClientBase(index, subindex, complete_access)
        self._buffer = bytearray()
        self._total: int | None = None
        self._toggle = False
        self._started = False

    @property
    def done(self) -> bool:
        """True once finished (successfully or not)."""
        return self._c.done

    @property
    def abort_request(self) -> SdoAbortTransfer | None:
        """The abort the master should send after a local protocol failure."""
        return self._c.abort_request

    def start(self) -> SdoInitiateUploadRequest:
        """The initiate upload request."""
        self._started = True
        return SdoInitiateUploadRequest(self._c.index, self._c.subindex, self._c.complete_access)

    def receive(self, msg: CoeMessage) -> SdoUploadSegmentRequest | SdoTransferDone:
        """Process one response from the slave."""
        c = self._c
        c._check_common(msg)
        if not self._started:
            raise MailboxError("SdoUploadClient.receive() before start()")
        if isinstance(msg, SdoInitiateUploadResponse) and self._total is None and not self._buffer:
            if msg.index != c.index or (msg.subindex != c.subindex and not c.complete_access):
                raise c._fail(
                    SdoAbortCode.INVALID_COMMAND,
                    f"response for 0x{msg.index:04X}:{msg.subindex:02X}",
                )
            if msg.expedited:
                c.done = True
                return SdoTransferDone(msg.data)
            self._buffer += msg.data
            if msg.size_indicated:
                self._total = msg.total_size
                if len(self._buffer) >= self._total:
                    c.done = True
                    return SdoTransferDone(bytes(self._buffer[: self._total]))
            else:
                self._total = -1  # unknown: segments until the last one
            return SdoUploadSegmentRequest(self._toggle)
        if isinstance(msg, SdoUploadSegmentResponse) and self._total is not None:
            if msg.toggle != self._toggle:
                raise c._fail(SdoAbortCode.TOGGLE_BIT, "upload segment toggle not alternated")
            self._buffer += msg.data
            if self._total >= 0 and len(self._buffer) > self._total:
                raise c._fail(
                    SdoAbortCode.LENGTH_TOO_HIGH,
                    f"{len(self._buffer)} bytes received, complete size {self._total}",
                )
            if msg.last:
                if self._total >= 0 and len(self._buffer) != self._total:
                    raise c._fail(
                        SdoAbortCode.LENGTH_MISMATCH,
                        f"{len(self._buffer)} bytes received, complete size {self._total}",
                    )
                c.done = True
                return SdoTransferDone(bytes(self._buffer))
            self._toggle = not self._toggle
            return SdoUploadSegmentRequest(self._toggle)
        raise c._fail(SdoAbortCode.INVALID_COMMAND, f"unexpected {type(msg).__name__}")


class SdoDownloadClient:
    """Master side of one SDO download (write).

    Expedited when the data has 1..4 bytes and complete access is off (as
    SOEM does); otherwise a normal transfer whose first part rides in the
    initiate frame and the rest in segments sized for ``mailbox_size``.
    """

    def __init__(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        mailbox_size: int,
        complete_access: bool = False,
        expedited: bool | None = None,
    ) -> None:
        _check_mailbox_size(mailbox_size)
        self._c = _ClientBase(index, subindex, complete_access)
        data = bytes(data)
        if expedited is None:
            expedited = 1 <= len(data) <= 4 and not complete_access
        if expedited and not 1 <= len(data) <= 4:
            raise MailboxError(f"expedited download carries 1..4 bytes, got {len(data)}")
        first = sdo_initiate_max_data(mailbox_size)
        self._expedited = expedited
        if expedited:
            self._initiate = SdoInitiateDownloadRequest(
                index, subindex, data, True, True, None, complete_access
            )
            self._segments: list[bytes] = []
        else:
            self._initiate = SdoInitiateDownloadRequest(
                index, subindex, data[:first], False, True, len(data), complete_access
            )
            self._segments = _split_segments(data[first:], sdo_segment_max_data(mailbox_size))
        self._next = 0
        self._toggle = False
        self._started = False

    @property
    def done(self) -> bool:
        """True once finished (successfully or not)."""
        return self._c.done

    @property
    def abort_request(self) -> SdoAbortTransfer | None:
        """The abort the master should send after a local protocol failure."""
        return self._c.abort_request

    def start(self) -> SdoInitiateDownloadRequest:
        """The initiate download request."""
        self._started = True
        return self._initiate

    def _next_segment(self) -> SdoDownloadSegmentRequest:
        chunk = self._segments[self._next]
        self._next += 1
        return SdoDownloadSegmentRequest(self._toggle, self._next == len(self._segments), chunk)

    def receive(self, msg: CoeMessage) -> SdoDownloadSegmentRequest | SdoTransferDone:
        """Process one response from the slave."""
        c = self._c
        c._check_common(msg)
        if not self._started:
            raise MailboxError("SdoDownloadClient.receive() before start()")
        if isinstance(msg, SdoInitiateDownloadResponse) and self._next == 0:
            if msg.index != c.index or (msg.subindex != c.subindex and not c.complete_access):
                raise c._fail(
                    SdoAbortCode.INVALID_COMMAND,
                    f"response for 0x{msg.index:04X}:{msg.subindex:02X}",
                )
            if not self._segments:
                c.done = True
                return SdoTransferDone()
            return self._next_segment()
        if isinstance(msg, SdoDownloadSegmentResponse) and self._next > 0:
            if msg.toggle != self._toggle:
                raise c._fail(SdoAbortCode.TOGGLE_BIT, "download segment toggle not echoed")
            if self._next == len(self._segments):
                c.done = True
                return SdoTransferDone()
            self._toggle = not self._toggle
            return self._next_segment()
        raise c._fail(SdoAbortCode.INVALID_COMMAND, f"unexpected {type(msg).__name__}")


class SdoUploadServer:
    """Slave side of one upload: answers the initiate, then each segment request.

    Build it when an :class:`SdoInitiateUploadRequest` arrived and the object
    was read; ``start()`` is the initiate response; ``receive(request)``
    answers segment requests (a toggle error or a stray request yields an
    :class:`SdoAbortTransfer` and ends the transfer).
    """

    def __init__(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        mailbox_size: int,
        complete_access: bool = False,
    ) -> None:
        _check_mailbox_size(mailbox_size)
        _check_address(index, subindex)
        data = bytes(data)
        self.index = index
        self.subindex = subindex
        self.done = False
        first = sdo_initiate_max_data(mailbox_size)
        if 1 <= len(data) <= 4 and not complete_access:
            self._initiate = SdoInitiateUploadResponse(
                index, subindex, data, True, True, None, complete_access
            )
            self._segments: list[bytes] = []
        else:
            self._initiate = SdoInitiateUploadResponse(
                index, subindex, data[:first], False, True, len(data), complete_access
            )
            self._segments = _split_segments(data[first:], sdo_segment_max_data(mailbox_size))
        self._next = 0
        self._toggle = False

    def start(self) -> SdoInitiateUploadResponse:
        """The initiate upload response."""
        if not self._segments:
            self.done = True
        return self._initiate

    def receive(self, msg: CoeMessage) -> SdoUploadSegmentResponse | SdoAbortTransfer:
        """Answer one request of the master."""
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            return msg
        if self.done or not isinstance(msg, SdoUploadSegmentRequest):
            self.done = True
            return SdoAbortTransfer(
                self.index, self.subindex, SdoAbortCode.INVALID_COMMAND, CoeService.SDO_REQUEST
            )
        if msg.toggle != self._toggle:
            self.done = True
            return SdoAbortTransfer(self.index, self.subindex, SdoAbortCode.TOGGLE_BIT)
        chunk = self._segments[self._next]
        self._next += 1
        last = self._next == len(self._segments)
        reply = SdoUploadSegmentResponse(self._toggle, last, chunk)
        self._toggle = not self._toggle
        self.done = last
        return reply


@dataclass(frozen=True, slots=True)
class SdoDownloadEvent:
    """What :class:`SdoDownloadServer` says about one request.

    ``reply`` is the message to send; when ``data`` is not None the transfer is
    complete: store ``data`` and send ``reply`` (or an abort instead, if the
    object refuses the value).
    """

    reply: SdoInitiateDownloadResponse | SdoDownloadSegmentResponse | SdoAbortTransfer
    data: bytes | None = None


class SdoDownloadServer:
    """Slave side of one download: collects the initiate frame and the segments."""

    def __init__(self, request: SdoInitiateDownloadRequest) -> None:
        self.index = request.index
        self.subindex = request.subindex
        self.complete_access = request.complete_access
        self._request = request
        self._buffer = bytearray(request.data)
        self._total = request.total_size
        self._toggle = False
        self.done = False

    def start(self) -> SdoDownloadEvent:
        """Handle the initiate request this server was built with."""
        reply = SdoInitiateDownloadResponse(self.index, self.subindex, self.complete_access)
        req = self._request
        if req.expedited or len(self._buffer) >= self._total:
            self.done = True
            return SdoDownloadEvent(reply, bytes(self._buffer))
        return SdoDownloadEvent(reply)

    def _abort(self, code: int) -> SdoDownloadEvent:
        self.done = True
        return SdoDownloadEvent(SdoAbortTransfer(self.index, self.subindex, code))

    def receive(self, msg: CoeMessage) -> SdoDownloadEvent:
        """Handle one download segment request."""
        if isinstance(msg, SdoAbortTransfer):
            self.done = True
            return SdoDownloadEvent(msg)
        if self.done or not isinstance(msg, SdoDownloadSegmentRequest):
            return self._abort(SdoAbortCode.INVALID_COMMAND)
        if msg.toggle != self._toggle:
            return self._abort(SdoAbortCode.TOGGLE_BIT)
        self._buffer += msg.data
        if len(self._buffer) > self._total:
            return self._abort(SdoAbortCode.LENGTH_TOO_HIGH)
        reply = SdoDownloadSegmentResponse(self._toggle)
        self._toggle = not self._toggle
        if msg.last:
            self.done = True
            if len(self._buffer) != self._total:
                return self._abort(SdoAbortCode.LENGTH_TOO_LOW)
            return SdoDownloadEvent(reply, bytes(self._buffer))
        return SdoDownloadEvent(reply)
