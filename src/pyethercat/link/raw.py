"""Raw Ethernet link: an ``AF_PACKET`` socket bound to one interface (Linux).

Only frames with EtherType 0x88A4 reach the socket: the protocol is set at
``bind`` time on the interface, so nothing from other interfaces slips in
between creating and binding the socket. Frames the kernel loops back to us
(our own transmissions, packet type ``PACKET_OUTGOING``; ``packet(7)``) are
dropped, so ``recv`` returns only frames that came in from the wire, whatever
source MAC they carry: the link tells direction (``sees_own_frames`` is
False), and a master takes an incoming frame with its own source MAC as a
reply (KickCAT's ESC emulator returns frames without setting the locally
administered bit).

Opening the socket needs ``CAP_NET_RAW``; without it
:class:`pyethercat.errors.PermissionError` says how to get it.

The socket stays in blocking mode so that a wait is one system call: a
frame that is already queued is taken with ``MSG_DONTWAIT``; otherwise
``recvfrom`` blocks in the kernel under a receive timeout (``SO_RCVTIMEO``,
changed only when the wait changes by a millisecond or more) and returns
the moment a frame arrives. The kernel counts that timeout in scheduler
ticks, so the last ``_TICK_MARGIN`` seconds of a wait are done with
``select``, which keeps to the timeout given. Sends never block
(``MSG_DONTWAIT``).

A deleted interface is reported as :class:`~pyethercat.errors.LinkError`
("has gone"), for good: the kernel signals the deletion at most once (as
``ENETDOWN``, and not at all when the interface was already down) and then
leaves the socket bound to nothing, so a ``recv`` that finds nothing checks,
at most once every ``_PRESENCE_PERIOD`` seconds, that the interface index it
bound to still exists.

Going down is not final: the socket works again once the interface is up.
A ``send`` while our interface is down raises
:class:`~pyethercat.errors.LinkDownError`; so does one the kernel refuses
for a full transmit queue (``ENOBUFS``) while the interface has no carrier
(a pulled cable: the queue fills because nothing drains it); with carrier a
full queue only loses the frame, as on a busy wire. A ``recv`` waiting when
the interface goes down gets the kernel's one-off ``ENETDOWN`` notice, also
as :class:`~pyethercat.errors.LinkDownError`; later calls wait as usual.
:meth:`RawLink.carrier` asks the kernel whether the interface is up with a
link partner (``SIOCGIFFLAGS``: ``IFF_UP`` and ``IFF_RUNNING``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import socket
import struct
import sys
import time

from pyethercat.errors import LinkDownError, LinkError, PermissionError
from pyethercat.link.base import MAX_FRAME, SocketLink
from pyethercat.wire.frame import ETHERTYPE_ETHERCAT

__all__ = ["RawLink"]

# Linux <linux/if_packet.h>
_SOL_PACKET = 263
_PACKET_ADD_MEMBERSHIP = 1
_PACKET_MR_PROMISC = 1
_PACKET_OUTGOING = 4
_PACKET_IGNORE_OUTGOING = 23
_TIMEVAL = struct.Struct("@ll")
# Longer than one kernel tick at HZ=100: SO_RCVTIMEO may run this much over.
_TICK_MARGIN = 0.011
# Blocking waits are cut into slices this long so that close() is noticed.
_MAX_BLOCK = 1.0
# How often an idle recv checks that the interface still exists (one ioctl).
_PRESENCE_PERIOD = 1.0
# Linux <linux/sockios.h>, <net/if.h>: interface flags of a struct ifreq.
_SIOCGIFFLAGS = 0x8913
_IFF_UP = 0x1
_IFF_RUNNING = 0x40
_IFREQ = struct.Struct("16sH14x")


def _permission_message(iface: str) -> str:
    exe = os.path.realpath(sys.executable)
    return (
        f"no permission to open a raw socket on {iface}: run as root or "
        f"`sudo setcap cap_net_raw+ep {exe}`"
    )


class RawLink(SocketLink):
    """EtherCAT frames on a network interface through an ``AF_PACKET`` raw socket."""

    #: The kernel marks our own transmissions (PACKET_OUTGOING); recv drops them.
    sees_own_frames = False

    def __init__(
        self,
        iface: str,
        promiscuous: bool = False,
        rcvbuf: int | None = 1 << 20,
    ) -> None:
        if not hasattr(socket, "AF_PACKET"):
            raise LinkError("raw Ethernet links need Linux (AF_PACKET)")
        self.iface = iface
        try:
            ifindex = socket.if_nametoindex(iface)
        except OSError:
            raise LinkError(f"no such network interface: {iface}") from None
        try:
            # Protocol 0: receives nothing until bound with the EtherCAT EtherType below.
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        except OSError as exc:
            if exc.errno in (errno.EPERM, errno.EACCES):
                raise PermissionError(_permission_message(iface)) from exc
            raise LinkError(f"cannot open a raw socket for {iface}: {exc}") from exc
        try:
            sock.bind((iface, ETHERTYPE_ETHERCAT))
            if rcvbuf:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            # Kernel 4.20+: our own frames are not even queued to us. Older kernels
            # refuse the option; the packet type check in recv does the job there.
            ignores_outgoing = False
            with contextlib.suppress(OSError):
                sock.setsockopt(_SOL_PACKET, _PACKET_IGNORE_OUTGOING, 1)
                ignores_outgoing = True
            if promiscuous:
                mreq = struct.pack("iHH8s", ifindex, _PACKET_MR_PROMISC, 0, b"")
                # Membership-based: the kernel drops promiscuous mode when the socket closes.
                sock.setsockopt(_SOL_PACKET, _PACKET_ADD_MEMBERSHIP, mreq)
        except OSError as exc:
            sock.close()
            if exc.errno == errno.ENODEV:
                raise LinkError(f"no such network interface: {iface}") from exc
            if exc.errno == errno.ENETDOWN:
                raise LinkError(f"network interface {iface} is down") from exc
            raise LinkError(f"cannot bind a raw socket to {iface}: {exc}") from exc
        super().__init__(iface, sock)
        self._ifindex = ifindex
        #: Set once the interface is found deleted: the error every later call raises.
        self._gone: str | None = None
        self._presence_checked = time.monotonic()
        #: SO_RCVTIMEO now set, in milliseconds (0: none set yet).
        self._rcvtimeo_ms = 0
        #: Frames of ours the kernel looped back and recv dropped.
        self.dropped_outgoing = 0
        #: Frames lost to a full transmit queue (ENOBUFS) while the carrier was there.
        self.dropped_nobufs = 0
        #: ENETDOWN notices the kernel gave recv (the interface went down).
        self.down_notices = 0
        # With PACKET_IGNORE_OUTGOING no frame of ours is queued: poll_into needs no
        # packet type (recv_into, no address tuple per frame).
        self._ignores_outgoing = ignores_outgoing
        # A receive that must not block asks first whether anything is there: a poll
        # costs a third of a recvfrom that raises BlockingIOError, and a loop waiting
        # for a reply asks many times (an error notice reads as ready: recvfrom sees it).
        self._ready = select.poll()
        self._ready.register(sock.fileno(), select.POLLIN)

    def __getstate__(self) -> dict[str, object]:
        # (the isolated engine takes the link over in a pickle, its socket by descriptor;
        # a poll object does not pickle: the new process registers its own)
        state = dict(self.__dict__)
        del state["_ready"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._ready = select.poll()
        self._ready.register(self._sock.fileno(), select.POLLIN)

    def _check_present(self, now: float | None = None) -> None:
        """Raise LinkError if the bound interface was deleted.

        With ``now``, only when the last check is ``_PRESENCE_PERIOD`` old; the
        verdict "gone" is kept, as an interface index never comes back.
        """
        if self._gone is None:
            if now is not None:
                if now - self._presence_checked < _PRESENCE_PERIOD:
                    return
                self._presence_checked = now
            try:
                socket.if_indextoname(self._ifindex)
            except OSError:
                # ENXIO: no interface has this index any more (deleted, or moved to
                # another network namespace); a new one of the same name would get
                # another index and never reach this socket.
                self._gone = f"network interface {self.iface} has gone"
            else:
                return
        raise LinkError(self._gone)

    def carrier(self) -> bool | None:
        """Whether the interface is up and has a link partner (False once it has gone)."""
        if self._closed or self._gone is not None:
            return False
        try:
            got = fcntl.ioctl(self._sock.fileno(), _SIOCGIFFLAGS,
                              _IFREQ.pack(self.iface.encode(), 0))
        except OSError:
            return False
        flags = _IFREQ.unpack(got)[1]
        return bool(flags & _IFF_UP) and bool(flags & _IFF_RUNNING)

    def send(self, frame: bytes) -> None:
        self._check_open()
        if self._gone is not None:
            self._check_present()
        for attempt in (1, 2):
            try:
                self._sock.send(frame, socket.MSG_DONTWAIT)
                return
            except BlockingIOError:
                return  # transmit queue full: the frame is lost, as on a busy wire
            except OSError as exc:
                if exc.errno == errno.ENOBUFS:
                    if self.carrier() is False:
                        self._check_present()
                        raise LinkDownError(f"no carrier on {self.iface}") from exc
                    self.dropped_nobufs += 1
                    return
                if exc.errno == errno.ENETDOWN:
                    self._check_present()
                    if attempt == 1 and self.carrier():
                        continue  # the notice of a spell that is over: send again
                    raise LinkDownError(f"network interface {self.iface} is down") from exc
                if exc.errno == errno.EMSGSIZE:
                    raise LinkError(
                        f"frame of {len(frame)} bytes is too large for {self.iface}"
                    ) from exc
                if exc.errno == errno.ENXIO or exc.errno == errno.ENODEV:
                    self._gone = f"network interface {self.iface} has gone"
                    raise LinkError(self._gone) from exc
                raise LinkError(f"send on {self.iface} failed: {exc}") from exc

    def recv(self, timeout: float | None = None) -> bytes | None:
        self._check_open()
        if self._gone is not None:
            self._check_present()
        return super().recv(timeout)

    def poll_into(self, buf: bytearray) -> int:
        if not self._ignores_outgoing or self._gone is not None or self._closed:
            return super().poll_into(buf)
        try:
            return self._sock.recv_into(buf, MAX_FRAME, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return 0
        except OSError as exc:
            self._receive_failed(exc)
            return 0

    def _receive_failed(self, exc: OSError) -> None:
        """Raise what a failed receive means; return for a notice that needs nothing."""
        if self._closed:
            self._check_open()
        if exc.errno in (errno.ENODEV, errno.ENXIO):
            self._gone = f"network interface {self.iface} has gone"
            raise LinkError(self._gone) from exc
        if exc.errno == errno.ENETDOWN:
            # A one-off notice that the interface went down (the kernel says the
            # same for a deleted one): the socket works again once it is up.
            self._check_present()
            self.down_notices += 1
            if not self.carrier():
                raise LinkDownError(f"network interface {self.iface} is down") from exc
            return  # the notice of a spell that is already over
        raise LinkError(f"receive on {self.iface} failed: {exc}") from exc

    def _nothing(self, left: float | None, flags: int) -> None:
        """Nothing came: the interface's presence now and then, the last slice of a wait."""
        if self._closed:
            self._check_open()
        now = time.monotonic()
        if now - self._presence_checked >= _PRESENCE_PERIOD:
            self._check_present(now)
        if flags and left is not None and left > 0:
            # The last slice: select keeps to the time given (SO_RCVTIMEO counts ticks).
            self._wait_readable(left)

    def _receive(self, left: float | None) -> bytes | None:
        sock = self._sock
        block = min(_MAX_BLOCK if left is None else left, _MAX_BLOCK) - _TICK_MARGIN
        if block >= 0.001:
            # The coarse part of the wait: block in recvfrom itself (a frame that
            # is already there is returned at once).
            ms = int(block * 1000)
            if ms != self._rcvtimeo_ms:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO,
                                _TIMEVAL.pack(ms // 1000, (ms % 1000) * 1000))
                self._rcvtimeo_ms = ms
            flags = 0
        else:
            flags = socket.MSG_DONTWAIT
        if flags and not self._ready.poll(0):
            self._nothing(left, flags)
            return None
        try:
            data, addr = sock.recvfrom(MAX_FRAME + 64, flags)
        except BlockingIOError:
            self._nothing(left, flags)
            return None
        except OSError as exc:
            self._receive_failed(exc)
            return None
        if addr[2] == _PACKET_OUTGOING:
            self.dropped_outgoing += 1
            return None
        return data
