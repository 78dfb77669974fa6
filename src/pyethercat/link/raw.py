"""Raw Ethernet link: an ``AF_PACKET`` socket bound to one interface (Linux).

Only frames with EtherType 0x88A4 reach the socket: the protocol is set at
``bind`` time on the interface, so nothing from other interfaces slips in
between creating and binding the socket. Frames the kernel loops back to us
(our own transmissions, packet type ``PACKET_OUTGOING``) are dropped, so
``recv`` returns only frames that came in from the wire.

Opening the socket needs ``CAP_NET_RAW``; without it
:class:`pyethercat.errors.PermissionError` says how to get it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import socket
import struct
import sys
import time

from pyethercat.errors import LinkError, PermissionError
from pyethercat.link.base import MAX_FRAME, Link
from pyethercat.wire.frame import ETHERTYPE_ETHERCAT

__all__ = ["RawLink"]

# Linux <linux/if_packet.h>
_SOL_PACKET = 263
_PACKET_ADD_MEMBERSHIP = 1
_PACKET_MR_PROMISC = 1
_PACKET_OUTGOING = 4
_PACKET_IGNORE_OUTGOING = 23


def _permission_message(iface: str) -> str:
    exe = os.path.realpath(sys.executable)
    return (
        f"no permission to open a raw socket on {iface}: run as root or "
        f"`sudo setcap cap_net_raw+ep {exe}`"
    )


class RawLink(Link):
    """EtherCAT frames on a network interface through an ``AF_PACKET`` raw socket."""

    def __init__(
        self,
        iface: str,
        promiscuous: bool = False,
        rcvbuf: int | None = 1 << 20,
    ) -> None:
        super().__init__(iface)
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
            with contextlib.suppress(OSError):
                sock.setsockopt(_SOL_PACKET, _PACKET_IGNORE_OUTGOING, 1)
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
        sock.setblocking(False)
        self._sock = sock
        #: Frames of ours the kernel looped back and recv dropped.
        self.dropped_outgoing = 0

    def fileno(self) -> int | None:
        return None if self._closed else self._sock.fileno()

    def send(self, frame: bytes) -> None:
        self._check_open()
        try:
            self._sock.send(frame)
        except BlockingIOError:
            pass  # transmit queue full: the frame is lost, as on a busy wire
        except OSError as exc:
            if exc.errno == errno.ENETDOWN:
                raise LinkError(f"network interface {self.iface} is down") from exc
            if exc.errno == errno.EMSGSIZE:
                raise LinkError(
                    f"frame of {len(frame)} bytes is too large for {self.iface}"
                ) from exc
            if exc.errno == errno.ENXIO or exc.errno == errno.ENODEV:
                raise LinkError(f"network interface {self.iface} has gone") from exc
            raise LinkError(f"send on {self.iface} failed: {exc}") from exc

    def recv(self, timeout: float | None = None) -> bytes | None:
        self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                data, addr = self._sock.recvfrom(MAX_FRAME + 64)
            except BlockingIOError:
                pass
            except OSError as exc:
                if exc.errno == errno.ENETDOWN:
                    raise LinkError(f"network interface {self.iface} is down") from exc
                raise LinkError(f"receive on {self.iface} failed: {exc}") from exc
            else:
                if addr[2] == _PACKET_OUTGOING:
                    self.dropped_outgoing += 1
                    continue
                return data
            if deadline is None:
                select.select([self._sock], [], [])
            else:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                select.select([self._sock], [], [], left)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sock.close()
