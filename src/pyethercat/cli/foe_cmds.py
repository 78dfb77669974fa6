"""FoE commands: ``foe_read`` and ``foe_write`` (in the style of IgH's ``ethercat`` tool).

::

    pyethercat foe_read  -p POS NAME [PASSWORD] [-o FILE]
    pyethercat foe_write -p POS FILE [PASSWORD] [-o|--name NAME] [--boot]

As IgH: ``foe_read`` writes the file to stdout unless ``-o`` names a local
file; ``foe_write`` takes the local FILE (``-`` for stdin, then ``--name`` is
required) and stores it under its base name unless ``--name``/``-o`` says
otherwise. ``--password`` is the same as the positional PASSWORD. A rich
progress bar runs on stderr while a terminal watches (``--quiet`` hides it).

``--boot`` updates firmware: the slave goes INIT -> BOOT with its bootstrap
mailbox, the file goes over FoE, then BOOT -> INIT.

Without ``--boot`` the slave is brought to PRE-OP when it is in INIT (the
mailbox works from there); a slave found in BOOT is served through its
bootstrap mailbox.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from pyethercat.cli._connect import connect
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError
from pyethercat.master.bootstrap import boot_mailbox, bootstrap_update
from pyethercat.master.foe import FoeClient, ProgressCallback
from pyethercat.master.mailbox import Mailbox
from pyethercat.master.master import Master
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.foe_transfer import FoeProgress

__all__ = ["foe_client", "register"]


def _password(positional: str | None, option: str | None) -> int:
    if positional is not None and option is not None and positional != option:
        raise ConfigError("give the password once (PASSWORD or --password)")
    text = option if option is not None else positional
    return 0 if text is None else number(text, "password", 0xFFFFFFFF)


def foe_client(m: Master, position: int) -> tuple[Slave, FoeClient]:
    """The FoE client of the slave at ``position`` (scanning first; PRE-OP if in INIT)."""
    m.scan(reset=False)
    s = m.slave(position)
    if s.sii is None or not s.has_mailbox:
        raise ConfigError(f"{s.describe()} has no mailbox: no FoE")
    if s.al_state == AlState.BOOT:
        rx_off, rx_size, tx_off, tx_size = boot_mailbox(s)
        box = Mailbox(m.scheduler, s.station_address, s.describe(), rx_offset=rx_off,
                      rx_size=rx_size, tx_offset=tx_off, tx_size=tx_size)
        return s, FoeClient(box)
    if s.al_state in (AlState.INIT, AlState.NONE):
        m.set_state(AlState.PREOP, [s])
    if s.mbx is None:
        raise ConfigError(f"{s.describe()} has no mailbox: no FoE")
    return s, FoeClient(s.mbx)


@contextmanager
def _progress(what: str, total: int | None, quiet: bool) -> Iterator[ProgressCallback | None]:
    """A rich progress bar on stderr (nothing when quiet or stderr is no terminal)."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        DownloadColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
        TransferSpeedColumn,
    )

    columns = (TextColumn("{task.description}"), BarColumn(), DownloadColumn(),
               TransferSpeedColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(what, total=total)

        def update(p: FoeProgress) -> None:
            note = f"{what} (slave busy {p.busy.done}/{p.busy.entire})" if p.busy else what
            bar.update(task, completed=p.done, description=note)

        yield update


def register(cli: click.Group) -> None:
    """Add ``foe_read`` and ``foe_write``."""

    @cli.command("foe_read")
    @click.option("-p", "--position", metavar="POS", required=True, help="Ring position.")
    @click.option("-o", "--output-file", metavar="FILE", default="-", show_default=True,
                  help="Local file to write ('-': stdout).")
    @click.option("--password", metavar="P", help="Password (as the PASSWORD argument).")
    @click.option("--max-size", metavar="BYTES", help="Refuse files longer than this.")
    @click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
    @click.argument("name")
    @click.argument("password_arg", metavar="[PASSWORD]", required=False)
    @click.pass_obj
    def foe_read_cmd(obj: dict[str, Any], position: str, output_file: str,
                     password: str | None, max_size: str | None, quiet: bool, name: str,
                     password_arg: str | None) -> None:
        """Read file NAME from a slave over FoE."""
        pw = _password(password_arg, password)
        limit = number(max_size, "max size") if max_size is not None else None
        with connect(obj) as conn:
            _s, client = foe_client(conn.master, number(position, "position", 0xFFFF))
            with _progress(f"FoE read {name}", None, quiet) as progress:
                data = client.read(name, password=pw, max_size=limit, progress=progress)
        if output_file == "-":
            sys.stdout.buffer.write(data)
            sys.stdout.buffer.flush()
        else:
            try:
                Path(output_file).write_bytes(data)
            except OSError as exc:
                raise ConfigError(f"cannot write {output_file}: {exc.strerror}") from None

    @cli.command("foe_write")
    @click.option("-p", "--position", metavar="POS", required=True, help="Ring position.")
    @click.option("-o", "--name", "--output-file", "name", metavar="NAME",
                  help="File name on the slave (default: FILE's base name).")
    @click.option("--password", metavar="P", help="Password (as the PASSWORD argument).")
    @click.option("--boot", is_flag=True,
                  help="Firmware update: INIT -> BOOT (bootstrap mailbox), write, BOOT -> INIT.")
    @click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
    @click.argument("file")
    @click.argument("password_arg", metavar="[PASSWORD]", required=False)
    @click.pass_obj
    def foe_write_cmd(obj: dict[str, Any], position: str, name: str | None,
                      password: str | None, boot: bool, quiet: bool, file: str,
                      password_arg: str | None) -> None:
        """Write local FILE to a slave over FoE ('-' reads stdin)."""
        pw = _password(password_arg, password)
        if file == "-":
            if not name:
                raise ConfigError("reading stdin: give the file name on the slave with --name")
            data = sys.stdin.buffer.read()
        else:
            try:
                data = Path(file).read_bytes()
            except OSError as exc:
                raise ConfigError(f"cannot read {file}: {exc.strerror}") from None
        target = name or Path(file).name
        pos = number(position, "position", 0xFFFF)
        with connect(obj) as conn:
            m = conn.master
            with _progress(f"FoE write {target}", len(data), quiet) as progress:
                if boot:
                    m.scan(reset=False)
                    bootstrap_update(m, pos, data, name=target, password=pw, progress=progress)
                else:
                    _s, client = foe_client(m, pos)
                    client.write(target, data, password=pw, progress=progress)
