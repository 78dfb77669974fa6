"""The link interface: something that sends and receives whole Ethernet frames.

Every link carries complete Ethernet frames (destination MAC, source MAC,
EtherType 0x88A4, EtherCAT header, datagrams, padding; no FCS), whatever the
medium underneath: a raw socket, a UDP socket, a socketpair or a queue. Links
never look inside a frame beyond what the medium needs.
"""

from __future__ import annotations

import abc
import contextlib
import select
import socket
import time
from types import TracebackType
from typing import Self

from pyethercat.errors import LinkClosedError

__all__ = ["Link", "MAX_FRAME", "MIN_FRAME", "SocketLink"]

#: Largest frame any link accepts or returns (Ethernet without FCS, plus a VLAN tag).
MAX_FRAME = 1518
#: Shortest frame any link sends: an Ethernet header. Shorter ones raise LinkError
#: (the kernel refuses them on raw sockets; an empty message on a socketpair would
#: read as the peer's close).
MIN_FRAME = 14


class Link(abc.ABC):
    """A bidirectional frame link.

    ``send`` never blocks for long (a full medium drops or raises, like
    Ethernet); ``recv(timeout)`` waits at most ``timeout`` seconds (``None``:
    forever, ``0``: poll) and returns one frame, or ``None`` when nothing
    arrived in time. After :meth:`close` both raise
    :class:`~pyethercat.errors.LinkClosedError`, and so does ``recv`` once the
    peer of a connected link (pair, socketpair) has gone and no frame is left.
    """

    #: Human-readable name (interface name, address, ...), used in messages.
    name: str = "link"
    #: Whether ``recv`` may return frames this link sent itself, unmarked. A link
    #: that knows the direction of every frame (an AF_PACKET socket drops what the
    #: kernel marks outgoing; a point-to-point socket or queue only carries the
    #: peer's frames) says False; the master then takes a frame that carries its
    #: own source MAC as a reply (some ESC emulators do not set the locally
    #: administered bit), instead of as its own frame seen again.
    sees_own_frames: bool = True

    def __init__(self, name: str) -> None:
        self.name = name
        self._closed = False

    @abc.abstractmethod
    def send(self, frame: bytes) -> None:
        """Send one Ethernet frame."""

    @abc.abstractmethod
    def recv(self, timeout: float | None = None) -> bytes | None:
        """Receive one Ethernet frame, or ``None`` after ``timeout`` seconds."""

    def fileno(self) -> int | None:
        """A file descriptor that polls readable when a frame may be ready, or ``None``."""
        return None

    def carrier(self) -> bool | None:
        """Whether the medium is connected: True or False where the OS tells (a network
        interface that is up with a link partner), None where the link cannot know."""
        return None

    def poll_into(self, buf: bytearray) -> int:
        """Take a frame that is already waiting into ``buf`` without waiting.

        Returns its length (0: none waiting). For loops that poll a link and
        keep one buffer (a simulator's serve loop): the socket links receive
        straight into ``buf``, with no allocation per frame. ``buf`` must hold
        :data:`MAX_FRAME` bytes.
        """
        frame = self.recv(0)
        if frame is None:
            return 0
        buf[:len(frame)] = frame
        return len(frame)

    def close(self) -> None:
        """Release the link; further use raises :class:`LinkClosedError`. Idempotent."""
        self._closed = True

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise LinkClosedError(f"link {self.name} is closed")

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = " closed" if self._closed else ""
        return f"<{type(self).__name__} {self.name}{state}>"


class SocketLink(Link):
    """A link over a socket: ``fileno``, ``close`` and the receive-deadline loop.

    ``recv(timeout)`` calls :meth:`_receive` with the time left until a
    frame comes or the time is up; a subclass receives one frame there, or
    waits (at most ``left`` seconds, ``None``: as long as it likes) and
    returns ``None`` to be asked again.
    """

    def __init__(self, name: str, sock: socket.socket) -> None:
        super().__init__(name)
        self._sock = sock

    def fileno(self) -> int | None:
        return None if self._closed else self._sock.fileno()

    def recv(self, timeout: float | None = None) -> bytes | None:
        self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        left = timeout
        while True:
            frame = self._receive(left)
            if frame is not None:
                return frame
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None

    @abc.abstractmethod
    def _receive(self, left: float | None) -> bytes | None:
        """One frame, or None after waiting up to ``left`` seconds (or none at all)."""

    def _wait_readable(self, left: float | None) -> None:
        """Wait until the socket is readable or ``left`` seconds passed."""
        with contextlib.suppress(InterruptedError, ValueError):
            select.select([self._sock], [], [], left)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sock.close()
