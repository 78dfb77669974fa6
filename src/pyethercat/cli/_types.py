"""Data types on the command line, as IgH's ``ethercat`` tool names and prints them.

``--type`` of ``upload``/``download``/``reg_read``/``reg_write`` takes IgH's
names (``bool``, ``int8``..``int64``, ``uint8``..``uint64``, ``float``,
``double``, ``string``, ``octet_string``, ``unicode_string``, the
sign-and-magnitude ``sm8``..``sm64``, and ``raw``) and the CANopen ones
(``UNSIGNED16``...). Values print as IgH's ``DataTypeHandler::outputData``
does.
"""

from __future__ import annotations

from dataclasses import dataclass

from pyethercat.errors import ConfigError
from pyethercat.master.coe import resolve_dtype
from pyethercat.wire.mailbox.datatypes import (
    TYPE_NAMES,
    DataType,
    decode_value,
    encode_value,
    parse_value,
)

__all__ = ["CliType", "type_name", "upload_type", "format_upload", "encode_download",
           "raw_text", "RAW"]

#: ``-t raw``: bytes as they are (IgH prints them as ``0x.. 0x..``).
RAW = "raw"

# IgH spellings first in TYPE_NAMES: the first name of each type is what we print.
_IGH_NAMES: dict[int, str] = {}
for _name, _dt in TYPE_NAMES.items():
    if not _name.startswith("sm"):  # sign-magnitude names are no CANopen types
        _IGH_NAMES.setdefault(int(_dt), _name)
_INTEGER_TYPES = frozenset(t for t in DataType
                           if t.name.startswith(("INTEGER", "UNSIGNED")) or t is DataType.BOOLEAN)


def type_name(code: int) -> str:
    """IgH's name of a data type (``uint16``), or ``type 0xNNNN``."""
    if code in _IGH_NAMES:
        return _IGH_NAMES[code]
    try:
        return DataType(code).name.lower()
    except ValueError:
        return f"type 0x{code:04x}"


#: IgH's sign-and-magnitude types: the top bit is the sign, the other bits the magnitude.
_SIGN_MAGNITUDE = {"sm8": DataType.INTEGER8, "sm16": DataType.INTEGER16,
                   "sm32": DataType.INTEGER32, "sm64": DataType.INTEGER64}


@dataclass(frozen=True, slots=True)
class CliType:
    """A ``--type`` as the CLI understands it: the CANopen type, and IgH's sign-magnitude."""

    dtype: DataType
    sign_magnitude: bool = False
    #: IgH's ``raw``: bytes as they are, any length.
    raw: bool = False

    @property
    def name(self) -> str:
        if self.raw:
            return RAW
        if self.sign_magnitude:
            return f"sm{self.dtype.bit_size}"
        return type_name(int(self.dtype))


def upload_type(name: str) -> CliType:
    """The type a ``--type`` names (IgH names first); :class:`ConfigError` if unknown."""
    key = name.strip().lower()
    if key == RAW:
        return CliType(DataType.OCTET_STRING, raw=True)
    if key in _SIGN_MAGNITUDE:
        return CliType(_SIGN_MAGNITUDE[key], True)
    return CliType(resolve_dtype(name))


def format_upload(ctype: CliType | DataType | None, raw: bytes) -> str:
    """How ``upload`` prints a value, in the format of IgH's ``ethercat upload``.

    Integers (and bool): ``0x`` + the value's bytes in hex (two's complement,
    the type's width), a space, the decimal value; sign-and-magnitude types
    show the raw hex and the signed magnitude. Floats: 6 significant digits
    (C++ stream default). Strings: the text without trailing NULs (IgH
    prints them raw). Everything else, octet strings included (which IgH
    writes to stdout as binary): ``0x00 0x01 ...``. A fixed-size type whose
    size differs from the data raises :class:`ConfigError`, as IgH refuses it.
    """
    if ctype is None:
        return raw_text(raw)
    if isinstance(ctype, DataType):
        ctype = CliType(ctype)
    if ctype.raw:
        return raw_text(raw)
    dtype = ctype.dtype
    size = dtype.byte_size
    if size is not None and len(raw) != size:
        raise ConfigError(f"Data type mismatch. Expected {ctype.name} with {size} byte"
                          f"{'s' if size != 1 else ''}, but got {len(raw)} byte"
                          f"{'s' if len(raw) != 1 else ''}.")
    if dtype in _INTEGER_TYPES and size is not None:
        unsigned = int.from_bytes(raw, "little")
        if ctype.sign_magnitude:
            top = 1 << (8 * size - 1)
            value = -(unsigned & (top - 1)) if unsigned & top else unsigned
        else:
            value = int.from_bytes(raw, "little", signed=dtype.name.startswith("INTEGER"))
        return f"0x{unsigned:0{2 * size}x} {value}"
    if dtype in (DataType.REAL32, DataType.REAL64):
        return f"{float(decode_value(dtype, raw)):g}"
    if dtype in (DataType.VISIBLE_STRING, DataType.UNICODE_STRING):
        return str(decode_value(dtype, raw))
    return raw_text(raw)


def raw_text(raw: bytes) -> str:
    """IgH's printRawData: every byte as ``0xNN``, separated by spaces."""
    return " ".join(f"0x{b:02x}" for b in raw)


def encode_download(ctype: CliType, text: str) -> bytes:
    """The bytes ``download`` writes for ``text`` typed as ``ctype``."""
    if ctype.sign_magnitude:
        size = ctype.dtype.byte_size or 1
        try:
            value = int(text.strip(), 0)
        except ValueError:
            raise ConfigError(f"{text!r} is not a valid {ctype.name} value") from None
        top = 1 << (8 * size - 1)
        if abs(value) >= top:
            raise ConfigError(f"value {value} out of range for {ctype.name}")
        return ((top if value < 0 else 0) | abs(value)).to_bytes(size, "little")
    return encode_value(ctype.dtype, parse_value(ctype.dtype, text))


