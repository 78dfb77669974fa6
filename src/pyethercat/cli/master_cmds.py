"""Diagnostic master commands: ``slaves``, ``states``, ``reg_read``, ``reg_write``,
``sii_read``, ``sii_write`` and ``counters`` (in the style of IgH's ``ethercat`` tool).

Listing commands scan without resetting the slaves (states stay as they
are); ``reg_*`` and ``sii_*`` address a slave by ring position and need no
scan at all. Output is plain text, one record per line where possible.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

import click

from pyethercat.cli._connect import connect
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError, SiiError, StateTimeoutError
from pyethercat.master.listing import slave_record, slave_table, topology_tree
from pyethercat.master.master import Master
from pyethercat.master.scan import Progress
from pyethercat.wire.al import AlState, al_status_code_name, state_name
from pyethercat.wire.registers import (
    AL_CONTROL,
    AL_ERROR_FLAG,
    AL_STATE_MASK,
    AL_STATUS,
    AL_STATUS_CODE,
    REGISTERS,
    register_containing,
)

__all__ = ["register"]


# --- helpers ----------------------------------------------------------------------------


def _hex_data(text: str) -> bytes:
    """``"01 02"``, ``"0102"``, ``"01:02"`` or ``"0x0102"`` -> bytes in the given order."""
    cleaned = text.strip()
    if cleaned.lower().startswith("0x"):
        cleaned = cleaned[2:]
    for sep in (" ", ":", ",", "-"):
        cleaned = cleaned.replace(sep, "")
    try:
        data = bytes.fromhex(cleaned)
    except ValueError:
        raise ConfigError(f"not hex data: {text!r} (write bytes like 01 02 or 0102)") from None
    if not data:
        raise ConfigError("no data to write")
    return data


@contextmanager
def _progress_bar(enabled: bool) -> Iterator[Progress | None]:
    """A progress callback drawing a bar on a terminal's stderr (nothing otherwise)."""
    if not enabled or not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                  console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("scanning", total=None)

        def update(stage: str, done: int, total: int) -> None:
            what = "reading SII" if stage == "sii" else stage
            bar.update(task, description=what, completed=done, total=total or None)

        yield update


def _scan(master: Master, reset: bool = False) -> None:
    with _progress_bar(True) as progress:
        master.scan(reset=reset, progress=progress)


def _check_position(master: Master, position: int) -> None:
    count = master.count_slaves()
    if not 0 <= position < count:
        raise ConfigError(f"no slave at position {position}: the segment has {count} "
                          f"slave{'s' if count != 1 else ''}")


# --- slaves / states ----------------------------------------------------------------------


@click.command("slaves")
@click.option("-v", "--verbose", is_flag=True, help="Identity, ESC, ports, mailbox, SII, topology.")
@click.option("-p", "--position", metavar="POS", help="Only this slave.")
@click.pass_context
def slaves_command(ctx: click.Context, verbose: bool, position: str | None) -> None:
    """List the slaves: position, station address/alias, state, flag (+ ok, E error), name."""
    with connect(ctx.obj) as conn:
        m = conn.master
        _scan(m)
        chosen = m.slaves
        if position is not None:
            chosen = [m.slave(number(position, "position"))]
        if not m.slaves:
            click.echo("# no slaves found")
            return
        if not verbose:
            click.echo(slave_table(chosen))
            return
        for n, s in enumerate(chosen):
            if n:
                click.echo("")
            click.echo(slave_record(s))
        if position is None:
            click.echo("")
            click.echo("=== Topology ===")
            click.echo(topology_tree(m.slaves))
            if not m.topology_consistent:
                click.echo("# the port states do not explain the ring; positions after the "
                           "first gap are guessed")


@click.command("states")
@click.argument("state", required=False)
@click.option("-p", "--position", metavar="POS", help="Only this slave.")
@click.option("-t", "--timeout", type=float, default=5.0, show_default=True,
              help="Seconds each transition may take.")
@click.option("--ack", is_flag=True,
              help="Acknowledge error flags, leaving every slave in its state.")
@click.pass_context
def states_command(ctx: click.Context, state: str | None, position: str | None,
                   timeout: float, ack: bool) -> None:
    """Show the AL state of every slave, or request STATE (INIT, PREOP, BOOT, SAFEOP, OP).

    A slave showing an error flag is acknowledged before the request (it
    ignores requests while flagged); ``--ack`` acknowledges without a request.
    A slave in error is shown as ``STATE+ERR`` with its AL status code.
    """
    target = None
    if state is not None:
        if ack:
            raise ConfigError("states: give STATE or --ack, not both (a request "
                              "acknowledges errors first)")
        try:
            target = AlState.parse(state)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    with connect(ctx.obj) as conn:
        m = conn.master
        _scan(m)
        chosen = m.slaves if position is None else [m.slave(number(position, "position"))]
        if target is not None:
            try:
                m.set_state(target, chosen, timeout=timeout, configure=True)
            except StateTimeoutError as exc:
                if target != AlState.OP:
                    raise
                # The usual surprise: SAFEOP -> OP waits for valid outputs.
                raise StateTimeoutError(
                    f"{exc}; a slave with outputs enters OP only once it receives process "
                    f"data: use 'pyethercat run'") from None
        elif ack:
            done = m.acknowledge_errors(chosen)
            click.echo(f"# acknowledged {len(done)} slave{'s' if len(done) != 1 else ''}")
        m.read_states(chosen)
        for s in chosen:
            line = f"{s.position:<5} 0x{s.station_address:04X}  {s.al_state_name}"
            if s.al_error:
                line += f"  0x{s.al_status_code:04X} {al_status_code_name(s.al_status_code)}"
            click.echo(line)


# --- registers ----------------------------------------------------------------------------


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


@click.command("reg_read")
@click.option("-p", "--position", metavar="POS", required=True, help="Ring position of the slave.")
@click.argument("address")
@click.argument("size")
@click.pass_context
def reg_read_command(ctx: click.Context, position: str, address: str, size: str) -> None:
    """Read SIZE bytes at ADDRESS of one slave: hex dump with register names."""
    pos = number(position, "position")
    addr = number(address, "address")
    count = number(size, "size")
    if not 0 <= addr <= 0xFFFF or not 1 <= count <= 0x10000 - addr or count > 1486:
        raise ConfigError(f"cannot read {count} bytes at 0x{addr:04X} "
                          "(addresses 0x0000-0xFFFF, at most 1486 bytes)")
    with connect(ctx.obj) as conn:
        _check_position(conn.master, pos)
        data = conn.master.read(pos, addr, count)
    for line in format_registers(addr, data):
        click.echo(line)


@click.command("reg_write")
@click.option("-p", "--position", metavar="POS", required=True, help="Ring position of the slave.")
@click.argument("address")
@click.argument("data", metavar="HEXDATA")
@click.pass_context
def reg_write_command(ctx: click.Context, position: str, address: str, data: str) -> None:
    """Write HEXDATA (bytes in memory order, e.g. "02 00") at ADDRESS of one slave."""
    pos = number(position, "position")
    addr = number(address, "address")
    payload = _hex_data(data)
    if not 0 <= addr <= 0xFFFF or len(payload) > min(1486, 0x10000 - addr):
        raise ConfigError(f"cannot write {len(payload)} bytes at 0x{addr:04X}")
    with connect(ctx.obj) as conn:
        _check_position(conn.master, pos)
        conn.master.write(pos, addr, payload)
    reg = register_containing(addr)
    name = f" ({reg.name})" if reg is not None and reg.address == addr else ""
    click.echo(f"wrote {len(payload)} byte{'s' if len(payload) != 1 else ''} at 0x{addr:04X}"
               f"{name} of slave {pos}")


# --- SII ----------------------------------------------------------------------------------


def _hexdump(data: bytes) -> list[str]:
    return [f"{off:04X}  {data[off:off + 16].hex(' '):<47}  "
            + "".join(chr(b) if 32 <= b < 127 else "." for b in data[off:off + 16])
            for off in range(0, len(data), 16)]


@click.command("sii_read")
@click.option("-p", "--position", metavar="POS", required=True, help="Ring position of the slave.")
@click.option("-v", "--verbose", is_flag=True, help="Decode the fixed area and every category.")
@click.option("-o", "--output", metavar="FILE", type=click.Path(dir_okay=False),
              help="Write the binary image to FILE.")
@click.pass_context
def sii_read_command(ctx: click.Context, position: str, verbose: bool,
                     output: str | None) -> None:
    """Read a slave's SII (EEPROM) up to its end marker: hex dump, decoded (-v) or to a file."""
    from pyethercat.wire.sii import format_sii, parse_sii

    pos = number(position, "position")
    with connect(ctx.obj) as conn:
        _check_position(conn.master, pos)
        image = conn.master.sii_read(pos)
    if output is not None:
        try:
            with open(output, "wb") as fh:
                fh.write(image)
        except OSError as exc:
            raise ConfigError(f"cannot write {output}: {exc.strerror or exc}") from None
    if verbose:
        click.echo(format_sii(parse_sii(image)))
    elif output is None:
        for line in _hexdump(image):
            click.echo(line)
    else:
        click.echo(f"wrote {len(image)} bytes of SII of slave {pos} to {output}")


@click.command("sii_write")
@click.option("-p", "--position", metavar="POS", required=True, help="Ring position of the slave.")
@click.option("--force", is_flag=True, help="Write even if the image does not parse cleanly.")
@click.option("--all-words", is_flag=True, help="Write every word, not only changed ones.")
@click.argument("file", type=click.Path(dir_okay=False))
@click.pass_context
def sii_write_command(ctx: click.Context, position: str, force: bool, all_words: bool,
                      file: str) -> None:
    """Write FILE (a binary SII image) into a slave's EEPROM, then reload it."""
    from pyethercat.wire.sii import parse_sii

    pos = number(position, "position")
    try:
        with open(file, "rb") as fh:
            image = fh.read()
    except OSError as exc:
        raise ConfigError(f"cannot read {file}: {exc.strerror or exc}") from None
    try:
        info = parse_sii(image, strict=not force)
    except SiiError as exc:
        raise SiiError(f"{file}: {exc} (use --force to write it anyway)") from None
    if not info.checksum_ok and not force:
        raise SiiError(f"{file}: bad SII checksum (use --force to write it anyway)")
    with connect(ctx.obj) as conn:
        _check_position(conn.master, pos)
        with _progress_bar(True) as progress:
            written = conn.master.sii_write(pos, image, only_changed=not all_words,
                                            progress=progress)
    words = (len(image) + 1) // 2
    click.echo(f"wrote {written} of {words} words to the SII of slave {pos} "
               f"({words - written} unchanged), reloaded")


# --- counters -----------------------------------------------------------------------------


@click.command("counters")
@click.option("--clear", is_flag=True, help="Clear the counters after showing them.")
@click.pass_context
def counters_command(ctx: click.Context, clear: bool) -> None:
    """Error counters of every slave (invalid frames/RX errors/forwarded/lost links per port)."""
    with connect(ctx.obj) as conn:
        m = conn.master
        _scan(m)
        click.echo(m.error_counters().format())
        if clear:
            m.clear_error_counters()


def register(cli: click.Group) -> None:
    """Add the diagnostic master commands to the ``pyethercat`` group."""
    for cmd in (slaves_command, states_command, reg_read_command, reg_write_command,
                sii_read_command, sii_write_command, counters_command):
        cli.add_command(cmd)

