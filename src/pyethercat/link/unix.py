"""Link over a Unix-domain socketpair (``SOCK_SEQPACKET``: one frame per message).

Made for a simulator running in a child process: create the pair, hand one
file descriptor to the child (``fork`` keeps it; with ``subprocess`` pass it in
``pass_fds`` and rebuild the end there with :meth:`UnixLink.from_fd`).
``SOCK_SEQPACKET`` keeps frame boundaries and reports the peer's close, so
``recv`` raises :class:`~pyethercat.errors.LinkClosedError` when the other
process has gone. :meth:`UnixLink.connect` reaches a segment that listens on
a ``SOCK_SEQPACKET`` socket path instead (``open_link("unix:PATH")``).
"""

from __future__ import annotations

import os
import socket

from pyethercat.errors import LinkClosedError, LinkError
from pyethercat.link.base import MAX_FRAME, MIN_FRAME, SocketLink

__all__ = ["UnixLink"]


class UnixLink(SocketLink):
    """One end of a Unix-domain socketpair (or connection) carrying Ethernet frames."""

    #: The socket carries the peer's frames only.
    sees_own_frames = False

    def __init__(self, sock: socket.socket, name: str = "unix") -> None:
        if sock.family != socket.AF_UNIX:
            raise LinkError(f"link {name}: socket is not AF_UNIX")
        super().__init__(name, sock)
        # Sends block (a socketpair should not lose frames); receives are polled.
        sock.setblocking(True)

    @classmethod
    def pair(
        cls, name_a: str = "unix-a", name_b: str = "unix-b", inheritable: bool = False
    ) -> tuple[UnixLink, UnixLink]:
        """Two connected ends. ``inheritable=True`` lets the fds survive ``exec``."""
        a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        if inheritable:
            a.set_inheritable(True)
            b.set_inheritable(True)
        return cls(a, name_a), cls(b, name_b)

    @classmethod
    def connect(cls, path: str | os.PathLike[str], name: str | None = None) -> UnixLink:
        """Connect to a ``SOCK_SEQPACKET`` Unix socket listening at ``path``."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.connect(os.fspath(path))
        except OSError as exc:
            sock.close()
            raise LinkError(f"cannot connect to the Unix socket {os.fspath(path)}: "
                            f"{exc.strerror or exc}") from None
        return cls(sock, name or f"unix:{os.fspath(path)}")

    @classmethod
    def from_fd(cls, fd: int, name: str = "unix") -> UnixLink:
        """Wrap an inherited socket file descriptor (takes ownership of ``fd``)."""
        try:
            sock = socket.socket(fileno=fd)
        except OSError as exc:
            raise LinkError(f"link {name}: fd {fd} is not a usable socket: {exc}") from exc
        return cls(sock, name)

    def send(self, frame: bytes) -> None:
        self._check_open()
        if len(frame) < MIN_FRAME:
            # An empty SOCK_SEQPACKET message would also look like the peer's close.
            raise LinkError(f"link {self.name}: frame of {len(frame)} bytes is shorter than "
                            f"an Ethernet header")
        try:
            self._sock.send(frame)
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise LinkClosedError(f"peer of link {self.name} has closed") from exc
        except OSError as exc:
            raise LinkError(f"link {self.name}: send failed: {exc}") from exc

    def _receive(self, left: float | None) -> bytes | None:
        try:
            data = self._sock.recv(MAX_FRAME + 64, socket.MSG_DONTWAIT)
        except BlockingIOError:
            self._wait_readable(left)
            return None
        except ConnectionResetError as exc:
            raise LinkClosedError(f"peer of link {self.name} has closed") from exc
        except OSError as exc:
            raise LinkError(f"link {self.name}: receive failed: {exc}") from exc
        if not data:
            raise LinkClosedError(f"peer of link {self.name} has closed")
        return data

    def poll_into(self, buf: bytearray) -> int:
        if self._closed:
            self._check_open()
        try:
            n = self._sock.recv_into(buf, MAX_FRAME, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return 0
        except OSError:
            return super().poll_into(buf)  # says what happened
        if not n:
            raise LinkClosedError(f"peer of link {self.name} has closed")
        return n

    def detach(self) -> int:
        """Give up the file descriptor (e.g. to pass it to a child); the link is closed."""
        self._closed = True
        return self._sock.detach()
