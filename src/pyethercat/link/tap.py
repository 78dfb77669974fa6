"""A Linux TAP interface as a link: Ethernet frames to and from the host's IP stack.

The EoE switch of the master joins EtherCAT slaves to the host through a TAP
interface (the IgH master makes one network device per EoE slave, ``eoeXsY``;
SOEM's ``eoe_test`` sample bridges one slave to a TAP). A frame written to
the TAP's file descriptor is received by the kernel as if it arrived on the
interface; a frame the kernel sends on the interface is read from it. The
device is made with ``TUNSETIFF`` (``IFF_TAP | IFF_NO_PI``: plain Ethernet
frames, no packet-information prefix, see the kernel's
``Documentation/networking/tuntap.rst``) and configured with the classic
``SIOCSIF*`` ioctls (up, MTU, MAC, IPv4 address); it disappears when the
link is closed.

Creating a TAP needs ``CAP_NET_ADMIN`` (root): without it
:class:`~pyethercat.errors.PermissionError` says so in one line.
"""

from __future__ import annotations

import errno
import fcntl
import ipaddress
import os
import select
import socket
import struct

from pyethercat.errors import ConfigError, LinkError, PermissionError
from pyethercat.link.base import MAX_FRAME, MIN_FRAME, Link

__all__ = ["TapLink", "parse_mac", "format_mac", "IFNAMSIZ"]

#: Longest interface name Linux takes (15 characters and the NUL).
IFNAMSIZ = 16
_TUNSETIFF = 0x400454CA
_IFF_TAP = 0x0002
_IFF_NO_PI = 0x1000
_SIOCGIFFLAGS = 0x8913
_SIOCSIFFLAGS = 0x8914
_SIOCSIFADDR = 0x8916
_SIOCSIFNETMASK = 0x891C
_SIOCSIFMTU = 0x8922
_SIOCSIFHWADDR = 0x8924
_IFF_UP = 0x1
_ARPHRD_ETHER = 1
#: Default MTU: a standard Ethernet payload.
DEFAULT_MTU = 1500


def parse_mac(text: str) -> bytes:
    """``02:00:00:00:00:01`` (colons or hyphens) as 6 bytes; :class:`ConfigError` if malformed."""
    parts = text.replace("-", ":").split(":")
    try:
        raw = bytes(int(p, 16) for p in parts)
    except ValueError:
        raise ConfigError(f"invalid MAC address {text!r}") from None
    if len(parts) != 6 or any(len(p) not in (1, 2) for p in parts):
        raise ConfigError(f"invalid MAC address {text!r} (six hex bytes, e.g. 02:00:00:00:00:01)")
    return raw


def format_mac(mac: bytes) -> str:
    """Six bytes as ``02:00:00:00:00:01``."""
    return ":".join(f"{b:02x}" for b in mac)


def _ifreq(name: str, payload: bytes = b"") -> bytes:
    return name.encode().ljust(IFNAMSIZ, b"\x00") + payload.ljust(24, b"\x00")


class TapLink(Link):
    """A TAP interface named ``name`` (made now, removed on :meth:`close`).

    ``mac`` sets the interface's own MAC (default: the kernel's random one),
    ``address`` an IPv4 address with prefix (``"192.168.100.1/24"``), ``mtu``
    the MTU; the interface is brought up. Raises
    :class:`~pyethercat.errors.PermissionError` without ``CAP_NET_ADMIN`` and
    :class:`~pyethercat.errors.LinkError` when the name is taken by another
    kind of interface.
    """

    def __init__(self, name: str, *, mac: bytes | None = None,
                 address: str | ipaddress.IPv4Interface | None = None,
                 mtu: int = DEFAULT_MTU, up: bool = True) -> None:
        if not name or len(name.encode()) >= IFNAMSIZ or "/" in name or " " in name:
            raise ConfigError(f"invalid interface name {name!r} (1..15 characters, no '/' "
                              f"or spaces)")
        super().__init__(name)
        self._fd = -1
        try:
            fd = os.open("/dev/net/tun", os.O_RDWR | os.O_CLOEXEC)
        except FileNotFoundError:
            raise LinkError("no /dev/net/tun: this kernel has no TUN/TAP support") from None
        except OSError as exc:
            raise PermissionError(f"cannot open /dev/net/tun for TAP interface {name}: "
                                  f"{exc.strerror}; run as root or with CAP_NET_ADMIN") from None
        try:
            fcntl.ioctl(fd, _TUNSETIFF, struct.pack(f"{IFNAMSIZ}sH", name.encode(),
                                                    _IFF_TAP | _IFF_NO_PI))
        except OSError as exc:
            os.close(fd)
            if exc.errno == errno.EPERM:
                raise PermissionError(f"creating TAP interface {name} needs root or "
                                      f"CAP_NET_ADMIN") from None
            raise LinkError(f"cannot create TAP interface {name}: {exc.strerror} (is the "
                            f"name taken by another kind of interface?)") from None
        self._fd = fd
        os.set_blocking(fd, False)
        try:
            self.configure(mac=mac, address=address, mtu=mtu, up=up)
        except BaseException:
            self.close()
            raise

    # -- configuration -----------------------------------------------------------

    def configure(self, *, mac: bytes | None = None,
                  address: str | ipaddress.IPv4Interface | None = None,
                  mtu: int | None = None, up: bool | None = None) -> None:
        """Change MAC, IPv4 address, MTU or up/down state (only what is given)."""
        self._check_open()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                if mtu is not None:
                    fcntl.ioctl(s, _SIOCSIFMTU, _ifreq(self.name, struct.pack("i", mtu)))
                if mac is not None:
                    if len(mac) != 6:
                        raise ConfigError(f"a MAC address has 6 bytes, got {len(mac)}")
                    fcntl.ioctl(s, _SIOCSIFHWADDR,
                                _ifreq(self.name, struct.pack("H", _ARPHRD_ETHER) + mac))
                if address is not None:
                    iface = (address if isinstance(address, ipaddress.IPv4Interface)
                             else _parse_interface(address))
                    fcntl.ioctl(s, _SIOCSIFADDR, _ifreq(self.name, _sockaddr_in(iface.ip)))
                    fcntl.ioctl(s, _SIOCSIFNETMASK,
                                _ifreq(self.name, _sockaddr_in(iface.network.netmask)))
                if up is not None:
                    got = fcntl.ioctl(s, _SIOCGIFFLAGS, _ifreq(self.name))
                    flags = struct.unpack_from("H", got, IFNAMSIZ)[0]
                    flags = flags | _IFF_UP if up else flags & ~_IFF_UP
                    fcntl.ioctl(s, _SIOCSIFFLAGS, _ifreq(self.name, struct.pack("H", flags)))
            except OSError as exc:
                if exc.errno == errno.EPERM:
                    raise PermissionError(f"configuring {self.name} needs root or "
                                          f"CAP_NET_ADMIN") from None
                raise LinkError(f"configuring {self.name}: {exc.strerror}") from None

    @staticmethod
    def set_up(name: str) -> None:
        """Bring interface ``name`` (of the caller's namespace) up, e.g. ``lo``."""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                got = fcntl.ioctl(s, _SIOCGIFFLAGS, _ifreq(name))
                flags = struct.unpack_from("H", got, IFNAMSIZ)[0] | _IFF_UP
                fcntl.ioctl(s, _SIOCSIFFLAGS, _ifreq(name, struct.pack("H", flags)))
            except OSError as exc:
                raise LinkError(f"bringing {name} up: {exc.strerror}") from None

    @property
    def mac(self) -> bytes:
        """The interface's MAC address."""
        with open(f"/sys/class/net/{self.name}/address") as f:
            return parse_mac(f.read().strip())

    # -- frames ----------------------------------------------------------------------

    def send(self, frame: bytes) -> None:
        """Hand one frame to the host's stack (dropped when the kernel's queue is full)."""
        self._check_open()
        if not MIN_FRAME <= len(frame) <= MAX_FRAME:
            raise LinkError(f"{self.name}: frame of {len(frame)} bytes "
                            f"(a frame has {MIN_FRAME}..{MAX_FRAME})")
        try:
            os.write(self._fd, frame)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno in (errno.EIO, errno.ENETDOWN):
                return  # the interface is down: like a cable pulled, the frame is lost
            raise LinkError(f"{self.name}: {exc.strerror}") from None

    def recv(self, timeout: float | None = None) -> bytes | None:
        """One frame the host sent on the interface, or None after ``timeout``."""
        self._check_open()
        while True:
            try:
                return os.read(self._fd, 65536)
            except BlockingIOError:
                pass
            except OSError as exc:
                raise LinkError(f"{self.name}: {exc.strerror}") from None
            if timeout == 0:
                return None
            ready, _, _ = select.select([self._fd], [], [], timeout)
            if not ready:
                return None

    def fileno(self) -> int:
        return self._fd

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        super().close()


def _parse_interface(text: str) -> ipaddress.IPv4Interface:
    try:
        return ipaddress.IPv4Interface(text)
    except ValueError:
        raise ConfigError(f"invalid IPv4 address {text!r} (e.g. 192.168.100.1/24)") from None


def _sockaddr_in(addr: ipaddress.IPv4Address) -> bytes:
    return struct.pack("H2s4s", socket.AF_INET, b"\x00\x00", addr.packed)
