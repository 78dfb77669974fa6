"""A kernel IP stack for a simulated EoE slave: a TAP interface in a network namespace.

:class:`NetnsEndpoint` makes a network namespace (``ip netns add``; its name
starts with ``pyecat-``), creates a TAP interface inside it and plays the
slave's side of that TAP: frames the master sends through EoE are written to
it, frames the namespace's kernel sends on it go back to the master. So ARP,
ping and TCP are answered by Linux itself. A web server (the device's
diagnostic page, :mod:`pyethercat.sim.eoe_web`) listens on port 80 inside the
namespace. Set IP parameter changes the interface (MAC, address, default
route); the DNS server goes to ``/etc/netns/NAME/resolv.conf``, which
``ip netns exec`` shows to programs run there.

A thread enters the namespace with ``setns(2)`` to create the TAP and the
listening socket: both stay in that namespace whatever thread uses them
later. Everything is removed on :meth:`NetnsEndpoint.close` and, for
endpoints still open, when the process exits. Namespaces left behind by a
killed simulator (their name carries its process id) are removed by the next
one. Needs root (``CAP_SYS_ADMIN`` for namespaces, ``CAP_NET_ADMIN`` for TAP).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import ipaddress
import os
import re
import shutil
import subprocess
import threading
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from pyethercat.errors import ConfigError, LinkError, PermissionError
from pyethercat.link.tap import TapLink
from pyethercat.sim.eoe import EoeSettings, FdReader
from pyethercat.wire.mailbox.eoe import EoeIpParameters, EoeResult

__all__ = ["NetnsEndpoint", "NETNS_PREFIX", "cleanup_stale_namespaces", "netns_name"]

#: Every namespace (and interface) the simulator makes starts with this.
NETNS_PREFIX = "pyecat-"
_CLONE_NEWNET = 0x40000000
_RUN_NETNS = Path("/run/netns")
_ETC_NETNS = Path("/etc/netns")
#: Interface name inside the namespace.
IFNAME = "eoe0"
_T = TypeVar("_T")
_live: set[NetnsEndpoint] = set()
_live_lock = threading.Lock()


def netns_name(slave: str) -> str:
    """A fresh namespace name for a slave: ``pyecat-eoe-<pid>-<slave>-<random>``."""
    clean = re.sub(r"[^A-Za-z0-9_.-]", "", slave)[:20] or "slave"
    return f"{NETNS_PREFIX}eoe-{os.getpid()}-{clean}-{uuid.uuid4().hex[:4]}"


def cleanup_stale_namespaces() -> list[str]:
    """Remove ``pyecat-eoe-<pid>-...`` namespaces whose simulator process is gone."""
    removed: list[str] = []
    if not _RUN_NETNS.is_dir():
        return removed
    for entry in _RUN_NETNS.iterdir():
        m = re.match(rf"{NETNS_PREFIX}eoe-(\d+)-", entry.name)
        if m is None or _alive(int(m.group(1))):
            continue
        _delete_netns(entry.name)
        removed.append(entry.name)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _ip(*args: str) -> None:
    ip = shutil.which("ip")
    if ip is None:
        raise ConfigError("the 'ip' command (iproute2) is needed for EoE network namespaces")
    done = subprocess.run([ip, *args], capture_output=True, text=True)
    if done.returncode != 0:
        err = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "failed"
        if "Operation not permitted" in err or "Permission denied" in err:
            raise PermissionError(f"'ip {' '.join(args)}' needs root (network namespaces)")
        raise LinkError(f"'ip {' '.join(args)}': {err}")


def _delete_netns(name: str) -> None:
    with contextlib.suppress(LinkError, ConfigError):
        _ip("netns", "delete", name)
    shutil.rmtree(_ETC_NETNS / name, ignore_errors=True)


def _in_netns(name: str, fn: Callable[[], _T]) -> _T:
    """Run ``fn`` in a thread that joined namespace ``name``; its result."""
    box: list[Any] = []

    def enter() -> None:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = os.open(_RUN_NETNS / name, os.O_RDONLY | os.O_CLOEXEC)
            try:
                if libc.setns(fd, _CLONE_NEWNET) != 0:
                    err = ctypes.get_errno()
                    raise PermissionError(f"entering network namespace {name}: "
                                          f"{os.strerror(err)}; needs root")
            finally:
                os.close(fd)
            box.append(fn())
        except BaseException as exc:  # handed to the caller
            box.append(exc)

    t = threading.Thread(target=enter, name=f"netns-{name}")
    t.start()
    t.join()
    if isinstance(box[0], BaseException):
        raise box[0]
    return box[0]  # type: ignore[no-any-return]


class NetnsEndpoint:
    """The IP side of an EoE slave in its own namespace (see the module text).

    ``status`` gives the diagnostic page its content (identity, state,
    temperatures, errors, a live value); ``settings`` the initial address.
    """

    def __init__(self, settings: EoeSettings, status: Callable[[], dict[str, Any]],
                 name: str) -> None:
        netns = settings.netns or netns_name(name)
        if not netns.startswith(NETNS_PREFIX) or "/" in netns:
            raise ConfigError(f"EoE namespace {netns!r}: names start with {NETNS_PREFIX!r}")
        if os.geteuid() != 0:
            raise PermissionError(f"EoE namespace {netns} needs root (network namespaces "
                                  f"and TAP interfaces)")
        cleanup_stale_namespaces()
        if (_RUN_NETNS / netns).exists():
            raise ConfigError(f"network namespace {netns} exists already (another simulator?)")
        self.netns = netns
        self.settings = settings
        self.mac = settings.mac or _mac_for(netns)
        self.ip = settings.ip
        self.gateway = settings.gateway
        self.dns_server: ipaddress.IPv4Address | None = None
        self.dns_name: str | None = None
        self.frames_in = 0
        self.frames_out = 0
        self._deliver: Callable[[bytes], None] = lambda _f: None
        self._wants: Callable[[], bool] = lambda: True
        self._tap: TapLink | None = None
        self._web: Any = None
        self._closed = False
        _ip("netns", "add", netns)
        with _live_lock:
            _live.add(self)
        try:
            self._tap, self._web = _in_netns(netns, lambda: self._setup(status))
            if self.gateway is not None:
                _ip("-n", netns, "route", "replace", "default", "via", str(self.gateway))
        except BaseException:
            self.close()
            raise

    def _setup(self, status: Callable[[], dict[str, Any]]) -> tuple[TapLink, Any]:
        from pyethercat.sim.eoe_web import start_web_server

        lo = Path("/proc/sys/net/ipv6/conf/default/disable_ipv6")
        with contextlib.suppress(OSError):
            lo.write_text("1")  # no IPv6 chatter through the slow mailbox (this namespace only)
        with contextlib.suppress(LinkError):
            TapLink.set_up("lo")
        tap = TapLink(IFNAME, mac=self.mac, address=self.ip)
        web = start_web_server(status, self.settings.http_port)
        return tap, web

    # -- EoeEndpoint ------------------------------------------------------------------

    def attach(self, deliver: Callable[[bytes], None], wants: Callable[[], bool]) -> None:
        self._deliver = deliver
        self._wants = wants

    def send(self, frame: bytes) -> None:
        if self._tap is not None:
            self.frames_in += 1
            self._tap.send(frame)

    def readers(self) -> list[FdReader]:
        if self._tap is None or self._closed:
            return []
        return [(self._tap.fileno(), self._readable)]

    def _readable(self) -> None:
        tap = self._tap
        if tap is None:
            return
        # One frame per wake-up while the sender has room: the rest waits in the
        # TAP queue, so TCP sees a slow link instead of losses.
        while self._wants():
            frame = tap.recv(0)
            if frame is None:
                return
            self.frames_out += 1
            self._deliver(frame)

    def configure(self, params: EoeIpParameters) -> int:
        try:
            if params.mac is not None:
                mac = params.mac
                _in_netns(self.netns, lambda: self._tap_configure(mac=mac))
                self.mac = mac
            if params.ip is not None:
                mask = params.subnet or (self.ip.netmask if self.ip is not None
                                         else ipaddress.IPv4Address("255.255.255.0"))
                new = ipaddress.IPv4Interface(f"{params.ip}/{mask}")
                _ip("-n", self.netns, "addr", "flush", "dev", IFNAME)
                _ip("-n", self.netns, "addr", "add", str(new), "dev", IFNAME)
                self.ip = new
            if params.gateway is not None:
                _ip("-n", self.netns, "route", "replace", "default", "via", str(params.gateway))
                self.gateway = params.gateway
            if params.dns_server is not None:
                folder = _ETC_NETNS / self.netns
                folder.mkdir(parents=True, exist_ok=True)
                (folder / "resolv.conf").write_text(f"nameserver {params.dns_server}\n")
                self.dns_server = params.dns_server
            if params.dns_name is not None:
                self.dns_name = params.dns_name
        except (LinkError, ConfigError, OSError):
            return EoeResult.UNSPECIFIED_ERROR
        return EoeResult.SUCCESS

    def _tap_configure(self, **kw: Any) -> None:
        assert self._tap is not None
        self._tap.configure(**kw)

    def parameters(self) -> EoeIpParameters:
        return EoeIpParameters(self.mac, self.ip.ip if self.ip else None,
                               self.ip.netmask if self.ip else None, self.gateway,
                               self.dns_server, self.dns_name)

    def close(self) -> None:
        """Stop the web server, remove the TAP and the namespace. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._web is not None:
            with contextlib.suppress(Exception):
                self._web.shutdown()
                self._web.server_close()
        if self._tap is not None:
            self._tap.close()
            self._tap = None
        _delete_netns(self.netns)
        with _live_lock:
            _live.discard(self)


def _mac_for(netns: str) -> bytes:
    """A locally administered unicast MAC derived from the namespace name."""
    digest = uuid.uuid5(uuid.NAMESPACE_DNS, netns).bytes
    return bytes([0x02, 0xEC]) + digest[:4]


@atexit.register
def _close_all() -> None:
    with _live_lock:
        live = list(_live)
    for ep in live:
        ep.close()
