"""``pyethercat sim``: serve a simulated segment described by a topology file."""

from __future__ import annotations

from pathlib import Path

import click

from pyethercat.errors import ConfigError

__all__ = ["register", "sim_command", "check_control_path"]


@click.command("sim")
@click.argument("topology", type=click.Path(dir_okay=False))
@click.option("--iface", "sim_iface", metavar="IF", help="Serve on this network interface (raw socket).")
@click.option("--redundant-iface", "sim_iface_b", metavar="IF",
              help="Close the ring: master port B (the last slave's free port) on this interface.")
@click.option("--udp", "sim_udp", metavar="HOST:PORT", multiple=True,
              help="Serve EtherCAT over UDP on this address (twice: master ports A and B of a ring).")
@click.option("--fd", "sim_fd", type=int, multiple=True, hidden=True,
              help="Serve on an inherited Unix socket fd (twice: a ring).")
@click.option("--pcap", metavar="FILE", help="Record every frame in and out (pcapng, or pcap for *.pcap).")
@click.option("--control", metavar="PATH", help="Unix socket for the JSON control channel (faults).")
@click.option("--check", is_flag=True, help="Only load and check the topology, print it and exit.")
@click.option("-q", "--quiet", is_flag=True, help="No start/stop messages on stderr.")
@click.option("--realtime", type=click.IntRange(0, 99), default=0, metavar="PRIO",
              help="Serve under SCHED_FIFO with this priority (1-99; root or CAP_SYS_NICE), so a "
                   "loaded machine does not delay replies past a master's frame timeout.")
@click.option("--busy-poll", "busy_poll", type=click.FloatRange(0, 1_000_000), default=None,
              metavar="US", help="Poll for the next frame this long after each frame before "
                                 "blocking (default 100 us; 0: block at once).")
@click.option("--busy-poll-share", "busy_poll_share", type=click.FloatRange(0.01, 1.0), default=None,
              metavar="F", help="Share of each second the polling may take (0.01-1; default: below "
                                "the kernel's real-time share under --realtime, 0.2 on a virtual "
                                "machine, else no limit; 1: no limit).")
@click.option("--cpu", type=click.IntRange(0), default=None, metavar="N",
              help="Pin the simulator to CPU N.")
@click.pass_context
def sim_command(
    ctx: click.Context,
    topology: str,
    sim_iface: str | None,
    sim_iface_b: str | None,
    sim_udp: tuple[str, ...],
    sim_fd: tuple[int, ...],
    pcap: str | None,
    control: str | None,
    check: bool,
    quiet: bool,
    realtime: int,
    busy_poll: float | None,
    busy_poll_share: float | None,
    cpu: int | None,
) -> None:
    """Serve the simulated segment of TOPOLOGY.toml on an interface or UDP address.

    Runs until interrupted (Ctrl-C / SIGTERM). Frames that are not EtherCAT are
    ignored. Example: pyethercat sim examples/demo.toml --iface pyecat-0a

    A ring (cable redundancy): --iface A --redundant-iface B, or --udp twice;
    the last slave's free port is cabled to the second one (or where the
    topology's [segment] ring = "SLAVE:PORT" says).
    """
    from pyethercat.sim.server import DEFAULT_BUSY_POLL_S, serve, serving_link
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
    iface_b = sim_iface_b or obj.get("redundant_iface")
    udps = list(sim_udp) or ([obj["udp"]] if obj.get("udp") else [])
    fds = list(sim_fd)
    kinds = sum(bool(x) for x in (iface, udps, fds))
    if kinds != 1:
        raise ConfigError("sim: give exactly one of --iface IF or --udp HOST:PORT (or --check)")
    if iface_b is not None and not iface:
        raise ConfigError("sim: --redundant-iface goes with --iface (the ring's port A)")
    if len(udps) > 2 or len(fds) > 2:
        raise ConfigError("sim: a ring has two master ports: give --udp at most twice")
    spec_b: dict[str, object] | None = None
    if iface_b is not None:
        spec_b = {"iface": iface_b}
    elif len(udps) == 2:
        spec_b = {"udp": udps[1]}
    elif len(fds) == 2:
        spec_b = {"fd": fds[1]}
    log = None if quiet else (lambda msg: click.echo(f"pyethercat sim: {msg}", err=True))
    # Load the topology before opening the link: a bad file fails fast.
    load_topology(topology)
    if control is not None:
        check_control_path(control)
    link = serving_link(iface=iface, udp=udps[0] if udps else None, fd=fds[0] if fds else None,
                     pcap=pcap)
    link_b = None
    try:
        if spec_b is not None:
            link_b = serving_link(**spec_b, pcap=None if pcap is None else _port_b_capture(pcap))  # type: ignore[arg-type]
        stats = serve(topology, link, control=control, log=log, realtime=realtime, link_b=link_b,
                      busy_poll_s=DEFAULT_BUSY_POLL_S if busy_poll is None else busy_poll / 1e6,
                      busy_poll_share=busy_poll_share, cpu=cpu)
    finally:
        link.close()
        if link_b is not None:
            link_b.close()
    if log is not None:
        d = stats.as_dict()
        log(
            f"stopped: {d['frames']} frames, {d['replies']} replies, {d['lost']} lost, "
            f"mean {d['mean_process_us']} us, max {d['max_process_us']} us per frame"
        )


def _port_b_capture(pcap: str) -> str:
    """The capture file of port B beside port A's: ``x.pcapng`` -> ``x-b.pcapng``."""
    p = Path(pcap)
    return str(p.with_name(f"{p.stem}-b{p.suffix}"))


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
