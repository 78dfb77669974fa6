"""CoE commands: ``upload``, ``download`` and ``sdos`` (in the style of IgH's ``ethercat`` tool).

``upload -p POS INDEX SUBINDEX [--type T]`` reads an object and prints it by
its type (given, or taken from the slave's SDO information; raw hex when
neither is known). ``download -p POS INDEX SUBINDEX VALUE [--type T]`` writes
one. ``sdos [-p POS]`` lists the object dictionary as IgH prints it::

    SDO 0x1018, "Identity"
      0x1018:00, r-r-r-, uint8, 8 bit, "Number of entries"

The slaves are scanned without a reset; a slave still in INIT (or BOOT) is
brought to PRE-OP first, because the mailbox works only from there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import click

from pyethercat.cli._connect import connect
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError, SdoAbort
from pyethercat.master.coe import CoeClient, resolve_dtype
from pyethercat.master.master import Master
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.datatypes import (
    TYPE_NAMES,
    DataType,
    decode_value,
    encode_value,
    parse_value,
)

__all__ = ["CliType", "register", "format_sdos", "type_name", "format_upload", "upload_type",
           "encode_download"]

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


def _slave(m: Master, position: str) -> tuple[Slave, CoeClient]:
    pos = number(position, "position", 0xFFFF)
    m.scan(reset=False)
    s = m.slave(pos)
    if s.coe is None:
        raise ConfigError(f"{s.describe()} has no mailbox: no CoE")
    if s.al_state in (AlState.INIT, AlState.BOOT, AlState.NONE):
        m.set_state(AlState.PREOP, [s])
    return s, s.coe


def _entry_type(client: CoeClient, index: int, subindex: int) -> DataType | None:
    """The data type the slave's SDO information gives for an entry (None if unknown)."""
    try:
        desc = client.entry_description(index, subindex, value_info=0)
        return DataType(desc.data_type)
    except (SdoAbort, ValueError):
        return None
    except Exception:  # noqa: BLE001 - no SDO information service: type unknown
        return None


#: IgH's sign-and-magnitude types: the top bit is the sign, the other bits the magnitude.
_SIGN_MAGNITUDE = {"sm8": DataType.INTEGER8, "sm16": DataType.INTEGER16,
                   "sm32": DataType.INTEGER32, "sm64": DataType.INTEGER64}


@dataclass(frozen=True, slots=True)
class CliType:
    """A ``--type`` as the CLI understands it: the CANopen type, and IgH's sign-magnitude."""

    dtype: DataType
    sign_magnitude: bool = False

    @property
    def name(self) -> str:
        if self.sign_magnitude:
            return f"sm{self.dtype.bit_size}"
        return type_name(int(self.dtype))


def upload_type(name: str) -> CliType:
    """The type a ``--type`` names (IgH names first); :class:`ConfigError` if unknown."""
    key = name.strip().lower()
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
        return _raw_text(raw)
    if isinstance(ctype, DataType):
        ctype = CliType(ctype)
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
    return _raw_text(raw)


def _raw_text(raw: bytes) -> str:
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


def format_sdos(client: CoeClient, quiet: bool = False) -> list[str]:
    """The ``sdos`` listing of one slave (IgH layout)."""
    lines: list[str] = []
    od = client.od
    for index in od:
        try:
            obj = od[index]
        except (KeyError, SdoAbort) as exc:
            lines.append(f"SDO 0x{index:04X}, (no description: {exc})")
            continue
        lines.append(f"SDO 0x{index:04X}, \"{obj.name}\"")
        if quiet:
            continue
        for e in obj.entries:
            lines.append(f"  0x{index:04X}:{e.subindex:02X}, {e.access_text}, "
                         f"{type_name(e.data_type)}, {e.bit_length} bit, \"{e.name}\"")
    return lines


def register(cli: click.Group) -> None:
    """Add ``upload``, ``download`` and ``sdos``."""

    @cli.command("upload")
    @click.option("-p", "--position", metavar="POS", required=True, help="Ring position.")
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type (uint8..uint64, int8..int64, float, double, string, "
                       "octet_string, bool ...); default: from the slave's SDO information.")
    @click.option("--complete-access", "-c", is_flag=True, help="Read all subindices at once.")
    @click.argument("index")
    @click.argument("subindex")
    @click.pass_obj
    def upload_cmd(obj: dict[str, Any], position: str, dtype: str | None,
                   complete_access: bool, index: str, subindex: str) -> None:
        """Read an object with an SDO upload and print its value."""
        idx = number(index, "index", 0xFFFF)
        sub = number(subindex, "subindex", 0xFF)
        ct = upload_type(dtype) if dtype is not None else None
        with connect(obj) as conn:
            _s, client = _slave(conn.master, position)
            raw = client.upload(idx, sub, complete_access=complete_access)
            if ct is None and not complete_access:
                described = _entry_type(client, idx, sub)
                ct = CliType(described) if described is not None else None
            click.echo(format_upload(ct, raw))

    @cli.command("download")
    @click.option("-p", "--position", metavar="POS", required=True, help="Ring position.")
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type of VALUE; default: from the slave's SDO information.")
    @click.option("--complete-access", "-c", is_flag=True, help="Write all subindices at once.")
    @click.argument("index")
    @click.argument("subindex")
    @click.argument("value")
    @click.pass_obj
    def download_cmd(obj: dict[str, Any], position: str, dtype: str | None,
                     complete_access: bool, index: str, subindex: str, value: str) -> None:
        """Write VALUE to an object with an SDO download."""
        idx = number(index, "index", 0xFFFF)
        sub = number(subindex, "subindex", 0xFF)
        ct = upload_type(dtype) if dtype is not None else None
        with connect(obj) as conn:
            _s, client = _slave(conn.master, position)
            if ct is None:
                dt = _entry_type(client, idx, sub) if not complete_access else None
                if dt is None and complete_access:
                    dt = DataType.OCTET_STRING
                if dt is None:
                    raise ConfigError(f"the slave does not describe 0x{idx:04X}:{sub:02X}: "
                                      "give --type")
                ct = CliType(dt)
            client.download(idx, sub, encode_download(ct, value),
                            complete_access=complete_access)

    @cli.command("sdos")
    @click.option("-p", "--position", metavar="POS", help="Only this slave.")
    @click.option("-q", "--quiet", is_flag=True, help="Objects only, no entries.")
    @click.pass_obj
    def sdos_cmd(obj: dict[str, Any], position: str | None, quiet: bool) -> None:
        """List the object dictionary (SDO information service)."""
        with connect(obj) as conn:
            m = conn.master
            m.scan(reset=False)
            chosen = ([m.slave(number(position, "position", 0xFFFF))] if position is not None
                      else [s for s in m.slaves if s.coe is not None and s.has_coe])
            if position is None and not chosen:
                raise ConfigError("no slave speaks CoE")
            low = [s for s in chosen if s.al_state in (AlState.INIT, AlState.BOOT, AlState.NONE)]
            if low:
                m.set_state(AlState.PREOP, low)
            for s in chosen:
                if s.coe is None:
                    raise ConfigError(f"{s.describe()} has no mailbox: no CoE")
                if len(chosen) > 1 or position is None:
                    click.echo(f"=== slave {s.position} ({s.address_text}, {s.name or '?'}) ===")
                for line in format_sdos(s.coe, quiet):
                    click.echo(line)
