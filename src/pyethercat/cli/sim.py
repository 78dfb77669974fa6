"""``pyethercat sim``: serve a simulated segment described by a topology file."""

from __future__ import annotations

from pathlib import Path

import click

from pyethercat.errors import ConfigError

__all__ = ["register", "sim_command", "check_control_path"]


@click.command("sim")
@click.argument("topology", type=click.Path(dir_okay=False))
@click.option("--iface", "sim_iface", metavar="IF", help="Serve on this network interface (raw socket).")
@click.option("--udp", "sim_udp", metavar="HOST:PORT", help="Serve EtherCAT over UDP on this address.")
@click.option("--fd", "sim_fd", type=int, hidden=True, help="Serve on an inherited Unix socket fd.")
@click.option("--pcap", metavar="FILE", help="Record every frame in and out (pcapng, or pcap for *.pcap).")
@click.option("--control", metavar="PATH", help="Unix socket for the JSON control channel (faults).")
@click.option("--check", is_flag=True, help="Only load and check the topology, print it and exit.")
@click.option("-q", "--quiet", is_flag=True, help="No start/stop messages on stderr.")
@click.option("--realtime", type=click.IntRange(0, 99), default=0, metavar="PRIO",
              help="Serve under SCHED_FIFO with this priority (1-99; root or CAP_SYS_NICE), so a "
                   "loaded machine does not delay replies past a master's frame timeout.")
@click.pass_context
def sim_command(
    ctx: click.Context,
    topology: str,
    sim_iface: str | None,
    sim_udp: str | None,
    sim_fd: int | None,
    pcap: str | None,
    control: str | None,
    check: bool,
    quiet: bool,
    realtime: int,
) -> None:
    """Serve the simulated segment of TOPOLOGY.toml on an interface or UDP address.

    Runs until interrupted (Ctrl-C / SIGTERM). Frames that are not EtherCAT are
    ignored. Example: pyethercat sim examples/demo.toml --iface pyecat-0a
    """
    from pyethercat.sim.server import open_link, serve
    from pyethercat.sim.topology import load_topology

    if check:
        topo = load_topology(topology)
        for i, s in enumerate(topo.slaves):
            place = "" if s.parent is None else f"  on {s.parent}:{s.port}"
            info = s.info
            click.echo(
                f"{i:3d}  {s.name:<16} 0x{info.vendor_id:08X}:0x{info.product_code:08X}"
                f"  {s.profile.name:<8} in {s.input_bits:>4} b  out {s.output_bits:>4} b"
                f"  {info.device_name or ''}{place}"
            )
        for w in topo.wires:
            click.echo(f"wire {w.src}:{w.src_bit} -> {w.dst}:{w.dst_bit}  {w.bits} bits")
        return
    # The global --iface/--udp (before the command) work too.
    obj = ctx.obj or {}
    iface = sim_iface or obj.get("iface")
    udp = sim_udp or obj.get("udp")
    if sum(x is not None for x in (iface, udp, sim_fd)) != 1:
        raise ConfigError("sim: give exactly one of --iface IF or --udp HOST:PORT (or --check)")
    log = None if quiet else (lambda msg: click.echo(f"pyethercat sim: {msg}", err=True))
    # Load the topology before opening the link: a bad file fails fast.
    load_topology(topology)
    if control is not None:
        check_control_path(control)
    link = open_link(iface=iface, udp=udp, fd=sim_fd, pcap=pcap)
    try:
        stats = serve(topology, link, control=control, log=log, realtime=realtime)
    finally:
        link.close()
    if log is not None:
        d = stats.as_dict()
        log(
            f"stopped: {d['frames']} frames, {d['replies']} replies, {d['lost']} lost, "
            f"mean {d['mean_process_us']} us, max {d['max_process_us']} us per frame"
        )


def check_control_path(path: str) -> None:
    """Refuse a ``--control`` path that cannot be bound or belongs to a running simulator.

    The server replaces a socket file left behind by a simulator that is gone;
    one that still answers is another simulator's control channel.
    """
    import socket
    import stat

    target = Path(path)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise ConfigError(f"--control {path}: directory {parent} does not exist")
    if not target.exists() and not target.is_symlink():
        return
    if not stat.S_ISSOCK(target.lstat().st_mode):
        raise ConfigError(f"--control {path}: exists and is not a socket")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(path)
    except OSError:
        return  # nobody listens: a stale socket file
    finally:
        probe.close()
    raise ConfigError(f"--control {path}: in use by a running simulator (stop it, or give "
                      "another path)")


def register(cli: click.Group) -> None:
    """Add the ``sim`` command to the ``pyethercat`` group."""
    cli.add_command(sim_command)
