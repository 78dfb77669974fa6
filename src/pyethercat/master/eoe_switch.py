"""The master's Ethernet switch: EoE slaves and the host's IP stack on one layer-2 network.

The 2003 EtherCAT article describes a switch in the master that carries
Ethernet frames between the EoE slaves and the host's IP stack and behaves
as a layer-2 switch that only looks at Ethernet addresses. :class:`EoeSwitch`
is that switch, without I/O: ports (the host's TAP interface, each EoE
slave) are callables that take a frame; it learns source addresses, sends a
frame to the one port behind its destination, and floods broadcasts,
multicasts and unknown destinations to every other port. Frames between two
slaves never touch the host.

:class:`EoeBridge` wires it up: TAP interfaces (:class:`~pyethercat.link.tap.TapLink`)
and a thread that reads them, and the slaves' :class:`~pyethercat.master.eoe.EoeClient`.
Two layouts:

- ``switch`` (default): one TAP (``eoe0`` or a name given) with the switch
  between it and every EoE slave;
- ``per-slave``: one TAP per slave named ``<prefix>s<position>`` (IgH's
  ``eoe0s3`` for master 0, slave 3), each wired to its slave only, as IgH's
  EoE network devices are (users join them with a Linux bridge if they want).

The TAP comes up with MTU 1500 and, if given, an IPv4 address for the host.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import queue
import select
import threading
import time
import weakref
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pyethercat.errors import ConfigError, LinkError
from pyethercat.link.tap import DEFAULT_MTU, TapLink
from pyethercat.master.eoe import EoeClient, EoeService, eoe_clients

__all__ = ["EoeBridge", "EoeRun", "EoeSwitch", "SwitchPortStats", "SwitchPort", "running_eoe",
           "start_eoe"]

_log = logging.getLogger("pyethercat.eoe")
#: Frames waiting for a TAP's writer at most (more are dropped, counted at the port).
TAP_QUEUE = 512
#: Seconds a learned address is kept without traffic from it (as 802.1D's default).
DEFAULT_AGING = 300.0


@dataclass
class SwitchPortStats:
    """Frames and bytes through one switch port (in = from the port into the switch)."""

    frames_in: int = 0
    bytes_in: int = 0
    frames_out: int = 0
    bytes_out: int = 0
    #: Frames the port could not take (its queue full).
    dropped: int = 0


@dataclass
class SwitchPort:
    """One port: a name and the callable that takes frames out of the switch."""

    name: str
    send: Callable[[bytes], bool]
    stats: SwitchPortStats = field(default_factory=SwitchPortStats)


class EoeSwitch:
    """A learning layer-2 switch between ports (see the module text)."""

    def __init__(self, aging: float = DEFAULT_AGING) -> None:
        self.aging = aging
        self.ports: list[SwitchPort] = []
        self._table: dict[bytes, tuple[int, float]] = {}
        self._lock = threading.Lock()

    def add_port(self, name: str, send: Callable[[bytes], bool]) -> int:
        """A new port; its number."""
        self.ports.append(SwitchPort(name, send))
        return len(self.ports) - 1

    def lookup(self, mac: bytes) -> int | None:
        """The port a MAC address was last seen on (None: unknown or aged out)."""
        got = self._table.get(mac)
        if got is None or time.monotonic() - got[1] > self.aging:
            return None
        return got[0]

    def forward(self, port: int, frame: bytes, now: float | None = None) -> int:
        """A frame entered on ``port``: learn its source, send it on; how many ports
        it was for refused it (their queues full)."""
        if len(frame) < 14:
            return 0
        now = time.monotonic() if now is None else now
        src_port = self.ports[port]
        src_port.stats.frames_in += 1
        src_port.stats.bytes_in += len(frame)
        dst, src = frame[:6], frame[6:12]
        if not src[0] & 1:
            with self._lock:
                self._table[src] = (port, now)
        target: int | None = None
        if not dst[0] & 1:  # unicast
            got = self._table.get(dst)
            if got is not None and now - got[1] <= self.aging:
                target = got[0]
        if target is not None:
            return 0 if target == port or self._out(target, frame) else 1
        return sum(not self._out(n, frame) for n in range(len(self.ports)) if n != port)

    def _out(self, n: int, frame: bytes) -> bool:
        p = self.ports[n]
        if p.send(frame):
            p.stats.frames_out += 1
            p.stats.bytes_out += len(frame)
            return True
        p.stats.dropped += 1
        return False


class EoeBridge:
    """TAP interface(s), the switch and the reader thread (see the module text).

    ``clients`` maps ring positions to EoE clients. ``tap`` is the TAP name
    (``switch``) or the name prefix (``per-slave``); ``host_ip`` the host's
    address on the TAP (``"192.168.100.1/24"``), optional.
    """

    def __init__(self, clients: Mapping[int, EoeClient], *, tap: str = "eoe0",
                 per_slave: bool = False, host_ip: str | None = None,
                 mtu: int = DEFAULT_MTU, ipv6: bool = False) -> None:
        if not clients:
            raise ConfigError("no slave speaks EoE: nothing to bridge")
        self.per_slave = per_slave
        self.clients = dict(clients)
        self.taps: list[TapLink] = []
        self.switches: list[EoeSwitch] = []
        #: (TAP, switch, port of the TAP) for the reader thread.
        self._inputs: list[tuple[TapLink, EoeSwitch, int, list[EoeClient]]] = []
        #: TAP name per slave position (for the ``eoe`` listing).
        self.names: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        #: Per TAP: the queue of frames for the host and the thread that writes them.
        self._writers: list[tuple[TapLink, queue.SimpleQueue[bytes | None]]] = []
        self._writer_threads: list[threading.Thread] = []
        try:
            address = ipaddress.IPv4Interface(host_ip) if host_ip is not None else None
        except ValueError:
            raise ConfigError(f"invalid host address {host_ip!r} (e.g. 192.168.100.1/24)") from None
        if per_slave and address is not None:
            raise ConfigError("one TAP per slave: give each interface its address with "
                              "'ip addr add' (a host address goes with the switched TAP)")
        try:
            if per_slave:
                for pos, client in sorted(self.clients.items()):
                    link = self._tap(f"{tap}s{pos}", None, mtu, ipv6)
                    self._join(link, [(pos, client)])
            else:
                link = self._tap(tap, address, mtu, ipv6)
                self._join(link, sorted(self.clients.items()))
        except BaseException:
            self.close()
            raise

    def _tap(self, name: str, address: ipaddress.IPv4Interface | None, mtu: int,
             ipv6: bool) -> TapLink:
        link = TapLink(name, address=address, mtu=mtu, up=False)
        if not ipv6:
            with contextlib.suppress(OSError), open(
                    f"/proc/sys/net/ipv6/conf/{name}/disable_ipv6", "w") as f:
                f.write("1")
        link.configure(up=True)
        self.taps.append(link)
        return link

    def _join(self, link: TapLink, members: list[tuple[int, EoeClient]]) -> None:
        sw = EoeSwitch()
        host = sw.add_port(link.name, self._to_tap(link))
        for pos, client in members:
            port = sw.add_port(f"slave {pos}", client.send)
            client.on_frame = self._from_slave(sw, port, client)
            self.names[pos] = link.name
        self.switches.append(sw)
        self._inputs.append((link, sw, host, [c for _, c in members]))

    def _to_tap(self, link: TapLink) -> Callable[[bytes], bool]:
        # Frames for the host go through a queue to a writer thread: a TAP write runs the
        # host's IP stack (TCP included) in the writer's time, 15-25 us a frame, which
        # the cyclic loop's thread, where the EoE service delivers them, must not pay.
        out: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._writers.append((link, out))

        def send(frame: bytes) -> bool:
            if out.qsize() >= TAP_QUEUE:
                return False  # the host does not keep up: dropped, as a full switch port
            out.put(frame)
            return True
        return send

    @staticmethod
    def _write_loop(link: TapLink, out: queue.SimpleQueue[bytes | None]) -> None:
        while True:
            frame = out.get()
            if frame is None:
                return
            try:
                link.send(frame)
            except LinkError:
                return  # the TAP is gone (closing)

    @staticmethod
    def _from_slave(sw: EoeSwitch, port: int, client: EoeClient) -> Callable[[bytes], None]:
        def deliver(frame: bytes) -> None:
            if sw.forward(port, frame):
                # (the host's or another slave's queue was full: the slave's frame is
                # lost, and its handler's Dropped column says so)
                client.stats.rx.dropped += 1
        return deliver

    # -- running ---------------------------------------------------------------------

    def start(self) -> EoeBridge:
        """Read the TAP(s) in a thread of their own."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="ecat-eoe-tap", daemon=True)
        self._thread.start()
        for link, out in self._writers:
            t = threading.Thread(target=self._write_loop, args=(link, out),
                                 name=f"ecat-eoe-{link.name}", daemon=True)
            t.start()
            self._writer_threads.append(t)
        return self

    def _loop(self) -> None:
        inputs = {link.fileno(): (link, sw, port, members)
                  for link, sw, port, members in self._inputs}
        while not self._stop.is_set():
            # Read a TAP only while all its slaves have room: the rest waits in the
            # kernel's queue, so TCP sees a slow link instead of losses.
            fds = [fd for fd, (_l, _s, _p, members) in inputs.items()
                   if all(c.has_room for c in members)]
            if not fds:
                self._stop.wait(0.0005)
                continue
            try:
                ready, _, _ = select.select(fds, [], [], 0.05)
            except (OSError, ValueError):
                return
            for fd in ready:
                link, sw, port, members = inputs[fd]
                for _ in range(16):
                    if not all(c.has_room for c in members):
                        break
                    try:
                        frame = link.recv(0)
                    except LinkError:
                        return
                    if frame is None:
                        break
                    sw.forward(port, frame)

    def close(self) -> None:
        """Stop the thread and remove the TAP interface(s). Idempotent."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join()
        self._thread = None
        for c in self.clients.values():
            c.on_frame = None
        for _link, out in self._writers:
            out.put(None)
        for w in self._writer_threads:
            w.join()
        self._writer_threads = []
        for link in self.taps:
            link.close()
        self.taps = []

    def __enter__(self) -> EoeBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class EoeRun:
    """The EoE parts of a running master: the service, the bridge and when they started."""

    service: EoeService
    bridge: EoeBridge
    clients: dict[int, EoeClient]
    started: float

    def close(self) -> None:
        """Remove the TAP(s) and stop moving fragments."""
        self.bridge.close()
        self.service.stop()
        _RUNNING.pop(self.service.scheduler, None)


#: The EoE run of a master, by its scheduler (what the control socket's ``eoe`` shows).
_RUNNING: weakref.WeakKeyDictionary[Any, EoeRun] = weakref.WeakKeyDictionary()


def running_eoe(master: Any) -> EoeRun | None:
    """The EoE run started on ``master`` (None: no switch up)."""
    return _RUNNING.get(master.scheduler)


def start_eoe(master: Any, runner: Any, *, tap: str = "eoe0", host_ip: str | None = None,
              per_slave: bool = False) -> EoeRun:
    """EoE clients for every EoE slave, ticking with ``runner``'s cycle, joined to TAP(s)."""
    clients = eoe_clients(master.slaves)
    if not clients:
        raise ConfigError("no slave announces EoE in its SII")
    bridge = EoeBridge(clients, tap=tap, host_ip=host_ip, per_slave=per_slave)
    service = EoeService(master.scheduler, list(clients.values()))
    offsets = {p: (runner.config.slaves[p].group, runner.config.slaves[p].mailbox_status_offset)
               for p in clients if p in runner.config.slaves}
    service.attach(runner, offsets)
    bridge.start()
    run = EoeRun(service, bridge, clients, time.monotonic())
    _RUNNING[master.scheduler] = run
    return run
