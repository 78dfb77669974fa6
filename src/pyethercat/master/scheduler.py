"""The scheduler: one object owns the link and drives the PDU core for every thread.

The frame logic (packing, indices, the in-flight table, reply matching,
retries) is :class:`~pyethercat.master.pdu.PduCore`, which does no I/O. The
scheduler adds what the core leaves out: a lock, the link, a clock, and the
receive loop.

Callers queue datagrams (``submit`` gives small futures, ``transact`` a whole
batch at once); whichever caller waits for a result receives frames for
everybody (leader/follower): one thread blocks in ``link.recv`` with the
lock released, the others sleep on a condition it notifies on every change.
There is no I/O thread.

The cyclic path sends its own frame (``send_prepared`` of a
:class:`~pyethercat.master.pdu.CyclicTemplate`, or the one-off
``send_cyclic``), lets queued acyclic datagrams ride in its spare room and
is never retried: the next cycle is the retry. ``acyclic_hold`` makes
acyclic requests wait that long for a cyclic frame before they get frames of
their own.

A ring (a link with two ports, ``link.redundant.RedundantLink``): the core
chooses the ports of every frame (:meth:`PduCore.route`), the scheduler
sends on them, hands each received frame to the core with the port it came
in on and sends what the core passes on (``take_forwards``); the core
merges the copies (``master.redundancy``).

Work that must go in step with the cyclic loop (recovering a hot-swapped
slave) runs as a worker of :attr:`Scheduler.stepper`
(``master.stepping``): its requests ride in cyclic frames and the loop
resumes it after each cycle.

Time comes from a :mod:`pyethercat.clock` clock. With a
:class:`~pyethercat.clock.VirtualClock` the scheduler runs in virtual time,
for links that answer inside ``send`` (the in-process pair link with a
simulator as responder): a receive never blocks, a frame whose reply is not
already queued is lost once the virtual clock has been moved to its deadline,
every frame sent takes its wire time, and :meth:`sleep` moves the clock
instead of sleeping. Tests and the command line's ``--sim`` then run without
timing and without threads, and timeouts still mean what they say.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

from pyethercat.clock import Clock, VirtualClock, WallClock, is_virtual
from pyethercat.errors import EtherCATError
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.link.base import Link
from pyethercat.link.redundant import RedundantLink
from pyethercat.master.pdu import (
    DEFAULT_MAX_IN_FLIGHT,
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT,
    CyclicFrame,
    CyclicTemplate,
    PduCore,
    PduStats,
    Request,
    describe_datagram,
)
from pyethercat.master.redundancy import Redundancy, mark_for_port
from pyethercat.master.stepping import Stepper
from pyethercat.wire.datagram import MAX_PAYLOAD, Datagram
from pyethercat.wire.frame import (
    LOCALLY_ADMINISTERED_BIT,
    MASTER_MAC,
    MIN_FRAME_SIZE,
    WIRE_EXTRA_BYTES,
    WIRE_NS_PER_BYTE,
)

if TYPE_CHECKING:
    from pyethercat.realtime import SpinBudget

__all__ = [
    "DEFAULT_MAX_IN_FLIGHT",
    "DEFAULT_REPLY_SPIN",
    "DEFAULT_RETRIES",
    "DEFAULT_TIMEOUT",
    "CyclicFrame",
    "CyclicTemplate",
    "PduStats",
    "Request",
    "Scheduler",
    "describe_datagram",
]

#: Default ``Scheduler.reply_spin``: poll up to 0.5 ms for a cyclic reply before blocking.
DEFAULT_REPLY_SPIN = 0.0005
# At most this many frames are taken at once before deadlines are judged.
_DRAIN_MAX = 64


class Scheduler:
    """Owns a link and a :class:`PduCore`; thread-safe: any thread may submit and wait.

    ``timeout`` is the time one frame has to come back, ``retries`` how
    often a lost datagram is sent again, ``max_in_flight`` how many frames
    may be on the wire at once, ``src`` the source MAC of our frames.
    ``clock`` is the time base (default: real time); a
    :class:`~pyethercat.clock.VirtualClock` selects virtual time (see the
    module text).
    """

    def __init__(self, link: Link, *, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = DEFAULT_RETRIES, max_in_flight: int = DEFAULT_MAX_IN_FLIGHT,
                 src: bytes = MASTER_MAC, capacity: int = MAX_PAYLOAD,
                 clock: Clock | None = None) -> None:
        # Own-frame detection by source MAC only where the link cannot tell received
        # frames from the ones it sent (see Link.sees_own_frames).
        self.core = PduCore(timeout=timeout, retries=retries, max_in_flight=max_in_flight,
                            src=src, capacity=capacity, name=link.name,
                            drop_own_frames=link.sees_own_frames)
        self.link = link
        self.clock: Clock = clock if clock is not None else WallClock()
        #: True in virtual time (see the module text).
        self.virtual = is_virtual(self.clock)
        vclock = self.clock
        if isinstance(vclock, VirtualClock):
            self._vclock: VirtualClock | None = vclock
            # (its ``ns`` attribute, not ``now_ns()``: one call less on the hot path)
            self.now: Callable[[], float] = lambda: vclock.ns * 1e-9
        else:
            self._vclock = None
            # WallClock counts time.monotonic's nanoseconds: read it directly (hot path).
            if isinstance(self.clock, WallClock):
                self.now = time.monotonic
            else:
                wall = self.clock
                self.now = lambda: wall.now_ns() * 1e-9
        #: Seconds the cyclic thread polls the link for a prepared frame's reply
        #: before it blocks (0: block at once). Waking from a blocking receive
        #: costs tens of microseconds on a busy or virtual machine, and the CPU
        #: comes back with cold caches; SOEM polls the same way. Only
        #: ``wait_raw`` (the cyclic path) polls; with one CPU it never does,
        #: as the spinning would keep the CPU from whoever has to answer.
        self.reply_spin = DEFAULT_REPLY_SPIN if (os.cpu_count() or 1) > 1 else 0.0
        #: The share of each second that polling may take (None: no limit); past it
        #: the cyclic thread blocks for its reply (see :class:`~pyethercat.realtime.SpinBudget`).
        self.spin_budget: SpinBudget | None = None
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._receiving = False
        #: Threads blocked in the condition's wait (nobody to wake: skip the notify).
        self._sleepers = 0
        #: Workers run in step with the cyclic loop (see ``master.stepping``).
        self.stepper = Stepper(self.now)
        #: The link's ports when it is a ring's (RedundantLink), else None.
        self._ring = link if isinstance(link, RedundantLink) else None
        if self._ring is not None:
            self.core.redundancy = Redundancy(2)

    # -- the core's settings and counters -------------------------------------------

    @property
    def stats(self) -> PduStats:
        """Counters of the PDU core."""
        return self.core.stats

    @property
    def timeout(self) -> float:
        return self.core.timeout

    @property
    def retries(self) -> int:
        return self.core.retries

    @property
    def max_in_flight(self) -> int:
        return self.core.max_in_flight

    @property
    def src(self) -> bytes:
        return self.core.src

    @property
    def capacity(self) -> int:
        return self.core.capacity

    @property
    def acyclic_hold(self) -> float:
        """Seconds an acyclic request waits for a cyclic frame to carry it (0: never)."""
        return self.core.acyclic_hold

    @acyclic_hold.setter
    def acyclic_hold(self, seconds: float) -> None:
        self.core.acyclic_hold = seconds

    @property
    def in_flight(self) -> int:
        """Frames on the wire now."""
        with self._lock:
            return self.core.in_flight

    @property
    def queued(self) -> int:
        """Datagrams waiting to be sent."""
        with self._lock:
            return self.core.queued

    # -- time -------------------------------------------------------------------------

    def sleep(self, seconds: float) -> None:
        """Pause ``seconds`` in the scheduler's time (virtual time just moves on)."""
        if seconds <= 0:
            return
        if self.stepper.is_worker():
            self.stepper.wait(lambda: False, self.now() + seconds)
            return
        vclock = self._vclock
        if vclock is not None:
            vclock.advance(int(seconds * 1e9))
            # Let other threads run (a cyclic runner on real time beside a virtual
            # master): a poll loop in virtual time would otherwise keep the CPU.
            time.sleep(0)
        else:
            time.sleep(seconds)

    # -- submitting ----------------------------------------------------------------

    def submit(self, datagrams: Iterable[Datagram], *, retries: int | None = None,
               flush: bool = True) -> list[Request]:
        """Queue datagrams (sent in this order); returns one request per datagram.

        The datagrams' ``index`` fields are ignored (the core assigns frame
        indices). ``flush=False`` only queues: the next flush, wait or cyclic
        frame sends them, so several callers' datagrams share frames.
        """
        if flush and self.stepper.is_worker():
            flush = False  # a stepped worker's requests ride in the loop's frames
        with self._lock:
            now = self.now()
            reqs = self.core.submit(datagrams, now, retries=retries, waiter=self)
            if flush:
                self._send_queued_locked(now)
        return reqs

    def submit_one(self, datagram: Datagram, *, retries: int | None = None) -> Request:
        """Queue one datagram and send it."""
        return self.submit([datagram], retries=retries)[0]

    def flush(self) -> None:
        """Send queued datagrams now (as far as the in-flight budget allows)."""
        with self._lock:
            self.core.check_open()
            self._send_queued_locked(self.now(), force=True)

    def transact(self, datagrams: Sequence[Datagram], *, retries: int | None = None,
                 timeout: float | None = None) -> list[Datagram]:
        """Send a batch and return the replies in order; raises the first failure.

        All datagrams of the batch are queued before anything is sent, so
        they share as few frames as possible.
        """
        if not datagrams:
            return []
        reqs = self.submit(datagrams, retries=retries)
        self.wait(reqs, timeout)
        for r in reqs:
            if r.error is not None:
                raise r.error
        return [r.reply for r in reqs if r.reply is not None]

    def transact_one(self, datagram: Datagram, *, retries: int | None = None) -> Datagram:
        """Send one datagram and return its reply."""
        return self.transact([datagram], retries=retries)[0]

    def wait(self, requests: Sequence[Request], timeout: float | None = None) -> None:
        """Wait until every request is done (replied or failed); errors stay in them.

        ``timeout`` bounds the whole wait (the requests' own retries and
        timeouts end every wait anyway); when it runs out, the requests not
        yet done fail with :class:`TimeoutError`.
        """
        if not self.wait_until(lambda: all(r.done() for r in requests), timeout):
            with self._lock:
                for r in requests:
                    if not r.done():
                        r.error = EcTimeoutError(
                            f"no reply to {describe_datagram(r.datagram)} within {timeout} s")
                        self.core.forget(r)

    # -- the cyclic hook -----------------------------------------------------------

    def send_cyclic(self, datagrams: Sequence[Datagram], *, carry_acyclic: bool = True,
                    timeout: float | None = None) -> CyclicFrame:
        """Send ``datagrams`` as one frame now; queued acyclic datagrams fill the spare room.

        Raises :class:`FrameTooLargeError` if the cyclic datagrams alone do
        not fit one frame. The frame is never retried; ``timeout`` (default:
        the scheduler's) is how long it may take to come back.
        """
        return self.send_prepared(self.prepare_cyclic(datagrams), carry_acyclic=carry_acyclic,
                                  timeout=timeout)

    def exchange_cyclic(self, datagrams: Sequence[Datagram], *, carry_acyclic: bool = True,
                        timeout: float | None = None) -> list[Datagram] | None:
        """``send_cyclic`` and wait: the replies, or ``None`` when the frame was lost."""
        return self.send_cyclic(datagrams, carry_acyclic=carry_acyclic, timeout=timeout).wait()

    def prepare_cyclic(self, datagrams: Sequence[Datagram]) -> CyclicTemplate:
        """Encode a cyclic frame once, for :meth:`send_prepared` (see :class:`CyclicTemplate`)."""
        return self.core.prepare_cyclic(datagrams)

    def send_prepared(self, template: CyclicTemplate, *, carry_acyclic: bool = True,
                      timeout: float | None = None) -> CyclicFrame:
        """Send a prepared frame now (its data as the owner wrote it); like ``send_cyclic``.

        Queued acyclic datagrams ride behind the template's datagrams when
        they fit. ``wait_raw()`` on the ticket gives the reply frame.
        """
        with self._lock:
            ticket, idx, raw = self.core.send_prepared(
                template, self.now(), carry_acyclic=carry_acyclic, timeout=timeout, waiter=self)
            self._transmit_locked(idx, raw)
        return ticket

    def exchange_prepared(self, template: CyclicTemplate, *, carry_acyclic: bool = True,
                          timeout: float | None = None) -> bytes | None:
        """``send_prepared`` and wait: the reply frame, or ``None`` when the frame was lost."""
        return self.send_prepared(template, carry_acyclic=carry_acyclic,
                                  timeout=timeout).wait_raw()

    # -- the link -----------------------------------------------------------------------

    def replace_link(self, link: Link, *, wait: bool = True) -> Link:
        """Carry on over ``link``; returns the link used so far.

        The isolated cyclic engine takes the master's link into its own
        process and gives the master a link to itself. With ``wait``, frames
        still in flight are answered (or time out) first, so that no thread
        is receiving on the old link when it changes hands.
        """
        if wait:
            limit = self.core.timeout * (self.core.retries + 2)
            self.wait_until(lambda: not self.core.in_flight and not self._receiving, limit)
        with self._lock:
            old = self.link
            self.link = link
            self._ring = link if isinstance(link, RedundantLink) else None
            self.core.drop_own_frames = link.sees_own_frames and not (
                self.core.src[0] & LOCALLY_ADMINISTERED_BIT)
            self._notify()
        return old

    # -- closing --------------------------------------------------------------------

    def close(self) -> None:
        """Fail everything pending; further use raises :class:`LinkError`. Idempotent."""
        with self._lock:
            self.core.close()
            self._notify()

    # -- sending (hold self._lock) ----------------------------------------------------

    def _send_queued_locked(self, now: float, force: bool = False) -> None:
        """Send what the core packs now, frame by frame."""
        core = self.core
        while (frame := core.next_frame(now, force=force)) is not None:
            self._transmit_locked(*frame)

    def _transmit_locked(self, idx: int, raw: bytes) -> None:
        """Put a frame the core registered on the link; a refusal fails it."""
        vclock = self._vclock
        before = vclock.ns if vclock is not None else 0
        try:
            if self._ring is None:
                self.link.send(raw)
            else:
                self._transmit_ring_locked(idx, raw)
        except EtherCATError as exc:
            self.core.send_failed(idx, exc)
            self._notify()
            raise
        if vclock is not None and vclock.ns == before:
            # The frame takes its wire time (unless the responder moved the clock).
            vclock.advance((max(len(raw), MIN_FRAME_SIZE) + WIRE_EXTRA_BYTES) * WIRE_NS_PER_BYTE)

    def _transmit_ring_locked(self, idx: int, raw: bytes) -> None:
        """Send on the ports the core chooses; raises only when none took the frame."""
        ring = self._ring
        assert ring is not None
        core = self.core
        red = core.redundancy
        assert red is not None
        for p in (0, 1):
            red.carrier[p] = ring.port_carrier(p)
        error: EtherCATError | None = None
        sent = False
        for port in core.route(idx, raw):
            try:
                ring.send_on(port, mark_for_port(raw, port))
                sent = True
            except EtherCATError as exc:
                core.port_refused(idx, port)
                error = exc
        if not sent and error is not None:
            raise error

    def _forward_locked(self) -> None:
        """Send on what the core passes on (ring frames back on their own port)."""
        ring = self._ring
        red = self.core.redundancy
        if ring is None or red is None:
            return
        for port, frame in self.core.take_forwards():
            try:
                ring.send_on(port, frame)
            except EtherCATError:
                red.carrier[port] = False  # the frame's deadline settles it

    def _recv_locked(self, wait: float) -> tuple[bytes, int] | None:
        """One frame and its port (0 on a one-port link), lock released by the caller."""
        ring = self._ring
        if ring is not None:
            return ring.recv_from(wait)
        raw = self.link.recv(wait)
        return None if raw is None else (raw, 0)

    def _notify(self) -> None:
        """Wake the threads waiting for another receiver (lock held)."""
        if self._sleepers:
            self._cond.notify_all()

    # -- the receive loop ---------------------------------------------------------------

    def wait_until(self, done: Callable[[], bool], timeout: float | None) -> bool:
        """Drive or await the receive loop until ``done()``; False on ``timeout``."""
        now_fn = self.now
        limit = None if timeout is None else now_fn() + timeout
        if self.stepper.is_worker():
            return self.stepper.wait(done, limit)
        core = self.core
        with self._lock:
            while not done():
                now = now_fn()
                if limit is not None and now >= limit:
                    return False
                if core.closed:
                    return done()
                if core.queued:
                    self._send_queued_locked(now)
                if self._receiving:
                    # Another thread receives for us; it notifies on every change.
                    wait = 0.05 if limit is None else min(0.05, max(0.0, limit - now))
                    self._sleepers += 1
                    try:
                        self._cond.wait(wait)
                    finally:
                        self._sleepers -= 1
                    continue
                if not core.in_flight and not core.queued:
                    # Nothing can finish what we wait for.
                    return done()
                self._receive_once_locked(now, limit)
        return True

    def wait_ticket(self, ticket: CyclicFrame, timeout: float | None) -> None:
        """``wait_until(ticket.done)`` without the calls: the cyclic thread's wait."""
        now_fn = self.now
        vclock = self._vclock
        virtual = vclock is not None
        # (no clock read for a wait without limit in virtual time: nothing would use it)
        start = now_fn() if timeout is not None or not virtual else 0.0
        limit = None if timeout is None else start + timeout
        spin_end = 0.0 if virtual else start + self.reply_spin
        budget = self.spin_budget
        if budget is None or not spin_end:
            self._wait_ticket(ticket, now_fn, vclock, limit, spin_end)
        elif not budget.allowed(start):
            self._wait_ticket(ticket, now_fn, vclock, limit, 0.0)  # (the share is spent: block)
        else:
            try:
                self._wait_ticket(ticket, now_fn, vclock, limit, spin_end)
            finally:
                budget.spent(min(now_fn(), spin_end) - start)

    def _wait_ticket(self, ticket: CyclicFrame, now_fn: Callable[[], float],
                     vclock: VirtualClock | None, limit: float | None, spin_end: float) -> None:
        virtual = vclock is not None
        core = self.core
        with self._lock:
            while ticket.raw is None and not ticket.lost and ticket.replies is None:
                # (``self.now()``; in virtual time without the call)
                now = vclock.ns * 1e-9 if vclock is not None else now_fn()
                if core.closed:
                    return
                if limit is not None and now >= limit:
                    if not self._receiving:
                        self._drain_locked(now)  # what is there came in time
                    return
                if core.queued:
                    self._send_queued_locked(now)
                if virtual and not self._receiving:
                    self._receive_virtual_locked(now)  # (what _receive_once_locked does)
                    continue
                if now < spin_end and not self._receiving:
                    # Poll (a receive that does not block); see ``reply_spin``.
                    self._receive_once_locked(now, now)
                    continue
                if self._receiving:
                    self._sleepers += 1
                    try:
                        self._cond.wait(0.05 if limit is None else min(0.05, limit - now))
                    finally:
                        self._sleepers -= 1
                    continue
                self._receive_once_locked(now, limit)

    def receive_ready(self) -> bool:
        """Take one frame the link holds now, without waiting; whether one came.

        For an event loop that saw the link readable (the isolated engine between
        cycles): unlike :meth:`wait_until` it sends nothing queued and expires
        nothing, so datagrams waiting for the next cyclic frame keep waiting.
        """
        with self._lock:
            if self._receiving or self._vclock is not None:
                return False  # (another thread receives; virtual time has no readiness)
            _now, came = self._take_frame_locked(0.0)
            self._notify()
            return came

    def step(self) -> None:
        """After a cycle (the loop's thread): expire late frames, resume stepped workers."""
        if not self.stepper.busy:
            return
        with self._lock:
            now = self.now()
            if self.core.expire(now):
                self._notify()
            if self.core.queued:
                self._send_queued_locked(now)
        self.stepper.step()

    def _take_frame_locked(self, wait: float) -> tuple[float, bool]:
        """Receive one frame, the lock released while waiting up to ``wait`` seconds, and
        hand it to the core; (the time after, whether one came). A link error wakes the
        waiters and is raised."""
        self._receiving = True
        lock = self._lock
        lock.release()
        got: tuple[bytes, int] | None = None
        error: EtherCATError | None = None
        try:
            got = self._recv_locked(wait)
        except EtherCATError as exc:
            error = exc
        finally:
            lock.acquire()
            self._receiving = False
        now = self.now()
        if error is not None:
            self._notify()
            raise error
        if got is not None:
            self.core.on_frame(got[0], now, got[1])
            self._forward_locked()
        return now, got is not None

    def _receive_once_locked(self, now: float, limit: float | None) -> None:
        """Receive one frame (lock released while blocking) and handle timeouts."""
        if self._vclock is not None:
            self._receive_virtual_locked(now)
            return
        core = self.core
        first = due = core.next_deadline()
        if first is None:
            first = now + core.timeout
        if limit is not None and limit < first:
            first = limit
        wait = first - now if first > now else 0.0
        now, _came = self._take_frame_locked(wait)
        if now >= first:
            if due is not None and now >= due:
                # (only when a frame is overdue: a poll within the deadlines, the
                # cyclic thread's every cycle, costs one receive, not two)
                self._drain_locked(now)
            core.expire(now)
        if core.queued:
            self._send_queued_locked(now)
        self._notify()

    def _drain_locked(self, now: float) -> None:
        """Take the frames already waiting at the link, before deadlines are judged.

        A reply that is there is not lost, even when nobody read it in time: a
        responder that answers inside ``send`` (the in-process pair link), or a
        send that blocked, queues it after its deadline passed. Bounded, so that
        a flood of foreign frames cannot hold the lock.
        """
        core = self.core
        for _ in range(_DRAIN_MAX):
            got = self._recv_locked(0.0)
            if got is None:
                return
            core.on_frame(got[0], now, got[1])
            self._forward_locked()

    def _receive_virtual_locked(self, now: float) -> None:
        """Virtual time: take what the responder queued, else jump to the next deadline."""
        core = self.core
        ring = self._ring
        # (``_recv_locked`` and ``_forward_locked`` inline: the cyclic hot path)
        port = 0
        if ring is None:
            raw = self.link.recv(0)
        else:
            got = ring.recv_from(0)
            raw = None if got is None else got[0]
            port = 0 if got is None else got[1]
        if raw is not None:
            core.on_frame(raw, now, port)
            if ring is not None:
                self._forward_locked()
        else:
            # The responder already answered everything it will ever answer.
            vclock = self._vclock
            first = core.next_deadline()
            if vclock is not None and first is not None:
                vclock.sleep_until(int(first * 1e9) + 1)
                # (the float deadline may round a hair above the clock's nanoseconds)
                now = max(self.now(), first)
            core.expire(now)
        if core.queued:
            self._send_queued_locked(now)
        if self._sleepers:  # (``_notify``)
            self._cond.notify_all()
