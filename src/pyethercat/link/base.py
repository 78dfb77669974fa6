"""The link interface: something that sends and receives whole Ethernet frames.

Every link carries complete Ethernet frames (destination MAC, source MAC,
EtherType 0x88A4, EtherCAT header, datagrams, padding; no FCS), whatever the
medium underneath: a raw socket, a UDP socket, a socketpair or a queue. Links
never look inside a frame beyond what the medium needs.
"""

from __future__ import annotations

import abc
from types import TracebackType
from typing import Self

from pyethercat.errors import LinkClosedError

__all__ = ["Link", "MAX_FRAME", "MIN_FRAME"]

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
