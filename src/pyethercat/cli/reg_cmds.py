"""Register commands: ``reg_read`` and ``reg_write`` (IgH's verbs, with ``-t TYPE``).

``reg_read ADDRESS [SIZE]`` prints the bytes with the names of the ESC
registers in the range; with ``-t TYPE`` one value printed as IgH prints it
(``0x0002 2``; the type gives the size). ``reg_write ADDRESS DATA`` writes
hex bytes (``"02 00"``), the contents of a file, or ``-`` (stdin) as IgH
does; with ``-t TYPE`` DATA is a value of that type.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import open_session
from pyethercat.cli._types import encode_download, format_upload, upload_type
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError
from pyethercat.master.control import messages as msg
from pyethercat.wire.al import al_status_code_name, state_name
from pyethercat.wire.datagram import MAX_DATA
from pyethercat.wire.registers import (
    AL_CONTROL,
    AL_ERROR_FLAG,
    AL_STATE_MASK,
    AL_STATUS,
    AL_STATUS_CODE,
    REGISTERS,
    register_containing,
)

__all__ = ["register", "format_registers", "hex_data"]

#: Most register bytes one datagram carries (alone in a standard frame).
MAX_REGISTER_BYTES = MAX_DATA


def hex_data(text: str) -> bytes:
    """``"01 02"``, ``"0102"``, ``"01:02"`` or ``"0x0102"`` -> bytes in the given order."""
    cleaned = text.strip()
    if cleaned.lower().startswith("0x"):
        cleaned = cleaned[2:]
    for sep in (" ", ":", ",", "-"):
        cleaned = cleaned.replace(sep, "")
    try:
        data = bytes.fromhex(cleaned)
    except ValueError:
        raise ConfigError(f"not hex data: {text!r} (write bytes like 01 02 or 0102, "
                          "a file name, or - for stdin)") from None
    if not data:
        raise ConfigError("no data to write")
    return data


def _decoded(address: int, value: int) -> str:
    if address in (AL_STATUS, AL_CONTROL):
        return f" ({state_name(value & (AL_STATE_MASK | AL_ERROR_FLAG))})"
    if address == AL_STATUS_CODE:
        return f" ({al_status_code_name(value)})"
    return ""


def format_registers(address: int, data: bytes) -> list[str]:
    """Lines ``0x0130  02 00  AL status = 0x0002 (PREOP)``, one per register in the range.

    Bytes outside any named register are dumped 16 per line.
    """
    lines: list[str] = []
    pos = 0
    while pos < len(data):
        addr = address + pos
        reg = register_containing(addr)
        if reg is not None and reg.address == addr and pos + reg.size <= len(data):
            chunk = data[pos:pos + reg.size]
            text = f"0x{addr:04X}  {chunk.hex(' '):<24}  {reg.name}"
            if reg.size in (1, 2, 4, 8):
                value = int.from_bytes(chunk, "little")
                text += f" = 0x{value:0{2 * reg.size}X}{_decoded(addr, value)}"
            lines.append(text)
            pos += reg.size
            continue
        # Unnamed bytes (or a register cut by the range): dump up to the next named start.
        end = len(data)
        for r in REGISTERS:
            if addr < r.address < address + end:
                end = r.address - address
                break
        end = min(end, pos + 16)
        if reg is not None and reg.address != addr:
            label = f"  ({reg.name}+{addr - reg.address})"
        elif reg is not None:
            label = f"  ({reg.name}, partial)"
        else:
            label = ""
        lines.append(f"0x{addr:04X}  {data[pos:end].hex(' '):<24}{label}")
        pos = end
    return lines


def _check_range(addr: int, count: int, what: str) -> None:
    if not 0 <= addr <= 0xFFFF or not 1 <= count <= 0x10000 - addr or count > MAX_REGISTER_BYTES:
        raise ConfigError(f"cannot {what} {count} byte{'s' if count != 1 else ''} at "
                          f"0x{addr:04X} (addresses 0x0000-0xFFFF, at most "
                          f"{MAX_REGISTER_BYTES} bytes)")


@click.command("reg_read")
@selection_options
@click.option("-t", "--type", "dtype", metavar="TYPE",
              help="Print one value of this type (uint16, int32, float, string, raw ...).")
@click.argument("address")
@click.argument("size", required=False)
@click.pass_obj
def reg_read_command(obj: dict[str, Any], position: str | None, alias: str | None,
                     dtype: str | None, address: str, size: str | None) -> None:
    """Read SIZE bytes at ADDRESS of one slave: hex dump with register names, or -t TYPE."""
    addr = number(address, "address")
    ctype = upload_type(dtype) if dtype is not None else None
    if ctype is not None and not ctype.raw and ctype.dtype.byte_size:
        count = ctype.dtype.byte_size  # the type gives the size (IgH: SIZE is ignored)
    elif size is not None:
        count = number(size, "size")
    else:
        raise ConfigError("reg_read: give SIZE (or a --type that implies one)")
    _check_range(addr, count, "read")
    with open_session(obj) as session:
        pos = session.single(position, alias, "reg_read")
        data = session.call(msg.RegRead(pos, addr, count)).data
    if ctype is not None:
        click.echo(format_upload(ctype, data))
        return
    for line in format_registers(addr, data):
        click.echo(line)


def _write_data(text: str) -> bytes:
    """DATA of ``reg_write`` without a type: ``-`` (stdin), an existing file, or hex bytes."""
    if text == "-":
        data = sys.stdin.buffer.read()
        if not data:
            raise ConfigError("reg_write: no data on stdin")
        return data
    if os.path.isfile(text):
        try:
            with open(text, "rb") as fh:
                data = fh.read()
        except OSError as exc:
            raise ConfigError(f"cannot read {text}: {exc.strerror or exc}") from None
        if not data:
            raise ConfigError(f"reg_write: {text} is empty")
        return data
    return hex_data(text)


@click.command("reg_write")
@selection_options
@click.option("-t", "--type", "dtype", metavar="TYPE",
              help="DATA is a value of this type (uint16, int32, float, string ...).")
@click.argument("address")
@click.argument("data", metavar="DATA")
@click.pass_obj
def reg_write_command(obj: dict[str, Any], position: str | None, alias: str | None,
                      dtype: str | None, address: str, data: str) -> None:
    """Write DATA at ADDRESS of one slave: hex bytes ("02 00"), a file, - (stdin), or -t TYPE VALUE."""
    addr = number(address, "address")
    payload = encode_download(upload_type(dtype), data) if dtype is not None else _write_data(data)
    _check_range(addr, len(payload), "write")
    with open_session(obj) as session:
        pos = session.single(position, alias, "reg_write")
        session.call(msg.RegWrite(pos, addr, payload))
    reg = register_containing(addr)
    name = f" ({reg.name})" if reg is not None and reg.address == addr else ""
    click.echo(f"wrote {len(payload)} byte{'s' if len(payload) != 1 else ''} at 0x{addr:04X}"
               f"{name} of slave {pos}")


def register(cli: click.Group) -> None:
    """Add ``reg_read`` and ``reg_write``."""
    cli.add_command(reg_read_command)
    cli.add_command(reg_write_command)
