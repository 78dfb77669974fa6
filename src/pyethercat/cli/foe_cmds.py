"""FoE commands: ``foe_read`` and ``foe_write`` (in the style of IgH's ``ethercat`` tool).

::

    pyethercat foe_read  -p POS NAME [PASSWORD] [-o FILE]
    pyethercat foe_write -p POS FILE [PASSWORD] [-o|--name NAME] [--boot]

As IgH: ``foe_read`` writes the file to stdout unless ``-o`` names a local
file; ``foe_write`` takes the local FILE (``-`` for stdin, then ``--name`` is
required) and stores it under its base name unless ``--name``/``-o`` says
otherwise. ``--password`` is the same as the positional PASSWORD. A rich
progress bar runs on stderr while a terminal watches (``--quiet`` hides it);
a running master serves the transfer in one request, so the bar then only
shows that it is under way.

``--boot`` updates firmware: the slave goes INIT -> BOOT with its bootstrap
mailbox, the file goes over FoE, then BOOT -> INIT.

A slave in BOOT is served through its bootstrap mailbox; one in INIT is
brought to PRE-OP first (with direct access; a running master keeps its
slaves where they are).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import Session, open_session
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError
from pyethercat.master.control import messages as msg
from pyethercat.wire.mailbox.foe_transfer import FoeProgress

__all__ = ["register"]


def _password(positional: str | None, option: str | None) -> int:
    if positional is not None and option is not None and positional != option:
        raise ConfigError("give the password once (PASSWORD or --password)")
    text = option if option is not None else positional
    return 0 if text is None else number(text, "password", 0xFFFFFFFF)


@contextmanager
def _progress(session: Session, what: str, total: int | None, quiet: bool) -> Iterator[None]:
    """A rich progress bar on stderr (nothing when quiet or stderr is no terminal)."""
    if quiet or not sys.stderr.isatty():
        yield
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
        task = bar.add_task(what, total=total if session.context is not None else None)

        def update(p: FoeProgress) -> None:
            note = f"{what} (slave busy {p.busy.done}/{p.busy.entire})" if p.busy else what
            bar.update(task, completed=p.done, description=note)

        set_progress: Callable[[Any], None] | None = update
        if session.context is not None:
            session.context.transfer_progress = set_progress
        try:
            yield
        finally:
            if session.context is not None:
                session.context.transfer_progress = None


def register(cli: click.Group) -> None:
    """Add ``foe_read`` and ``foe_write``."""

    @cli.command("foe_read")
    @selection_options
    @click.option("-o", "--output-file", metavar="FILE", default="-", show_default=True,
                  help="Local file to write ('-': stdout).")
    @click.option("--password", metavar="P", help="Password (as the PASSWORD argument).")
    @click.option("--max-size", metavar="BYTES", help="Refuse files longer than this.")
    @click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
    @click.argument("name")
    @click.argument("password_arg", metavar="[PASSWORD]", required=False)
    @click.pass_obj
    def foe_read_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                     output_file: str, password: str | None, max_size: str | None,
                     quiet: bool, name: str, password_arg: str | None) -> None:
        """Read file NAME from a slave over FoE."""
        pw = _password(password_arg, password)
        limit = number(max_size, "max size") if max_size is not None else None
        with open_session(obj) as session:
            pos = session.single(position, alias, "foe_read")
            with _progress(session, f"FoE read {name}", None, quiet):
                data = session.call(msg.FoeRead(pos, name, pw, limit)).data
        if output_file == "-":
            sys.stdout.buffer.write(data)
            sys.stdout.buffer.flush()
        else:
            try:
                Path(output_file).write_bytes(data)
            except OSError as exc:
                raise ConfigError(f"cannot write {output_file}: {exc.strerror}") from None

    @cli.command("foe_write")
    @selection_options
    @click.option("-o", "--name", "--output-file", "name", metavar="NAME",
                  help="File name on the slave (default: FILE's base name).")
    @click.option("--password", metavar="P", help="Password (as the PASSWORD argument).")
    @click.option("--boot", is_flag=True,
                  help="Firmware update: INIT -> BOOT (bootstrap mailbox), write, BOOT -> INIT.")
    @click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
    @click.argument("file")
    @click.argument("password_arg", metavar="[PASSWORD]", required=False)
    @click.pass_obj
    def foe_write_cmd(obj: dict[str, Any], position: str | None, alias: str | None,
                      name: str | None, password: str | None, boot: bool, quiet: bool,
                      file: str, password_arg: str | None) -> None:
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
        with open_session(obj) as session:
            pos = session.single(position, alias, "foe_write")
            with _progress(session, f"FoE write {target}", len(data), quiet):
                session.call(msg.FoeWrite(pos, target, data, pw, boot))
