"""Acyclic requests of the user's process, carried by the engine.

While the isolated engine runs, the user's master keeps its scheduler and
every service on it (SDO, FoE, EoE, register access, state changes,
recovery); only its link changes: frames go to the engine over a Unix
socketpair (:class:`EngineLink`). The engine takes the datagrams out of each
frame and queues them on its own scheduler: they ride in the spare room of
the next cyclic frame, or go at once in a frame of their own when the next
deadline is far enough away (those the cyclic frames have no room for go
right behind them). When every datagram of the frame is answered,
the engine sends the user's frame back as the slaves returned it (the
user's frame index, each datagram's data, address and working counter); a
frame whose datagrams are lost is not answered, and the user's scheduler
retries it as it would on the wire. The engine never waits for the user's
process: a reply it cannot hand over at once (the user's process is stopped
and the socket is full) is dropped and counted.
"""

from __future__ import annotations

import select
import socket
from collections import deque

from pyethercat.errors import EngineDiedError, EtherCATError, FrameError, LinkClosedError
from pyethercat.link.base import MAX_FRAME
from pyethercat.link.unix import UnixLink
from pyethercat.master.scheduler import Request, Scheduler
from pyethercat.wire.datagram import Datagram
from pyethercat.wire.frame import LOCALLY_ADMINISTERED_BIT, FrameType, decode_frame, encode_frame

__all__ = ["EngineLink", "Router"]


class _Carried:
    __slots__ = ("frame", "requests", "src")

    def __init__(self, frame: list[Datagram], requests: list[Request], src: bytes) -> None:
        self.frame = frame
        self.requests = requests
        self.src = src


class Router:
    """The engine's side (see the module text); ``sock`` is its end of the socketpair."""

    def __init__(self, sock: socket.socket, scheduler: Scheduler) -> None:
        self.sock = sock
        sock.setblocking(False)
        self.scheduler = scheduler
        # Whether a frame waits, asked every cycle: a poll costs a third of a receive
        # that finds nothing (measured on a KVM guest: 8 us a cycle, at 10 kHz).
        self._poller = select.poll()
        self._poller.register(sock.fileno(), select.POLLIN)
        self._pending: deque[_Carried] = deque()
        self._buf = bytearray(MAX_FRAME + 64)
        #: Frames and datagrams carried, replies dropped (the user did not take them).
        self.frames = 0
        self.datagrams = 0
        self.dropped = 0
        #: False once the user's end is closed.
        self.open = True

    def take(self, flush: bool) -> int:
        """Queue the datagrams of every frame waiting from the user; how many frames.

        ``flush``: send them now in frames of their own (there is time before
        the next deadline); otherwise they wait for the next cyclic frame.
        """
        taken = 0
        if not self._poller.poll(0):
            return taken  # (nothing waits; a closed end reads as ready: end of file)
        sock, buf = self.sock, self._buf
        while self.open:
            try:
                n = sock.recv_into(buf, len(buf), socket.MSG_DONTWAIT)
            except BlockingIOError:
                break
            except OSError:
                n = 0
            if n == 0:
                self.open = False
                break
            try:
                decoded = decode_frame(memoryview(buf)[:n], strict=False)
            except EtherCATError:
                continue  # not ours to judge: the user's scheduler times it out
            if decoded.frame_type != FrameType.DATAGRAMS or not decoded.datagrams:
                continue
            dgs = decoded.datagrams
            try:
                reqs = self.scheduler.submit(dgs, retries=0, flush=flush)
            except EtherCATError:
                continue
            self._pending.append(_Carried(dgs, reqs, decoded.src))
            taken += 1
            self.frames += 1
            self.datagrams += len(dgs)
        return taken

    @property
    def carrying(self) -> bool:
        """Whether frames of the user's wait for their replies."""
        return bool(self._pending)

    def answered(self) -> bool:
        """Whether every carried request has its reply (or failed)."""
        return all(r.done() for c in self._pending for r in c.requests)

    def answer(self) -> None:
        """Send back every frame whose datagrams are all answered (in order of arrival)."""
        pending = self._pending
        while pending:
            c = pending[0]
            if not all(r.done() for r in c.requests):
                return
            pending.popleft()
            if any(r.error is not None or r.reply is None for r in c.requests):
                continue  # lost: the user's scheduler sends it again
            replies: list[Datagram] = []
            for sent, r in zip(c.frame, c.requests, strict=True):
                got = r.reply
                assert got is not None
                replies.append(Datagram(sent.command, sent.index, got.address, got.data,
                                        got.irq, got.wkc, got.circulating))
            src = bytes([c.src[0] | LOCALLY_ADMINISTERED_BIT]) + c.src[1:]
            try:
                raw = encode_frame(replies, src=src)
            except FrameError:
                continue
            if not self.open:
                continue
            try:
                self.sock.send(raw, socket.MSG_DONTWAIT)
            except BlockingIOError:
                self.dropped += 1
            except OSError:
                self.open = False


class EngineLink(UnixLink):
    """The user's end: a Unix socketpair link whose peer is the engine.

    Once the engine has gone, sending and receiving raise
    :class:`~pyethercat.errors.EngineDiedError` (``why`` says how it ended).
    """

    def __init__(self, sock: socket.socket, name: str = "engine") -> None:
        super().__init__(sock, name)
        self.why: str | None = None

    def send(self, frame: bytes) -> None:
        if self.why is not None:
            raise EngineDiedError(self.why)
        try:
            super().send(frame)
        except LinkClosedError as exc:
            raise EngineDiedError(self.why or f"the cyclic engine has gone ({exc})") from None

    def recv(self, timeout: float | None = None) -> bytes | None:
        if self.why is not None:
            raise EngineDiedError(self.why)
        try:
            return super().recv(timeout)
        except LinkClosedError as exc:
            raise EngineDiedError(self.why or f"the cyclic engine has gone ({exc})") from None
