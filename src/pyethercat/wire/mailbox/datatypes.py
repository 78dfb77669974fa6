"""CANopen basic data types (IEC 61158-6-12:2019 5.6.7.3 Table 64): codes, sizes, value codecs.

Also the mapping from user type names (the CLI ``--type`` option, spelled as
IgH's ``ethercat`` tool spells them: ``uint16``, ``int32``, ``float``,
``string`` ...) to data types, and parsing of a value typed on a command line.
"""

from __future__ import annotations

import math
import struct
from enum import IntEnum

from pyethercat.errors import ConfigError, MailboxError

__all__ = [
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

Value = bool | int | float | str | bytes
"""What :func:`decode_value` returns and :func:`encode_value` takes."""


class DataType(IntEnum):
    """CANopen data type codes (object dictionary index of the type)."""

    BOOLEAN = 0x0001
    INTEGER8 = 0x0002
    INTEGER16 = 0x0003
    INTEGER32 = 0x0004
    UNSIGNED8 = 0x0005
    UNSIGNED16 = 0x0006
    UNSIGNED32 = 0x0007
    REAL32 = 0x0008
    VISIBLE_STRING = 0x0009
    OCTET_STRING = 0x000A
    UNICODE_STRING = 0x000B
    TIME_OF_DAY = 0x000C
    TIME_DIFFERENCE = 0x000D
    DOMAIN = 0x000F
    INTEGER24 = 0x0010
    REAL64 = 0x0011
    INTEGER40 = 0x0012
    INTEGER48 = 0x0013
    INTEGER56 = 0x0014
    INTEGER64 = 0x0015
    UNSIGNED24 = 0x0016
    UNSIGNED40 = 0x0018
    UNSIGNED48 = 0x0019
    UNSIGNED56 = 0x001A
    UNSIGNED64 = 0x001B
    GUID = 0x001D
    BYTE = 0x001E
    PDO_MAPPING = 0x0021
    IDENTITY = 0x0023
    COMMAND_PAR = 0x0025
    SYNC_PAR = 0x0029
    BITARR8 = 0x002D
    BITARR16 = 0x002E
    BITARR32 = 0x002F
    BIT1 = 0x0030
    BIT2 = 0x0031
    BIT3 = 0x0032
    BIT4 = 0x0033
    BIT5 = 0x0034
    BIT6 = 0x0035
    BIT7 = 0x0036
    BIT8 = 0x0037

    @property
    def bit_size(self) -> int | None:
        """Size in bits, or None for variable-length types (strings, domain, ...)."""
        return DATA_TYPE_BITS.get(self)

    @property
    def byte_size(self) -> int | None:
        """Bytes this type takes in an SDO transfer, or None when variable."""
        bits = DATA_TYPE_BITS.get(self)
        return None if bits is None else (bits + 7) // 8


DATA_TYPE_BITS: dict[DataType, int] = {
    DataType.BOOLEAN: 1,
    DataType.INTEGER8: 8,
    DataType.INTEGER16: 16,
    DataType.INTEGER24: 24,
    DataType.INTEGER32: 32,
    DataType.INTEGER40: 40,
    DataType.INTEGER48: 48,
    DataType.INTEGER56: 56,
    DataType.INTEGER64: 64,
    DataType.UNSIGNED8: 8,
    DataType.UNSIGNED16: 16,
    DataType.UNSIGNED24: 24,
    DataType.UNSIGNED32: 32,
    DataType.UNSIGNED40: 40,
    DataType.UNSIGNED48: 48,
    DataType.UNSIGNED56: 56,
    DataType.UNSIGNED64: 64,
    DataType.REAL32: 32,
    DataType.REAL64: 64,
    DataType.TIME_OF_DAY: 48,
    DataType.TIME_DIFFERENCE: 48,
    DataType.GUID: 128,
    DataType.BYTE: 8,
    DataType.BITARR8: 8,
    DataType.BITARR16: 16,
    DataType.BITARR32: 32,
    DataType.BIT1: 1,
    DataType.BIT2: 2,
    DataType.BIT3: 3,
    DataType.BIT4: 4,
    DataType.BIT5: 5,
    DataType.BIT6: 6,
    DataType.BIT7: 7,
    DataType.BIT8: 8,
}

_SIGNED = {
    DataType.INTEGER8,
    DataType.INTEGER16,
    DataType.INTEGER24,
    DataType.INTEGER32,
    DataType.INTEGER40,
    DataType.INTEGER48,
    DataType.INTEGER56,
    DataType.INTEGER64,
}
_UNSIGNED = {
    DataType.UNSIGNED8,
    DataType.UNSIGNED16,
    DataType.UNSIGNED24,
    DataType.UNSIGNED32,
    DataType.UNSIGNED40,
    DataType.UNSIGNED48,
    DataType.UNSIGNED56,
    DataType.UNSIGNED64,
    DataType.BYTE,
    DataType.BITARR8,
    DataType.BITARR16,
    DataType.BITARR32,
    DataType.BIT1,
    DataType.BIT2,
    DataType.BIT3,
    DataType.BIT4,
    DataType.BIT5,
    DataType.BIT6,
    DataType.BIT7,
    DataType.BIT8,
}
# Fixed-size types that have no natural Python number: carried as raw bytes.
_FIXED_BYTES = {DataType.TIME_OF_DAY, DataType.TIME_DIFFERENCE, DataType.GUID}

TYPE_NAMES: dict[str, DataType] = {
    # IgH ethercat tool spellings (what --type accepts first)
    "bool": DataType.BOOLEAN,
    "int8": DataType.INTEGER8,
    "int16": DataType.INTEGER16,
    "int24": DataType.INTEGER24,
    "int32": DataType.INTEGER32,
    "int40": DataType.INTEGER40,
    "int48": DataType.INTEGER48,
    "int56": DataType.INTEGER56,
    "int64": DataType.INTEGER64,
    "uint8": DataType.UNSIGNED8,
    "uint16": DataType.UNSIGNED16,
    "uint24": DataType.UNSIGNED24,
    "uint32": DataType.UNSIGNED32,
    "uint40": DataType.UNSIGNED40,
    "uint48": DataType.UNSIGNED48,
    "uint56": DataType.UNSIGNED56,
    "uint64": DataType.UNSIGNED64,
    "float": DataType.REAL32,
    "double": DataType.REAL64,
    "string": DataType.VISIBLE_STRING,
    "octet_string": DataType.OCTET_STRING,
    "unicode_string": DataType.UNICODE_STRING,
    "sm8": DataType.INTEGER8,
    "sm16": DataType.INTEGER16,
    "sm32": DataType.INTEGER32,
    "sm64": DataType.INTEGER64,
    # common alternatives
    "boolean": DataType.BOOLEAN,
    "sint8": DataType.INTEGER8,
    "sint16": DataType.INTEGER16,
    "sint32": DataType.INTEGER32,
    "sint64": DataType.INTEGER64,
    "usint": DataType.UNSIGNED8,
    "uint": DataType.UNSIGNED16,
    "udint": DataType.UNSIGNED32,
    "ulint": DataType.UNSIGNED64,
    "sint": DataType.INTEGER8,
    "int": DataType.INTEGER16,
    "dint": DataType.INTEGER32,
    "lint": DataType.INTEGER64,
    "real": DataType.REAL32,
    "lreal": DataType.REAL64,
    "float32": DataType.REAL32,
    "float64": DataType.REAL64,
    "byte": DataType.BYTE,
    "word": DataType.UNSIGNED16,
    "dword": DataType.UNSIGNED32,
    "raw": DataType.OCTET_STRING,
    "octets": DataType.OCTET_STRING,
    "domain": DataType.DOMAIN,
}


def parse_type_name(name: str) -> DataType:
    """Map a user type name ("uint16", "float", "UNSIGNED16", "0x0006") to a :class:`DataType`.

    Raises :class:`ConfigError` for an unknown name.
    """
    key = name.strip().lower().replace("-", "_")
    if key in TYPE_NAMES:
        return TYPE_NAMES[key]
    upper = key.upper()
    if upper in DataType.__members__:
        return DataType[upper]
    try:
        return DataType(int(key, 0))
    except ValueError:
        pass
    known = ", ".join(
        sorted(
            {k for k in TYPE_NAMES if "_" in k or k[-1].isdigit()}
            | {"float", "double", "string", "bool"}
        )
    )
    raise ConfigError(f"unknown data type {name!r} (known: {known})")


def _int_bounds(dtype: DataType) -> tuple[int, int]:
    bits = DATA_TYPE_BITS[dtype]
    if dtype in _SIGNED:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def encode_value(dtype: DataType, value: Value) -> bytes:
    """Little-endian bytes of ``value`` as ``dtype``, as an SDO transfer carries them.

    BOOLEAN and BITn take one byte. Raises :class:`MailboxError` when the value
    does not fit the type or has the wrong Python type.
    """
    if dtype is DataType.BOOLEAN:
        if isinstance(value, bool) or (isinstance(value, int) and value in (0, 1)):
            return bytes([int(value)])
        raise MailboxError(f"BOOLEAN needs True/False or 0/1, got {value!r}")
    if dtype in _SIGNED or dtype in _UNSIGNED:
        if not isinstance(value, int) or isinstance(value, bool):
            raise MailboxError(f"{dtype.name} needs an integer, got {value!r}")
        lo, hi = _int_bounds(dtype)
        if not lo <= value <= hi:
            raise MailboxError(f"value {value} out of range {lo}..{hi} for {dtype.name}")
        size = (DATA_TYPE_BITS[dtype] + 7) // 8
        return value.to_bytes(size, "little", signed=dtype in _SIGNED)
    if dtype in (DataType.REAL32, DataType.REAL64):
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise MailboxError(f"{dtype.name} needs a number, got {value!r}")
        try:
            return struct.pack("<f" if dtype is DataType.REAL32 else "<d", float(value))
        except (OverflowError, struct.error) as exc:
            raise MailboxError(f"value {value!r} does not fit {dtype.name}: {exc}") from None
    if dtype is DataType.VISIBLE_STRING:
        if not isinstance(value, str):
            raise MailboxError(f"VISIBLE_STRING needs a str, got {value!r}")
        return value.encode("utf-8")
    if dtype is DataType.UNICODE_STRING:
        if not isinstance(value, str):
            raise MailboxError(f"UNICODE_STRING needs a str, got {value!r}")
        try:
            return value.encode("utf-16-le")
        except UnicodeEncodeError as exc:
            raise MailboxError(f"cannot encode {value!r} as UTF-16: {exc}") from None
    # OCTET_STRING, DOMAIN, GUID, times and constructed types: raw bytes.
    if not isinstance(value, (bytes, bytearray)):
        raise MailboxError(f"{dtype.name} needs bytes, got {value!r}")
    fixed = dtype.byte_size
    if dtype in _FIXED_BYTES and fixed is not None and len(value) != fixed:
        raise MailboxError(f"{dtype.name} needs {fixed} bytes, got {len(value)}")
    return bytes(value)


def decode_value(
    dtype: DataType, raw: bytes | bytearray | memoryview, *, strict: bool = False
) -> Value:
    """Python value of ``raw`` as ``dtype``.

    Fixed-size types need at least their size in bytes; extra bytes are ignored
    (some slaves answer a u8 object with 4 expedited bytes) unless ``strict``.
    VISIBLE_STRING drops trailing NUL padding. Raises :class:`MailboxError`.
    """
    raw = bytes(raw)
    size = dtype.byte_size
    if size is not None:
        if len(raw) < size or (strict and len(raw) != size):
            raise MailboxError(f"{dtype.name} needs {size} bytes, got {len(raw)}")
        raw = raw[:size]
    if dtype is DataType.BOOLEAN:
        return bool(raw[0] & 1)
    if dtype in _SIGNED:
        return int.from_bytes(raw, "little", signed=True)
    if dtype in _UNSIGNED:
        value = int.from_bytes(raw, "little")
        bits = DATA_TYPE_BITS[dtype]
        return value & ((1 << bits) - 1)
    if dtype is DataType.REAL32:
        return float(struct.unpack("<f", raw)[0])
    if dtype is DataType.REAL64:
        return float(struct.unpack("<d", raw)[0])
    if dtype is DataType.VISIBLE_STRING:
        return raw.rstrip(b"\x00").decode("utf-8", errors="replace")
    if dtype is DataType.UNICODE_STRING:
        if len(raw) % 2:
            raise MailboxError(f"UNICODE_STRING needs an even byte count, got {len(raw)}")
        text = raw.decode("utf-16-le", errors="replace")
        return text.rstrip("\x00")
    return raw


def parse_value(dtype: DataType, text: str) -> Value:
    """Parse a value typed by a user (CLI) for ``dtype``.

    Integers accept ``0x`` hex, ``0b``, ``0o``; booleans accept true/false/on/off/1/0;
    OCTET_STRING/DOMAIN take hex digits (spaces and colons allowed). Raises
    :class:`ConfigError` for text that is not a value of the type.
    """
    t = text.strip()
    try:
        if dtype is DataType.BOOLEAN:
            low = t.lower()
            if low in ("1", "true", "on", "yes"):
                return True
            if low in ("0", "false", "off", "no"):
                return False
            raise ValueError(t)
        if dtype in _SIGNED or dtype in _UNSIGNED:
            value = int(t, 0)
            lo, hi = _int_bounds(dtype)
            if not lo <= value <= hi:
                raise ConfigError(f"value {value} out of range {lo}..{hi} for {dtype.name}")
            return value
        if dtype in (DataType.REAL32, DataType.REAL64):
            number = float(t)
            if (
                dtype is DataType.REAL32
                and math.isfinite(number)
                and abs(number) > 3.4028234663852886e38
            ):
                raise ConfigError(f"value {t} does not fit REAL32")
            return number
        if dtype in (DataType.VISIBLE_STRING, DataType.UNICODE_STRING):
            return text
        hexdigits = t.replace(" ", "").replace(":", "")
        if hexdigits.lower().startswith("0x"):
            hexdigits = hexdigits[2:]
        return bytes.fromhex(hexdigits)
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{text!r} is not a valid {dtype.name} value") from None


def format_value(dtype: DataType, value: Value) -> str:
    """Text for a decoded value: integers as decimal plus 0x hex, bytes as hex."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        if dtype in _SIGNED and value < 0:
            return str(value)
        width = ((dtype.bit_size or 8) + 3) // 4
        return f"0x{value:0{width}x} {value}"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, bytes):
        return value.hex(" ")
    return value
