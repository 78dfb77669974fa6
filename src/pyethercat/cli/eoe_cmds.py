"""``pyethercat eoe`` and ``pyethercat ip``: Ethernet over EtherCAT from the command line.

Both reach a running master (``run --eoe``) through its control socket, as
the other verbs do, or open the segment themselves when none runs.

As IgH's ``ethercat eoe`` and ``ethercat ip``:

- ``eoe`` lists the EoE handlers: interface, slave, state, bytes and rates
  each way, the transmit queue, plus frames and drops; ``-v`` adds each
  slave's IP parameters (Get IP parameter);
- ``ip -p POS --ip 192.168.100.10/24 [--gw G] [--mac M] [--dns D] [--name N]``
  sends Set IP parameter; IgH's argument pairs (``addr``, ``link``,
  ``default``, ``dns``, ``name``) work too.

``run --eoe`` (in ``run_cmds``) brings the switch up while the cyclic
exchange runs (:func:`pyethercat.master.eoe_switch.start_eoe`).
"""

from __future__ import annotations

import dataclasses
import ipaddress
from collections.abc import Sequence
from typing import Any

import click

from pyethercat.cli._session import open_session
from pyethercat.cli._util import parse_int
from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.link.tap import format_mac, parse_mac
from pyethercat.master.control import messages as msg
from pyethercat.master.eoe import EoeClient
from pyethercat.wire.mailbox.eoe import EoeIpParameters

__all__ = ["eoe_rows", "format_eoe", "parse_ip_args", "register"]

_IGH_KEYS = {"addr": "ip", "link": "mac", "default": "gw", "dns": "dns", "name": "name"}


def eoe_rows(clients: dict[int, EoeClient], names: dict[int, str], up: bool,
             seconds: float) -> list[dict[str, Any]]:
    """One row per handler (the ``eoe`` listing's data)."""
    rows = []
    for pos, c in sorted(clients.items()):
        st = c.stats
        rows.append({"interface": names.get(pos, "-"), "slave": pos, "state": "up" if up else "down",
                     "rx_bytes": st.rx.bytes, "rx_frames": st.rx.frames,
                     "rx_rate": int(st.rx.bytes / seconds) if seconds > 0 else 0,
                     "tx_bytes": st.tx.bytes, "tx_frames": st.tx.frames,
                     "tx_rate": int(st.tx.bytes / seconds) if seconds > 0 else 0,
                     "tx_queue": f"{c.sender.queued}/{c.sender.queue_limit}",
                     "dropped": st.rx.dropped + st.tx.dropped})
    return rows


def format_eoe(rows: Sequence[dict[str, Any]]) -> list[str]:
    """IgH's ``ethercat eoe`` columns, then frames and drops (rates in byte/s)."""
    out = ["Interface  Slave  State  RxBytes  RxRate  TxBytes  TxRate  TxQueue  "
           "RxFrames  TxFrames  Dropped"]
    for r in rows:
        out.append(f"{r['interface']:>9}  {r['slave']:>5}  {r['state']:>5}  {r['rx_bytes']:>7}  "
                   f"{r['rx_rate']:>6}  {r['tx_bytes']:>7}  {r['tx_rate']:>6}  "
                   f"{r['tx_queue']:>7}  {r['rx_frames']:>8}  {r['tx_frames']:>8}  "
                   f"{r['dropped']:>7}")
    return out


def parse_ip_args(args: Sequence[str], given: dict[str, str | None]) -> EoeIpParameters:
    """Options and IgH-style pairs (``addr A/P link M default G dns D name N``) as parameters."""
    values = dict(given)
    if len(args) % 2:
        raise ConfigError("ip: arguments come in pairs (addr, link, default, dns, name)")
    for key, value in zip(args[::2], args[1::2], strict=True):
        name = _IGH_KEYS.get(key.lower())
        if name is None:
            raise ConfigError(f"ip: unknown argument {key!r} (addr, link, default, dns, name)")
        values[name] = value
    ip = subnet = gw = dns = None
    try:
        if values.get("ip"):
            iface = ipaddress.IPv4Interface(str(values["ip"]))
            ip = iface.ip
            if "/" in str(values["ip"]):
                subnet = iface.netmask
        if values.get("gw"):
            gw = ipaddress.IPv4Address(str(values["gw"]))
        if values.get("dns"):
            dns = ipaddress.IPv4Address(str(values["dns"]))
    except ValueError as exc:
        raise ConfigError(f"ip: {exc}") from None
    mac = parse_mac(str(values["mac"])) if values.get("mac") else None
    name = values.get("name")
    if name is not None and len(name.encode("latin-1", "replace")) > 32:
        raise ConfigError(f"ip: host name {name!r} is longer than 32 bytes")
    params = EoeIpParameters(mac, ip, subnet, gw, dns, name)
    if not params.flags:
        raise ConfigError("ip: nothing to set (give --ip, --gw, --mac, --dns or --name)")
    return params


def register(cli: click.Group) -> None:
    """Add ``eoe`` and ``ip`` to the command line."""

    @cli.command("eoe")
    @click.option("-v", "--verbose", is_flag=True, help="Also each slave's IP parameters.")
    @click.pass_obj
    def eoe_cmd(obj: dict[str, Any], verbose: bool) -> None:
        """List the EoE handlers: interface, slave, state, bytes, rates, queue, drops."""
        with open_session(obj) as session:
            reply: msg.EoeHandlers = session.call(msg.EoeList())
            if not reply.handlers:
                click.echo("no slave speaks EoE")
                return
            for line in format_eoe([dataclasses.asdict(h) for h in reply.handlers]):
                click.echo(line)
            if not verbose:
                return
            for h in reply.handlers:
                try:
                    p: msg.EoeIp = session.call(msg.EoeGetIp(h.slave))
                except EtherCATError as exc:
                    click.echo(f"slave {h.slave}: {exc}")
                    continue
                click.echo(f"slave {h.slave}: ip {p.ip or '-'}/{p.subnet or '-'}, mac "
                           f"{format_mac(p.mac) if p.mac else '-'}, gateway {p.gateway or '-'}, "
                           f"dns {p.dns_server or '-'}, name {p.dns_name or '-'}")

    @cli.command("ip")
    @click.option("-p", "--position", "position", metavar="POS", required=True,
                  help="Slave (ring position).")
    @click.option("--ip", "ip_addr", metavar="ADDR[/PREFIX]", help="IPv4 address (and subnet).")
    @click.option("--gw", metavar="ADDR", help="Default gateway.")
    @click.option("--mac", metavar="MAC", help="MAC address (02:00:00:00:00:01).")
    @click.option("--dns", metavar="ADDR", help="DNS server.")
    @click.option("--name", metavar="NAME", help="Host (DNS) name, up to 32 bytes.")
    @click.argument("pairs", nargs=-1)
    @click.pass_obj
    def ip_cmd(obj: dict[str, Any], position: str, ip_addr: str | None, gw: str | None,
               mac: str | None, dns: str | None, name: str | None, pairs: tuple[str, ...]) -> None:
        """Send Set IP parameter to one EoE slave (IgH pairs: addr A/P link M default G ...)."""
        p = parse_ip_args(pairs, {"ip": ip_addr, "gw": gw, "mac": mac, "dns": dns,
                                  "name": name})
        pos = parse_int(position)

        def text(v: object) -> str | None:
            return None if v is None else str(v)

        with open_session(obj) as session:
            session.call(msg.EoeSetIp(pos, msg.EoeIp(p.mac, text(p.ip), text(p.subnet),
                                                     text(p.gateway), text(p.dns_server),
                                                     p.dns_name)))
