"""What every CoE message shares: the CoE header, the services and the SDO abort codes.

The CoE header is the u16 after the mailbox header: number in bits 8:0,
service in bits 15:12 (IEC 61158-6-12:2019 5.6.1, ETG.1000.6; SOEM
``include/soem/ec_coe.h``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from pyethercat.errors import MailboxError

__all__ = [
    "COE_HEADER_SIZE",
    "SDO_HEADER_SIZE",
    "CoeService",
    "CoeHeader",
    "SdoAbortCode",
    "SDO_ABORT_CODES",
    "sdo_abort_name",
]

COE_HEADER_SIZE = 2
"""CoE header bytes (after the mailbox header)."""
SDO_HEADER_SIZE = 8
"""Command byte + index + subindex + 4-byte data/size field."""


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
        check("CoE number", self.number, 0x1FF)
        check("CoE service", int(self.service), 0xF)

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


def coe_header_bytes(service: CoeService | int) -> bytes:
    """The CoE header bytes of a service with number 0 (the SDO and SDO info frames)."""
    got = _HEADER_BYTES.get(service)
    if got is None:
        got = CoeHeader(service).encode()
    return got


_HEADER_BYTES: dict[CoeService | int, bytes] = {
    s: struct.pack("<H", int(s) << 12) for s in CoeService}


def check(what: str, value: int, maximum: int, minimum: int = 0) -> None:
    if not minimum <= value <= maximum:
        raise MailboxError(f"{what} {value} out of range {minimum}..{maximum}")


def need(buf: bytes | bytearray | memoryview, n: int, what: str) -> None:
    """Raise :class:`MailboxError` unless ``buf`` holds at least ``n`` bytes."""
    if len(buf) < n:
        raise MailboxError(f"{what}: needs {n} bytes, got {len(buf)}")


# --- SDO abort codes -------------------------------------------------------------


class SdoAbortCode(IntEnum):
    """SDO abort codes (CiA 301, "SDO abort transfer"; the same table in SOEM
    ``src/ec_print.c`` ``ec_sdoerrorlist`` and SOES ``soes/esc_coe.h``)."""

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
