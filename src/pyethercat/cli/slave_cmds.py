"""Slave commands: ``slaves``, ``states``, ``rescan``, ``graph``, ``cstruct``, ``crc``, ``counters``.

Formats follow IgH's ``ethercat`` tool (``tool/Command*.cpp``) where it has
the verb: ``slaves`` prints ``0  0:0  PREOP  +  EK1100 ...``, ``graph``
the same Graphviz DOT, ``cstruct`` the same C structures, ``crc`` the same
table. ``slaves -v`` keeps pyethercat's own record (identity, ESC, ports
with their peers, mailbox, SII, the topology tree); ``states`` without a
state and ``counters`` are pyethercat's own.
"""

from __future__ import annotations

from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import Session, open_session
from pyethercat.errors import ConfigError, EtherCATError, StateTimeoutError
from pyethercat.master import diag
from pyethercat.master.control import messages as msg
from pyethercat.master.listing import alias_positions, igh_slave_list, slave_record, topology_tree
from pyethercat.master.slave import Slave
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, al_status_code_name, state_name
from pyethercat.wire.registers import AL_ERROR_FLAG, PortType

__all__ = ["register", "format_graph", "format_cstruct", "format_crc"]


def _chosen(session: Session, position: str | None, alias: str | None) -> list[Slave]:
    slaves = session.slaves()
    wanted = session.select(position, alias)
    return [slaves[p] for p in wanted if p < len(slaves)]


# --- slaves ----------------------------------------------------------------------------------


def _dc_delay(session: Session, slave: Slave) -> tuple[int | None, bool]:
    """(0x0928 as read now, has a system time) of a DC slave, for IgH's delay line."""
    if not slave.dc_supported:
        return None, False
    try:
        session.call(msg.RegRead(slave.position, R.DC_RECEIVE_TIME_ECAT, 8))
    except EtherCATError:
        return None, False  # receive-time latches only (0x0910 on does not answer)
    raw = session.call(msg.RegRead(slave.position, R.DC_SYSTEM_TIME_DELAY, 4)).data
    return int.from_bytes(raw, "little"), True


@click.command("slaves")
@selection_options
@click.option("-v", "--verbose", is_flag=True, help="Identity, ESC, ports, mailbox, SII, topology.")
@click.pass_obj
def slaves_command(obj: dict[str, Any], position: str | None, alias: str | None,
                   verbose: bool) -> None:
    """List the slaves: position, alias:relative position, state, flag (+ ok, E error), name."""
    with open_session(obj) as session:
        slaves = session.slaves()
        chosen = _chosen(session, position, alias)
        groups = _hot_connect_lines(session)
        if not verbose:
            for line in igh_slave_list(slaves, [s.position for s in chosen]):
                click.echo(line)
            for line in groups:
                click.echo(line)
            return
        for n, s in enumerate(chosen):
            if n:
                click.echo("")
            click.echo(slave_record(s, *_dc_delay(session, s)))
        if position is None and alias is None and slaves:
            click.echo("")
            click.echo("=== Topology ===")
            click.echo(topology_tree(slaves))
            if not session.consistent:
                click.echo("# the port states do not explain the ring; positions after the "
                           "first gap are guessed")
        for line in groups:
            click.echo(line)


def _hot_connect_lines(session: Session) -> list[str]:
    """One line per hot connect group of a running master (its presence)."""
    from pyethercat.master.control import ring_ops

    try:
        reply = session.call(ring_ops.HotConnectGroups())
    except EtherCATError:
        return []  # a master that does not serve the request (an older one)
    return [g.text for g in reply.groups]


# --- states ----------------------------------------------------------------------------------


def _state_lines(items: list[msg.SlaveState]) -> list[str]:
    lines = []
    for it in items:
        if not it.answered:
            lines.append(f"{it.position:<5} 0x{it.station_address:04X}  no answer")
            continue
        line = (f"{it.position:<5} 0x{it.station_address:04X}  "
                f"{state_name(it.state | (AL_ERROR_FLAG if it.error else 0))}")
        if it.error:
            line += f"  0x{it.code:04X} {al_status_code_name(it.code)}"
        lines.append(line)
    return lines


@click.command("states")
@click.argument("state", required=False)
@selection_options
@click.option("--wait", is_flag=True, help="Wait until every slave is there, then show the states.")
@click.option("-t", "--timeout", type=float, default=5.0, show_default=True,
              help="Seconds each transition may take (with --wait).")
@click.option("--ack", is_flag=True,
              help="Acknowledge error flags, leaving every slave in its state.")
@click.pass_obj
def states_command(obj: dict[str, Any], state: str | None, position: str | None,
                   alias: str | None, wait: bool, timeout: float, ack: bool) -> None:
    """Request STATE (INIT, PREOP, BOOT, SAFEOP, OP) and return; show the states without STATE.

    As IgH's tool, a request returns once it was sent (the steps before the
    last one are walked: mailbox and process-data set-up, error
    acknowledge); ``--wait`` waits for the slaves and prints their states.
    A slave in error is shown as ``STATE+ERR`` with its AL status code.
    """
    target = None
    if timeout <= 0:
        raise ConfigError(f"states: --timeout must be positive, got {timeout:g}")
    if state is not None:
        if ack:
            raise ConfigError("states: give STATE or --ack, not both (a request "
                              "acknowledges errors first)")
        try:
            target = AlState.parse(state)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    with open_session(obj) as session:
        wanted = None if position is None and alias is None else session.select(position, alias)
        if target is not None:
            try:
                reply = session.call(msg.RequestState(int(target), wanted, wait, timeout))
            except StateTimeoutError as exc:
                if target != AlState.OP:
                    raise
                # The usual surprise: SAFEOP -> OP waits for valid outputs.
                raise StateTimeoutError(
                    f"{exc}; a slave with outputs enters OP only once it receives process "
                    f"data: use 'pyethercat run'") from None
            if target == AlState.OP and not session.remote:
                click.echo("pyethercat: note: a slave with outputs stays in SAFEOP without "
                           "process data; 'pyethercat run' brings the segment to OP", err=True)
            if wait:
                for line in _state_lines(reply.items):
                    click.echo(line)
            return
        if ack:
            done = session.call(msg.AckErrors(wanted)).positions
            click.echo(f"# acknowledged {len(done)} slave{'s' if len(done) != 1 else ''}")
        for line in _state_lines(session.call(msg.ReadStates(wanted)).items):
            click.echo(line)


# --- rescan ----------------------------------------------------------------------------------


@click.command("rescan")
@click.option("-v", "--verbose", is_flag=True, help="Print how many slaves were found.")
@click.pass_obj
def rescan_command(obj: dict[str, Any], verbose: bool) -> None:
    """Scan the bus again (a running master forgets and reads its slaves again)."""
    with open_session(obj) as session:
        count = session.call(msg.Rescan()).slaves
    if verbose:
        click.echo(f"{count} slave{'s' if count != 1 else ''}")


# --- graph -----------------------------------------------------------------------------------

_MEDIA = {PortType.MII: ("MII", 1), PortType.EBUS: ("EBUS", 5)}


def format_graph(slaves: list[Slave], info: str | None = None,
                 counters: dict[int, bytes] | None = None) -> list[str]:
    """The bus as Graphviz DOT, as IgH's ``ethercat graph [DC|CRC]`` writes it."""
    out = ["/* EtherCAT bus graph. Generated by 'pyethercat graph'. */", "",
           "strict graph bus {", '    rankdir="LR"', "    ranksep=0.8", "    nodesep=0.8",
           '    node [fontname="Helvetica"]', '    edge [fontname="Helvetica",fontsize="10"]',
           "", '    master [label="EtherCAT\\nMaster"]']
    if slaves:
        line = "    master -- slave0"
        media = _MEDIA.get(slaves[0].ports[0].type)
        if media is not None:
            line += f'[label="{media[0]}"]'
        out.append(line)
    out.append("")
    rel = alias_positions(slaves)

    def crc(position: int, port: int) -> str:
        data = (counters or {}).get(position, bytes(20))
        return f" [{data[2 * port]}/{data[8 + port]}]"

    for s in slaves:
        alias, pos = rel[s.position]
        label = f"{s.position} / {alias}:{pos}"
        order = s.sii.order_number if s.sii is not None else None
        if order:
            label += f"\\n{order}"
        if info == "DC" and s.dc_supported:
            label += "\\nDC: " + ("64 bit" if s.esc.dc_64bit else "32 bit")
        out.append(f'    slave{s.position} [shape="box",label="{label}"]')
        for port in (1, 2, 3):
            peer = s.ports[port].peer
            if peer is None:
                continue
            tail = f"{port}" + (crc(s.position, port) if info == "CRC" else "")
            head = "0" + (crc(peer.position, 0) if info == "CRC" else "")
            line = f'    slave{s.position} -- slave{peer.position} [taillabel="{tail}",headlabel="{head}"'
            media = _MEDIA.get(s.ports[port].type) or _MEDIA.get(peer.ports[0].type)
            if media is not None:
                line += f',label="{media[0]}"'
            weight = _MEDIA.get(s.ports[port].type)
            if weight is not None:
                line += f',weight="{weight[1]}"'
            out.append(line + "]")
        out.append("")
    out.append("}")
    return out


@click.command("graph")
@click.argument("info", required=False, metavar="[DC|CRC]")
@click.pass_obj
def graph_command(obj: dict[str, Any], info: str | None) -> None:
    """The bus topology as a Graphviz graph (pyethercat graph | dot -Tsvg > bus.svg).

    ``DC`` adds each slave's clock width, ``CRC`` the CRC/forwarded error
    counters of each port.
    """
    kind = info.upper() if info is not None else None
    if kind not in (None, "DC", "CRC"):
        raise ConfigError(f"graph: unknown argument {info!r} (DC or CRC)")
    with open_session(obj) as session:
        slaves = session.slaves()
        counters = None
        if kind == "CRC":
            counters = {c.position: c.data for c in session.call(msg.ErrorCounters()).items}
    for line in format_graph(slaves, kind, counters):
        click.echo(line)


# --- cstruct ---------------------------------------------------------------------------------


def format_cstruct(slave: Slave) -> list[str]:
    """``ec_sync_info_t`` and friends for one slave, as IgH's ``ethercat cstruct`` writes them.

    From the slave's SII: its sync managers and their default PDOs.
    """
    sii = slave.sii
    if sii is None or not sii.sync_managers:
        return []
    ident = f"slave_{slave.position}_"
    syncs: list[str] = []
    pdos: list[str] = []
    entries: list[str] = []
    pdo_pos = entry_pos = 0
    all_pdos = list(sii.rx_pdos) + list(sii.tx_pdos)
    for n, sm in enumerate(sii.sync_managers):
        mine = [p for p in all_pdos if p.sync_manager == n]
        direction = "EC_DIR_OUTPUT" if sm.control & 0x04 else "EC_DIR_INPUT"
        watchdog = "EC_WD_ENABLE" if sm.control & 0x40 else "EC_WD_DISABLE"
        where = f"{ident}pdos + {pdo_pos}" if mine else "NULL"
        syncs.append(f"    {{{n}, {direction}, {len(mine)}, {where}, {watchdog}}},")
        pdo_pos += len(mine)
        for p in mine:
            at = f"{ident}pdo_entries + {entry_pos}" if p.entries else "NULL"
            line = f"    {{0x{p.index:04x}, {len(p.entries)}, {at}}},"
            name = sii.pdo_name(p)
            pdos.append(line + (f" /* {name} */" if name else ""))
            entry_pos += len(p.entries)
            for e in p.entries:
                line = f"    {{0x{e.index:04x}, 0x{e.subindex:02x}, {e.bit_length}}},"
                name = sii.pdo_name(e)
                entries.append(line + (f" /* {name} */" if name else ""))
    ident_lines = [f"/* Master 0, Slave {slave.position}"
                   + (f', "{sii.order_number}"' if sii.order_number else ""),
                   f" * Vendor ID:       0x{slave.identity.vendor_id:08x}",
                   f" * Product code:    0x{slave.identity.product_code:08x}",
                   f" * Revision number: 0x{(slave.identity.revision or 0):08x}",
                   " */", ""]
    out = ident_lines
    if entry_pos:
        out += [f"ec_pdo_entry_info_t {ident}pdo_entries[] = {{", *entries, "};", ""]
    if pdo_pos:
        out += [f"ec_pdo_info_t {ident}pdos[] = {{", *pdos, "};", ""]
    out += [f"ec_sync_info_t {ident}syncs[] = {{", *syncs, "    {0xff}", "};", ""]
    return out


@click.command("cstruct")
@selection_options
@click.pass_obj
def cstruct_command(obj: dict[str, Any], position: str | None, alias: str | None) -> None:
    """C structures of the slaves' PDOs for IgH's ecrt_slave_config_pdos()."""
    with open_session(obj) as session:
        for s in _chosen(session, position, alias):
            for line in format_cstruct(s):
                click.echo(line)


# --- crc / counters -------------------------------------------------------------------------


def format_crc(slaves: list[Slave], counters: dict[int, bytes]) -> list[str]:
    """IgH's ``ethercat crc`` table: CRC, PHY, forwarded errors and next slave per port."""
    out = ["   |" + "".join(f"Port {p}         |" for p in range(4)),
           "   |" + "CRC PHY FWD NXT|" * 4]
    for s in slaves:
        data = counters.get(s.position, bytes(20))
        line = f"{s.position:>3}|"
        for port in range(4):
            p = s.ports[port]
            if p.loop_closed:
                line += " " * 15 + "|"
                continue
            line += f"{data[2 * port]:>3}{data[2 * port + 1]:>4}{data[8 + port]:>4}"
            peer = p.peer
            if port == 0 and peer is None and s.parent is not None:
                peer = s.parent
            if peer is None:
                line += "    "
            elif peer.position == s.position - 1:
                line += "   ↑"
            elif peer.position == s.position + 1:
                line += "   ↓"
            else:
                line += f"{peer.position:>4}"
            line += "|"
        out.append(line + s.name[:11])
    return out


@click.command("crc")
@click.argument("reset", required=False, metavar="[reset]")
@click.pass_obj
def crc_command(obj: dict[str, Any], reset: str | None) -> None:
    """CRC error register diagnosis (0x0300-0x030B per port); ``crc reset`` clears them.

    CRC: invalid frames, PHY: physical-layer errors, FWD: forwarded RX
    errors, NXT: the next slave on the port.
    """
    if reset is not None and reset.lower() != "reset":
        raise ConfigError(f"crc: takes no argument or 'reset', not {reset!r}")
    with open_session(obj) as session:
        slaves = session.slaves()
        reply = session.call(msg.ErrorCounters(clear=reset is not None))
    if reset is not None:
        return
    for line in format_crc(slaves, {c.position: c.data for c in reply.items}):
        click.echo(line)


@click.command("counters")
@click.option("--clear", is_flag=True, help="Clear the counters after showing them.")
@click.pass_obj
def counters_command(obj: dict[str, Any], clear: bool) -> None:
    """Error counters of every slave (invalid frames/RX errors/forwarded/lost links per port)."""
    with open_session(obj) as session:
        items = session.call(msg.ErrorCounters(clear=clear)).items
    report = diag.ErrorCounterReport(tuple(
        diag.decode_error_counters(c.position, c.station_address, c.data, c.ok) for c in items))
    click.echo(report.format())


def register(cli: click.Group) -> None:
    """Add the slave commands to the ``pyethercat`` group."""
    for cmd in (slaves_command, states_command, rescan_command, graph_command, cstruct_command,
                crc_command, counters_command):
        cli.add_command(cmd)
