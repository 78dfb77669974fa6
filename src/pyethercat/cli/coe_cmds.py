"""CoE commands: ``upload``, ``download`` and ``sdos`` (in the style of IgH's ``ethercat`` tool).

``upload -p POS INDEX SUBINDEX [--type T]`` reads an object and prints it by
its type (given, or taken from the slave's SDO information; raw hex when
neither is known). ``download -p POS INDEX SUBINDEX VALUE [--type T]`` writes
one. ``sdos [-p POS]`` lists the object dictionary as IgH prints it::

    SDO 0x1018, "Identity"
      0x1018:00, r-r-r-, uint8, 8 bit, "Number of entries"

Slaves are chosen as IgH does (``-p``/``-a``). With direct access the slaves
are scanned without a reset and a slave still in INIT (or BOOT) is brought
to PRE-OP first, because the mailbox works only from there; a running master
(``pyethercat run``) is asked through its control socket instead.
"""

from __future__ import annotations

from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import Session, open_session
from pyethercat.cli._types import CliType, encode_download, format_upload, type_name, upload_type
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError
from pyethercat.master.control import messages as msg
from pyethercat.wire.mailbox.datatypes import DataType

__all__ = ["CliType", "register", "format_sdos", "type_name", "format_upload", "upload_type",
           "encode_download"]


def _described(session: Session, position: int, index: int, subindex: int) -> CliType | None:
    """The type the slave's SDO information gives an entry (None if unknown)."""
    reply: msg.EntryType = session.call(msg.SdoEntryType(position, index, subindex))
    if reply.data_type is None:
        return None
    try:
        return CliType(DataType(reply.data_type))
    except ValueError:
        return None


def format_sdos(objects: list[msg.SdoObjectInfo], quiet: bool = False) -> list[str]:
    """The ``sdos`` listing of one slave (IgH layout)."""
    lines: list[str] = []
    for obj in objects:
        if obj.error is not None and not obj.name:
            lines.append(f"SDO 0x{obj.index:04X}, (no description: {obj.error})")
            continue
        lines.append(f"SDO 0x{obj.index:04X}, \"{obj.name}\"")
        if quiet:
            continue
        if obj.error is not None:  # some entries not described
            lines.append(f"  ({obj.error})")
        for e in obj.entries:
            lines.append(f"  0x{obj.index:04X}:{e.subindex:02X}, {e.access_text}, "
                         f"{type_name(e.data_type)}, {e.bit_length} bit, \"{e.name}\"")
    return lines


def register(cli: click.Group) -> None:
    """Add ``upload``, ``download`` and ``sdos``."""

    @cli.command("upload")
    @selection_options
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type (uint8..uint64, int8..int64, float, double, string, "
                       "octet_string, bool, sm8..sm64, raw ...); default: from the slave's "
                       "SDO information.")
    @click.option("--complete-access", "-c", is_flag=True, help="Read all subindices at once.")
    @click.argument("index")
    @click.argument("subindex")
    @click.pass_obj
    def upload_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                   dtype: str | None, complete_access: bool, index: str, subindex: str) -> None:
        """Read an object with an SDO upload and print its value."""
        idx = number(index, "index", 0xFFFF)
        sub = number(subindex, "subindex", 0xFF)
        ct = upload_type(dtype) if dtype is not None else None
        with open_session(obj) as session:
            pos = session.single(position, alias, "upload")
            raw = session.call(msg.SdoUpload(pos, idx, sub, complete_access)).data
            if ct is None and not complete_access:
                ct = _described(session, pos, idx, sub)
            click.echo(format_upload(ct, raw))

    @cli.command("download")
    @selection_options
    @click.option("-t", "--type", "dtype", metavar="T",
                  help="Data type of VALUE; default: from the slave's SDO information.")
    @click.option("--complete-access", "-c", is_flag=True, help="Write all subindices at once.")
    @click.argument("index")
    @click.argument("subindex")
    @click.argument("value")
    @click.pass_obj
    def download_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                     dtype: str | None, complete_access: bool, index: str, subindex: str,
                     value: str) -> None:
        """Write VALUE to an object with an SDO download."""
        idx = number(index, "index", 0xFFFF)
        sub = number(subindex, "subindex", 0xFF)
        ct = upload_type(dtype) if dtype is not None else None
        if ct is not None:
            data = encode_download(ct, value)  # a bad value fails before the segment is touched
        with open_session(obj) as session:
            pos = session.single(position, alias, "download")
            if ct is None:
                if complete_access:
                    ct = CliType(DataType.OCTET_STRING)
                else:
                    ct = _described(session, pos, idx, sub)
                if ct is None:
                    raise ConfigError(f"the slave does not describe 0x{idx:04X}:{sub:02X}: "
                                      "give --type")
                data = encode_download(ct, value)
            session.call(msg.SdoDownload(pos, idx, sub, data, complete_access))

    @cli.command("sdos")
    @selection_options
    @click.option("-q", "--quiet", is_flag=True, help="Objects only, no entries.")
    @click.pass_obj
    def sdos_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                 quiet: bool) -> None:
        """List the object dictionary (SDO information service)."""
        with open_session(obj) as session:
            slaves = session.slaves()
            chosen = [slaves[p] for p in session.select(position, alias) if p < len(slaves)]
            if position is None and alias is None:
                chosen = [s for s in chosen if s.has_coe]
                if not chosen:
                    raise ConfigError("no slave speaks CoE")
            for s in chosen:
                if not s.has_mailbox:
                    raise ConfigError(f"{s.describe()} has no mailbox: no CoE")
                if len(chosen) > 1 or position is None:
                    click.echo(f"=== slave {s.position} ({s.address_text}, {s.name or '?'}) ===")
                objects = session.call(msg.SdoList(s.position, not quiet)).objects
                for line in format_sdos(objects, quiet):
                    click.echo(line)
