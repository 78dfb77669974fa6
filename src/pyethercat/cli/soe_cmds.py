"""SoE commands: ``soe_read`` and ``soe_write`` (in the style of IgH's ``ethercat`` tool).

::

    pyethercat soe_read  -p POS [DRIVE] IDN [--type T] [--element E]
    pyethercat soe_write -p POS [DRIVE] IDN VALUE [--type T]

IDN is a number (0x8001) or IEC 61800-7-204 text (S-0-0024, P-0-150); DRIVE
0-7 (default 0). As IgH, ``--type`` names a CANopen type (uint16, int32,
float, string, octet_string, ...). Unlike IgH it is optional: without it the
IDN's attribute element is read and decides (unsigned, signed, hex, IDN,
text, lists of them). ``--element`` reads another element than the value
(name, attribute, unit, min, max, default, data-state).
"""

from __future__ import annotations

from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import Session, open_session
from pyethercat.cli._types import encode_download, format_upload, upload_type
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError, MailboxError
from pyethercat.master.control import messages as msg
from pyethercat.master.soe import decode_soe_value, encode_soe_value, format_soe_value
from pyethercat.wire.mailbox.soe import SoeElement, format_idn, parse_idn
from pyethercat.wire.mailbox.soe_transfer import SoeAttribute, SoeDataType, decode_soe_text

__all__ = ["register"]

_ELEMENTS = {"value": SoeElement.VALUE, "name": SoeElement.NAME,
             "attribute": SoeElement.ATTRIBUTE, "unit": SoeElement.UNIT,
             "min": SoeElement.MINIMUM, "max": SoeElement.MAXIMUM,
             "default": SoeElement.DEFAULT, "data-state": SoeElement.DATA_STATE}


def _attribute(session: Session, position: int, idn: int, drive: int) -> SoeAttribute:
    raw = session.call(msg.SoeRead(position, idn, SoeElement.ATTRIBUTE, drive)).data
    return SoeAttribute.decode(raw)


def _drive_idn(args: tuple[str, ...], n_after: int) -> tuple[int, int, tuple[str, ...]]:
    """(drive, IDN, the rest) from ``[DRIVE] IDN REST...`` as IgH takes them."""
    if len(args) == 1 + n_after:
        drive, idn_text, rest = "0", args[0], args[1:]
    elif len(args) == 2 + n_after:
        drive, idn_text, rest = args[0], args[1], args[2:]
    else:
        want = "[DRIVE] IDN" + (" VALUE" if n_after else "")
        raise click.UsageError(f"expected {want}")
    try:
        idn = parse_idn(idn_text)
    except MailboxError as exc:
        raise ConfigError(str(exc)) from None
    return number(drive, "drive", 7), idn, rest


def _format_element(element: int, raw: bytes, attr: SoeAttribute | None) -> str:
    if element in (SoeElement.NAME, SoeElement.UNIT):
        return decode_soe_text(raw)
    if element == SoeElement.ATTRIBUTE:
        a = SoeAttribute.decode(raw)
        return (f"0x{int.from_bytes(raw[:4], 'little'):08X} ({a.length} byte"
                f"{'s' if a.length != 1 else ''}, {a.data_type.name.lower()}"
                f"{', list' if a.is_list else ''})")
    if attr is not None:
        return format_soe_value(decode_soe_value(raw, attr), attr)
    return raw.hex(" ")


def register(cli: click.Group) -> None:
    """Add ``soe_read`` and ``soe_write``."""

    @cli.command("soe_read")
    @selection_options
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type as for upload (default: from the IDN's attribute).")
    @click.option("-e", "--element", type=click.Choice(sorted(_ELEMENTS)), default="value",
                  show_default=True, help="Element of the IDN to read.")
    @click.argument("args", nargs=-1, required=True, metavar="[DRIVE] IDN")
    @click.pass_obj
    def soe_read_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                     dtype: str | None, element: str, args: tuple[str, ...]) -> None:
        """Read an IDN of a drive over SoE and print it."""
        drive, idn, _rest = _drive_idn(args, 0)
        flag = _ELEMENTS[element]
        with open_session(obj) as session:
            pos = session.single(position, alias, "soe_read")
            raw = session.call(msg.SoeRead(pos, idn, flag, drive)).data
            if dtype is not None and flag not in (SoeElement.NAME, SoeElement.UNIT,
                                                  SoeElement.ATTRIBUTE):
                click.echo(format_upload(upload_type(dtype), raw))
                return
            attr = None
            if flag in (SoeElement.VALUE, SoeElement.MINIMUM, SoeElement.MAXIMUM,
                        SoeElement.DEFAULT):
                attr = _attribute(session, pos, idn, drive)
            click.echo(_format_element(flag, raw, attr))

    # negative values ("-500") are values, not options
    @cli.command("soe_write", context_settings={"ignore_unknown_options": True})
    @selection_options
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type of VALUE as for download (default: from the attribute).")
    @click.argument("args", nargs=-1, required=True, metavar="[DRIVE] IDN VALUE")
    @click.pass_obj
    def soe_write_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                      dtype: str | None, args: tuple[str, ...]) -> None:
        """Write VALUE to an IDN of a drive over SoE."""
        drive, idn, rest = _drive_idn(args, 1)
        text = rest[0]
        with open_session(obj) as session:
            pos = session.single(position, alias, "soe_write")
            if dtype is not None:
                data = encode_download(upload_type(dtype), text)
            else:
                attr = _attribute(session, pos, idn, drive)
                data = encode_soe_value(_parse_value(text, idn, attr), attr)
            session.call(msg.SoeWrite(pos, idn, data, SoeElement.VALUE, drive))


def _parse_value(text: str, idn: int, attr: SoeAttribute) -> Any:
    """VALUE as the attribute's type takes it (lists space- or comma-separated)."""
    kind = attr.data_type
    if attr.is_list and kind != SoeDataType.STRING:
        items = text.replace(",", " ").split()
        return [parse_idn(t) if kind == SoeDataType.IDN else number(t, "value") for t in items]
    if kind == SoeDataType.STRING:
        return text
    if kind == SoeDataType.FLOAT:
        try:
            return float(text)
        except ValueError:
            raise ConfigError(f"{text!r} is not a number") from None
    if kind == SoeDataType.IDN:
        return parse_idn(text)
    try:
        return int(text, 0)
    except ValueError:
        raise ConfigError(f"{format_idn(idn)}: {text!r} is not a number") from None
