"""CoE emergencies (service 1) and PDOs over the mailbox (services 4-7).

An emergency is 8 bytes after the CoE header: error code u16, error register
u8 and 5 manufacturer bytes (CiA 301 EMCY; SOEM ``src/ec_main.c``
``ecx_mbxemergencyerror``; Wireshark ``packet-ecatmb.c``). The error-code classes are
CiA 301's table.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntFlag

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.coe.header import CoeHeader, CoeService, check, coe_header_bytes

__all__ = [
    "CoePdo",
    "PDO_SERVICES",
    "Emergency",
    "EMERGENCY_ERROR_CLASSES",
    "emergency_error_name",
    "ErrorRegister",
]


@dataclass(frozen=True, slots=True)
class CoePdo:
    """TxPDO/RxPDO (services 4/5) or their remote requests (6/7, no data)."""

    service: CoeService
    number: int
    data: bytes = b""

    def __post_init__(self) -> None:
        if self.service not in PDO_SERVICES:
            raise MailboxError(f"CoE service {self.service} is not a PDO service")
        check("PDO number", self.number, 0x1FF)
        object.__setattr__(self, "data", bytes(self.data))

    def encode(self) -> bytes:
        """CoE header + PDO data."""
        return CoeHeader(self.service, self.number).encode() + self.data


PDO_SERVICES = (
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
    0x7500: "communication error (drive)",
    0x8000: "monitoring",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    # CiA 402 (IEC 61800-7-201) drive codes, as Beckhoff's slave stack lists them
    # (SSC ``cia402appl.h``); 0xA0xx: EtherCAT state machine transition errors
    # (IEC 61158-6-12, as drive manuals such as STOBER's list them).
    0x8600: "positioning controller",
    0x8611: "following error",
    0x8612: "reference limit",
    0x8700: "sync controller",
    0x9000: "external error",
    0xA000: "EtherCAT transition PRE-OP to SAFE-OP failed",
    0xA001: "EtherCAT transition SAFE-OP to OP failed",
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
        check("emergency error code", self.error_code, 0xFFFF)
        check("emergency error register", self.error_register, 0xFF)
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
            coe_header_bytes(CoeService.EMERGENCY)
            + struct.pack("<HB", self.error_code, self.error_register)
            + self.data
        )
