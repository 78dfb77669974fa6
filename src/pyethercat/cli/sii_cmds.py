"""SII commands: ``sii_read``, ``sii_write`` and ``alias`` (IgH's verbs, written safely).

``sii_read`` writes the binary image to stdout when stdout is not a
terminal (as IgH's tool), a hex dump on a terminal, the decoded categories
with ``-v``, or the image to ``-o FILE`` (``-o -``: stdout). ``sii_write
FILE`` (``-`` reads stdin) and ``alias ALIAS`` go through
:mod:`pyethercat.master.sii_write`: the old content is saved first (path
printed), the header checksum computed, every word read back; an image of
another device needs ``--force``; a failure names the word and the command
that restores the backup.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import open_session, spec_of
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError, EtherCATError, SiiError
from pyethercat.master.control import messages as msg
from pyethercat.master.control.protocol import RemoteError
from pyethercat.master.sii_write import SiiWriteError, with_checksum
from pyethercat.wire.sii import parse_sii

__all__ = ["register", "backup_dir", "hexdump"]


def hexdump(data: bytes) -> list[str]:
    return [f"{off:04X}  {data[off:off + 16].hex(' '):<47}  "
            + "".join(chr(b) if 32 <= b < 127 else "." for b in data[off:off + 16])
            for off in range(0, len(data), 16)]


def backup_dir() -> Path:
    """Where old SII contents are kept: ``$XDG_STATE_HOME/pyethercat/sii-backup``."""
    state = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local",
                                                              "state")
    return Path(state) / "pyethercat" / "sii-backup"


def _backup_path(obj: dict[str, Any], position: int, given: str | None) -> Path:
    if given is not None:
        return Path(given).resolve()
    link = spec_of(obj).replace("/", "_").replace(":", "-")[:60]
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return backup_dir() / f"{link}-pos{position}-{stamp}-{os.getpid()}.bin"


def _where(obj: dict[str, Any]) -> str:
    for key in ("iface", "udp", "sim"):
        if obj.get(key) is not None:
            return f"--{key} {obj[key]}"
    return ""


def _restore_hint(obj: dict[str, Any], position: int, exc: EtherCATError) -> EtherCATError:
    """The error with the complete command that puts the backup back."""
    text = str(exc).replace("sii_write --force ",
                            f"pyethercat {_where(obj)} sii_write -p {position} --force ")
    if isinstance(exc, RemoteError):
        return RemoteError(exc.remote_type, text)
    return SiiError(text)


def _report(position: int, result: msg.SiiWriteResult, what: str) -> list[str]:
    lines = []
    if result.identity_changes:
        lines.append(f"note: slave {position} becomes another device: "
                     f"{', '.join(result.identity_changes)}")
    if result.checksum_fixed:
        lines.append(f"note: header checksum set to 0x{result.checksum:02X} (the image had "
                     "another)")
    if result.backup is not None:
        lines.append(f"old SII of slave {position} saved to {result.backup}")
    if not result.written:
        lines.append(f"slave {position}: the EEPROM already holds {what}; nothing written")
    else:
        n = len(result.written)
        lines.append(f"wrote {n} of {result.words} words of the SII of slave {position} "
                     f"({result.words - n} unchanged), each read back; reloaded, "
                     f"alias {result.alias}")
    return lines


@click.command("sii_read")
@selection_options
@click.option("-v", "--verbose", is_flag=True, help="Decode the fixed area and every category.")
@click.option("-o", "--output", "--output-file", "output", metavar="FILE",
              help="Write the binary image to FILE (- for stdout).")
@click.pass_obj
def sii_read_command(obj: dict[str, Any], position: str | None, alias: str | None,
                     verbose: bool, output: str | None) -> None:
    """Read a slave's SII (EEPROM) up to its end marker.

    Binary to stdout when it is not a terminal (as IgH's tool: ``sii_read
    -p 0 > eeprom.bin``), a hex dump on a terminal, decoded with -v.
    """
    with open_session(obj) as session:
        pos = session.single(position, alias, "sii_read")
        image = session.call(msg.SiiRead(pos)).data
    if output == "-" or (output is None and not verbose and not sys.stdout.isatty()):
        sys.stdout.buffer.write(image)
        sys.stdout.buffer.flush()
        return
    if output is not None:
        try:
            with open(output, "wb") as fh:
                fh.write(image)
        except OSError as exc:
            raise ConfigError(f"cannot write {output}: {exc.strerror or exc}") from None
    if verbose:
        click.echo(parse_and_format(image))
    elif output is None:
        for line in hexdump(image):
            click.echo(line)
    else:
        click.echo(f"wrote {len(image)} bytes of SII of slave {pos} to {output}")


def parse_and_format(image: bytes) -> str:
    from pyethercat.wire.sii import format_sii

    return format_sii(parse_sii(image))


def _read_image(file: str) -> bytes:
    if file == "-":
        image = sys.stdin.buffer.read()
        where = "stdin"
    else:
        try:
            with open(file, "rb") as fh:
                image = fh.read()
        except OSError as exc:
            raise ConfigError(f"cannot read {file}: {exc.strerror or exc}") from None
        where = file
    if not image or len(image) % 2:
        raise SiiError(f"{where}: {len(image)} bytes of SII data; an image is a non-zero "
                       "number of 16-bit words")
    return image


@click.command("sii_write")
@selection_options
@click.option("-f", "--force", is_flag=True,
              help="Write an image that does not parse, or of another device; take the EEPROM "
                   "from the slave's firmware.")
@click.option("--all-words", is_flag=True, help="Write every word, not only changed ones.")
@click.option("--backup", metavar="FILE",
              help="Save the old contents here (default: under $XDG_STATE_HOME/pyethercat).")
@click.argument("file", metavar="FILE|-")
@click.pass_obj
def sii_write_command(obj: dict[str, Any], position: str | None, alias: str | None,
                      force: bool, all_words: bool, backup: str | None, file: str) -> None:
    """Write FILE (a binary SII image; - reads stdin) into a slave's EEPROM, then reload it.

    The old contents are saved first and the path printed; the header
    checksum is computed; every word is read back; an image whose vendor,
    product or revision differ from the slave's needs --force.
    """
    image = _read_image(file)
    where = "stdin" if file == "-" else file
    if not force:
        try:
            parse_sii(with_checksum(image), strict=True)
        except SiiError as exc:
            raise SiiError(f"{where}: {exc} (use --force to write it anyway)") from None
    with open_session(obj) as session:
        pos = session.single(position, alias, "sii_write")
        path = _backup_path(obj, pos, backup)
        try:
            result = session.call(msg.SiiWrite(pos, image, force, not all_words, str(path)))
        except (SiiWriteError, RemoteError) as exc:
            if isinstance(exc, RemoteError) and exc.remote_type != "SiiWriteError":
                raise
            raise _restore_hint(obj, pos, exc) from None
    for line in _report(pos, result, "this image"):
        click.echo(line)


@click.command("alias")
@selection_options
@click.option("-f", "--force", is_flag=True,
              help="Write the alias of several slaves; take the EEPROM from the firmware.")
@click.option("--backup", metavar="FILE", help="Save the old contents here (one slave only).")
@click.argument("new_alias", metavar="ALIAS")
@click.pass_obj
def alias_command(obj: dict[str, Any], position: str | None, alias: str | None, force: bool,
                  backup: str | None, new_alias: str) -> None:
    """Write ALIAS (0-65535; 0 removes it) into the slaves' SII word 4, with its checksum.

    The old contents are saved first; the ESC reloads the alias at once.
    Several slaves at once need --force (as IgH's tool).
    """
    value = number(new_alias, "alias", 0xFFFF)
    with open_session(obj) as session:
        chosen = session.select(position, alias)
        if not chosen:
            click.echo("pyethercat: warning: the selection matches no slaves", err=True)
            return
        if len(chosen) > 1 and not force:
            raise ConfigError(f"this writes the alias of {len(chosen)} slaves to {value}; "
                              "give --force to do that")
        if len(chosen) > 1 and backup is not None:
            raise ConfigError("--backup names one file: select one slave")
        for pos in chosen:
            path = _backup_path(obj, pos, backup)
            try:
                result = session.call(msg.SetAlias(pos, value, force, str(path)))
            except (SiiWriteError, RemoteError) as exc:
                if isinstance(exc, RemoteError) and exc.remote_type != "SiiWriteError":
                    raise
                raise _restore_hint(obj, pos, exc) from None
            for line in _report(pos, result, f"alias {value}"):
                click.echo(line)


def register(cli: click.Group) -> None:
    """Add ``sii_read``, ``sii_write`` and ``alias``."""
    for cmd in (sii_read_command, sii_write_command, alias_command):
        cli.add_command(cmd)
