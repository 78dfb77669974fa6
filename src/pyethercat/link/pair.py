"""In-process link pair: two ends joined by queues (no sockets, no threads).

``PairLink.pair()`` gives two ends; a frame sent on one end is received on the
other, in order. It is thread-safe (one lock and condition per end), so a
simulator may serve one end from a thread, but it is also usable fully
synchronously: give the far end a *responder* and every frame sent to it is
handed to the responder inside ``send``; the frames the responder returns are
queued for the sender at once. A master test then needs no thread and no
timing at all::

    master_end = PairLink.responder_link(segment.process)   # process(frame) -> reply
    master_end.send(frame)
    reply = master_end.recv(0)

Frames are stored as ``bytes`` copies, so a caller may reuse its buffer.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Self

from pyethercat.errors import LinkClosedError, LinkError
from pyethercat.link.base import MIN_FRAME, Link

__all__ = ["PairLink", "Responder"]

#: Called with a frame sent to its end; returns nothing, one reply frame, or several.
Responder = Callable[[bytes], "bytes | bytearray | Iterable[bytes | bytearray] | None"]
_BYTES = (bytes, bytearray)


class PairLink(Link):
    """One end of an in-process link pair (create with :meth:`pair`)."""

    #: An end receives only what its peer sent.
    sees_own_frames = False

    def __init__(self, name: str, max_queue: int = 4096) -> None:
        super().__init__(name)
        self._queue: deque[bytes] = deque()
        # (entered through its lock: ``Condition.__enter__`` is two calls more per use)
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        #: Threads blocked in ``recv`` (nobody to wake: skip the notify).
        self._waiting = 0
        self._peer: PairLink | None = None
        self._peer_closed = False
        self._responder: Responder | None = None
        self.max_queue = max_queue
        #: Frames dropped because the receiving queue was full (Ethernet drops too).
        self.dropped = 0

    @classmethod
    def pair(cls, name_a: str = "pair-a", name_b: str = "pair-b") -> tuple[Self, Self]:
        """Two joined ends."""
        a, b = cls(name_a), cls(name_b)
        a._peer, b._peer = b, a
        return a, b

    @classmethod
    def responder_link(cls, responder: Responder, name: str = "pair") -> PairLink:
        """One end whose peer answers every sent frame synchronously with ``responder``."""
        a, b = cls.pair(name, name + "-peer")
        b.set_responder(responder)
        return a

    @property
    def peer(self) -> PairLink | None:
        """The other end."""
        return self._peer

    def set_responder(self, responder: Responder | None) -> None:
        """Answer frames arriving at this end synchronously (``None``: queue them again)."""
        self._responder = responder

    def _deliver(self, frame: bytes) -> None:
        with self._lock:
            if self._closed:
                return  # like a cable to a switched-off device
            if len(self._queue) >= self.max_queue:
                self.dropped += 1
                return
            self._queue.append(frame)
            if self._waiting:
                self._cond.notify()

    def send(self, frame: bytes) -> None:
        if self._closed:
            self._check_open()
        peer = self._peer
        if peer is None:
            raise LinkClosedError(f"link {self.name} has no peer")
        if self._peer_closed:
            raise LinkClosedError(f"peer of link {self.name} has closed")
        if len(frame) < MIN_FRAME:
            raise LinkError(f"link {self.name}: frame of {len(frame)} bytes is shorter than "
                            f"an Ethernet header")
        data = bytes(frame)
        responder = peer._responder
        if responder is None:
            peer._deliver(data)
            return
        # Called without holding any lock, so the responder may itself use the link.
        replies = responder(data)
        if replies is None:
            return
        if isinstance(replies, _BYTES):
            self._deliver(bytes(replies))
        else:
            for reply in replies:
                self._deliver(bytes(reply))

    def recv(self, timeout: float | None = None) -> bytes | None:
        with self._lock:
            if self._closed:
                self._check_open()
            if self._queue:
                return self._queue.popleft()
            deadline = None if timeout is None else time.monotonic() + timeout
            while not self._queue:
                if self._closed:
                    raise LinkClosedError(f"link {self.name} is closed")
                if self._peer_closed:
                    raise LinkClosedError(f"peer of link {self.name} has closed")
                self._waiting += 1
                try:
                    if deadline is None:
                        self._cond.wait()
                    else:
                        left = deadline - time.monotonic()
                        if left <= 0:
                            return None
                        self._cond.wait(left)
                finally:
                    self._waiting -= 1
            return self._queue.popleft()

    def pending(self) -> int:
        """Number of frames waiting to be received."""
        with self._cond:
            return len(self._queue)

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._queue.clear()
            self._cond.notify_all()
        peer = self._peer
        if peer is not None:
            with peer._cond:
                peer._peer_closed = True
                peer._cond.notify_all()
