"""Master commands: ``master``, ``domains``, ``data``, ``config``, ``version``.

In IgH's tool these show the kernel master and the application's domains
and slave configurations. Here they show the master that runs on the link
(``pyethercat run`` or a program holding ``Master.open``), reached through
its control socket; without one, ``master`` shows the short-lived master of
this command and ``domains``/``data``/``config`` have nothing to show (a
note on stderr says so). Formats are IgH's (``tool/CommandMaster.cpp``,
``CommandDomains.cpp``, ``CommandConfig.cpp``); IgH's byte counters and
device attach state have no counterpart and are left out.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from pyethercat.cli._select import parse_list, select_configs, selection_options
from pyethercat.cli._session import open_session, spec_of
from pyethercat.master.config import ProcessDataConfig
from pyethercat.master.control import messages as msg
from pyethercat.master.control.client import find_master
from pyethercat.master.listing import alias_positions, igh_state
from pyethercat.master.slave import Slave

__all__ = ["register", "format_master", "format_domains", "format_config"]


def _rates(values: list[float], digits: int) -> str:
    return " ".join(f"{v:>6.{digits}f}" for v in values)


def format_master(info: msg.MasterInfo) -> list[str]:
    """``ethercat master`` as IgH prints it (frame counters and rates; no byte counters)."""
    r = info.rates
    loss = [100.0 * lost / tx if tx else 0.0 for lost, tx in zip(r.lost, r.tx, strict=True)]
    lines = [
        "Master0",
        f"  Phase: {'Operation' if info.cycling else 'Idle'}",
        f"  Active: {'yes' if info.cycling else 'no'}",
        f"  Slaves: {info.slaves}",
        "  Ethernet devices:",
        f"    Main: {info.mac} ({info.link})",
        f"      Process: {'running master, pid ' + str(info.pid) if info.running else 'this command (no master runs on the link)'}",
        "    Common:",
        f"      Tx frames:   {info.frames_sent}",
        f"      Rx frames:   {info.frames_received}",
        f"      Lost frames: {info.frames_lost}",
        f"      Timeouts:    {info.timeouts} (after {info.retries} retries)",
        f"      Tx frame rate [1/s]: {_rates(r.tx, 0)}",
        f"      Rx frame rate [1/s]: {_rates(r.rx, 0)}",
        f"      Loss rate [1/s]:     {_rates(r.lost, 0)}",
        f"      Frame loss [%]:      {_rates(loss, 1)}",
    ]
    if info.cycling:
        lines += [
            "  Cyclic exchange:",
            f"    Cycle time [us]: {info.cycle_us:g}",
            f"    Cycles:          {info.cycles}",
            f"    Lost frames:     {info.cycle_lost_frames}",
            f"    WKC errors:      {info.wkc_errors}",
            f"    Late cycles:     {info.late_cycles}",
        ]
    return lines


@click.command("master")
@click.pass_obj
def master_command(obj: dict[str, Any]) -> None:
    """The master: link, slave count, frames sent/received/lost and their rates, cycling."""
    with open_session(obj) as session:
        info = session.call(msg.MasterInfoRequest())
    for line in format_master(info):
        click.echo(line)


def format_domains(domains: list[msg.DomainInfo], verbose: bool) -> list[str]:
    """``ethercat domains [-v]`` lines (IgH format; -v adds FMMUs and the data in hex)."""
    out: list[str] = []
    for d in domains:
        out.append(f"Domain{d.index}: LogBaseAddr 0x{d.logical_base:08x}, Size {d.size:>3}, "
                   f"WorkingCounter {d.wkc}/{d.expected_wkc}")
        if not verbose or not d.size:
            continue
        data = d.data or b""
        for f in d.fmmus:
            out.append(f"  SlaveConfig {f.alias}:{f.relative_position}, SM{f.sync_manager} "
                       f"({'Output' if f.output else ' Input'}), LogAddr "
                       f"0x{f.logical_address:08x}, Size {f.size}")
            start = f.logical_address - d.logical_base
            chunk = data[start:start + f.size]
            for off in range(0, len(chunk), 16):
                out.append("    " + "".join(f"{b:02x} " for b in chunk[off:off + 16]))
    return out


def _no_master_note(session_remote: bool, spec: str) -> None:
    if not session_remote:
        click.echo(f"pyethercat: note: no master runs on {spec}: nothing is exchanged "
                   "(start one with 'pyethercat run')", err=True)


def _checked_domain(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    # While the options are parsed: a bad list fails before the master is reached.
    if value is not None:
        parse_list(value, 0)
    return value


@click.command("domains")
@click.option("-d", "--domain", metavar="N", callback=_checked_domain,
              help="Only this domain (process-data group index).")
@click.option("-v", "--verbose", is_flag=True, help="Slave blocks and process data in hex.")
@click.pass_obj
def domains_command(obj: dict[str, Any], domain: str | None, verbose: bool) -> None:
    """Process-data groups (IgH's domains): logical address, size, working counter."""
    with open_session(obj) as session:
        reply = session.call(msg.Domains(data=verbose))
        remote = session.remote
    chosen = _pick(reply.domains, domain)
    if not reply.domains:
        _no_master_note(remote, spec_of(obj))
    for line in format_domains(chosen, verbose):
        click.echo(line)


def _pick(domains: list[msg.DomainInfo], domain: str | None) -> list[msg.DomainInfo]:
    if domain is None:
        return domains
    wanted = parse_list(domain, len(domains) - 1)
    return [d for d in domains if d.index in wanted]


@click.command("data")
@click.option("-d", "--domain", metavar="N", callback=_checked_domain,
              help="Only this domain (process-data group index).")
@click.pass_obj
def data_command(obj: dict[str, Any], domain: str | None) -> None:
    """The binary process image of every domain, concatenated, to stdout."""
    with open_session(obj) as session:
        reply = session.call(msg.Domains(data=True))
        remote = session.remote
    if not reply.domains:
        _no_master_note(remote, spec_of(obj))
    for d in _pick(reply.domains, domain):
        sys.stdout.buffer.write(d.data or b"")
    sys.stdout.buffer.flush()


def _sm_direction(cfg_sm: Any) -> str:
    return "Output" if cfg_sm.control & 0x04 else "Input"


def format_config(cfg: ProcessDataConfig | None, slaves: list[Slave],
                  states: list[msg.SlaveState], startup: list[msg.StartupSdo],
                  verbose: bool, position: str | None = None,
                  alias: str | None = None) -> list[str]:
    """``ethercat config [-v] [-p POS] [-a ALIAS]`` as IgH prints it, from the running
    master's configuration.

    ``position``/``alias`` select configurations by their ``alias:position``
    address as IgH does (:func:`pyethercat.cli._select.select_configs`).
    """
    if cfg is None:
        return []
    rel = alias_positions(slaves)
    by_pos = {s.position: s for s in slaves}
    state_of = {s.position: igh_state(s.state, s.error) for s in states}
    configured = sorted(cfg.slaves)
    keys = [rel.get(pos, (0, pos)) for pos in configured]
    rows = []
    for k in select_configs(keys, position, alias):
        pos = configured[k]
        s = by_pos.get(pos)
        cfg_alias, relpos = keys[k]
        vendor = s.identity.vendor_id if s is not None else 0
        product = s.identity.product_code if s is not None else 0
        rows.append((pos, str(cfg_alias), str(relpos), f"0x{vendor:08x}/0x{product:08x}",
                     str(pos) if s is not None else "-", state_of.get(pos, "-"), s))
    out: list[str] = []
    if not verbose:
        if not rows:
            return out
        wa = max(len(r[1]) for r in rows)
        wp = max(len(r[2]) for r in rows)
        ws = max(len(r[4]) for r in rows)
        wt = max(len(r[5]) for r in rows)
        for _pos, alias_t, rel_t, ident, spos, state, _s in rows:
            out.append(f"{alias_t:>{wa}}:{rel_t:<{wp}}  {ident}  {spos:<{ws}}  {state:<{wt}}  ")
        return out
    for pos, alias_t, rel_t, _ident, spos, state, s in rows:
        sc = cfg.slaves[pos]
        out += [f"Alias: {alias_t}", f"Position: {rel_t}",
                f"Vendor Id: 0x{(s.identity.vendor_id if s else 0):08x}",
                f"Product code: 0x{(s.identity.product_code if s else 0):08x}",
                f"Attached slave: {spos} ({state})" if s is not None else "Attached slave: none",
                "Watchdog divider: (Default)", "Watchdog intervals: (Default)"]
        for sm in sc.sync_managers:
            if not sm.pdos:
                continue
            wd = "Enable" if sm.control & 0x40 else "Disable"
            out.append(f"SM{sm.index}, Dir: {_sm_direction(sm)}, Watchdog: {wd}")
            for pdo in sm.pdos:
                out.append(f"  PDO 0x{pdo.index:04x}")
                for e in pdo.entries:
                    out.append(f"    PDO entry 0x{e.index:04x}:{e.subindex:02x}, "
                               f"{e.bit_length:>2} bit")
        out.append("SDO configuration:")
        mine = [c for c in startup if c.position == pos]
        if not mine:
            out.append("  None.")
        for c in mine:
            where = " C" if c.complete_access else f":{c.subindex:02x}"
            out.append(f"  0x{c.index:04x}{where}, {len(c.data)} byte ({c.transition})")
            for off in range(0, len(c.data), 16):
                out.append("    " + " ".join(f"{b:02x}" for b in c.data[off:off + 16]))
        out += ["IDN configuration:", "  None.", ""]
    return out


@click.command("config")
@selection_options
@click.option("-v", "--verbose", is_flag=True, help="PDOs, entries and start-up SDOs too.")
@click.pass_obj
def config_command(obj: dict[str, Any], position: str | None, alias: str | None,
                   verbose: bool) -> None:
    """The running master's slave configurations (IgH layout; -p/-a select by alias:position)."""
    with open_session(obj) as session:
        reply = session.call(msg.GetConfig())
        slaves = session.slaves() if reply.config is not None else []
        remote = session.remote
    if reply.config is None:
        _no_master_note(remote, spec_of(obj))
    for line in format_config(reply.config, slaves, reply.states, reply.startup, verbose,
                              position, alias):
        click.echo(line)


@click.command("version")
@click.pass_obj
def version_command(obj: dict[str, Any]) -> None:
    """pyethercat's version (and the running master's, when one runs on the given link)."""
    from pyethercat import __version__

    click.echo(f"pyethercat {__version__}")
    given = obj is not None and any(obj.get(k) for k in ("iface", "udp", "sim"))
    if given:
        client = find_master(spec_of(obj))
        if client is not None:
            with client:
                hello = client.hello
                assert hello is not None
                click.echo(f"running master on {hello.link}: pyethercat {hello.version}, "
                           f"pid {hello.pid}")


def register(cli: click.Group) -> None:
    """Add ``master``, ``domains``, ``data``, ``config`` and ``version``."""
    for cmd in (master_command, domains_command, data_command, config_command, version_command):
        cli.add_command(cmd)

