"""The PDU loop: one scheduler owns the link and turns datagrams into frames.

Callers queue datagrams (``submit`` gives small futures, ``transact`` a whole
batch at once). The scheduler packs queued datagrams into frames in queue
order (many per frame, up to 1498 bytes of datagrams), gives every frame its
own index (all datagrams of a frame carry it), keeps several frames in flight,
and matches replies by that index. A reply must have the same datagrams as
the frame that was sent (command, address, length; the ADP of auto-increment
and broadcast commands is allowed to grow), otherwise the requests of that
frame fail with :class:`~pyethercat.errors.FrameError`. Frames that get no
reply are retried (new index) up to ``retries`` times, then their requests
fail with :class:`~pyethercat.errors.TimeoutError`. Replies to retired frames
(stale or duplicate) and our own frames seen again on the wire (a returned
frame has the locally administered bit in its source MAC, facts 1.1) are
counted and dropped.

There is no I/O thread: whichever caller waits for a result receives frames
for everybody (leader/follower), so a test over an in-process pair link with
a synchronous responder runs without threads and without timing
(``deterministic=True``: a frame whose reply is not already queued counts as
lost at once instead of after a real timeout).

The cyclic path sends its own frame, lets queued acyclic datagrams ride in
the spare room and is never retried: the next cycle is the retry.
``acyclic_hold`` makes acyclic requests wait that long for a cyclic frame
before they get frames of their own. A cyclic frame is a
:class:`CyclicTemplate` (``prepare_cyclic``): the frame is encoded once, the
caller writes the data bytes in place, ``send_prepared`` only patches the
index, and the reply is checked and handed back as raw bytes at known
offsets (no datagram objects, no decoding of the cyclic part).
``send_cyclic`` is the one-off form: a template made for one frame.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from pyethercat.errors import EtherCATError, FrameError, FrameTooLargeError, LinkError
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.link.base import Link
from pyethercat.wire.datagram import (
    HEADER_SIZE,
    LEN_MASK,
    MAX_DATA,
    MAX_PAYLOAD,
    MORE_BIT,
    WKC_SIZE,
    Command,
    Datagram,
    command_name,
    decode_datagrams,
    encode_datagram_into,
)
from pyethercat.wire.frame import (
    ECAT_HEADER_SIZE,
    ETH_HEADER_SIZE,
    ETHERTYPE_ETHERCAT,
    ETHERTYPE_VLAN,
    LOCALLY_ADMINISTERED_BIT,
    MASTER_MAC,
    MIN_FRAME_SIZE,
    FrameType,
    NotEtherCATError,
    decode_frame,
    ecat_header,
    encode_frame,
)

__all__ = ["Request", "CyclicFrame", "CyclicTemplate", "Scheduler", "SchedulerStats",
           "describe_datagram"]

#: Default time to wait for the reply of one frame, seconds.
DEFAULT_TIMEOUT = 0.05
#: Default number of re-sends after the first attempt.
DEFAULT_RETRIES = 3
#: Default number of frames in flight at once.
DEFAULT_MAX_IN_FLIGHT = 8
#: Default ``Scheduler.reply_spin``: poll up to 0.5 ms for a cyclic reply before blocking.
DEFAULT_REPLY_SPIN = 0.0005

_INDEX_COUNT = 256
# Where the EtherCAT header and the first datagram's index sit in an untagged frame.
_ECAT_AT = ETH_HEADER_SIZE
_FIRST_INDEX_AT = ETH_HEADER_SIZE + ECAT_HEADER_SIZE + 1
_ETHERTYPE_HI = ETHERTYPE_ETHERCAT >> 8
_ETHERTYPE_LO = ETHERTYPE_ETHERCAT & 0xFF


def describe_datagram(d: Datagram) -> str:
    """Short text naming a datagram's command and address, for messages."""
    name = command_name(int(d.command))
    if d.is_logical:
        return f"{name} 0x{d.logical_address:08X} ({len(d.data)} bytes)"
    return f"{name} adp=0x{d.adp:04X} ado=0x{d.ado:04X} ({len(d.data)} bytes)"


class Request:
    """One queued datagram and its outcome: a small future.

    ``result()`` waits (driving the scheduler's receive loop when no other
    thread does) and returns the reply datagram (data and working counter as
    they came back), or raises the error the request failed with.
    """

    __slots__ = ("datagram", "reply", "error", "attempts", "retries", "queued_at", "_scheduler")

    def __init__(self, scheduler: Scheduler, datagram: Datagram, retries: int) -> None:
        self._scheduler = scheduler
        self.datagram = datagram
        self.reply: Datagram | None = None
        self.error: EtherCATError | None = None
        #: Number of frames this datagram was sent in so far.
        self.attempts = 0
        self.retries = retries
        self.queued_at = 0.0

    def done(self) -> bool:
        """Whether the request has a reply or an error."""
        return self.reply is not None or self.error is not None

    def result(self, timeout: float | None = None) -> Datagram:
        """The reply datagram; raises the request's error."""
        self._scheduler.wait([self], timeout)
        if self.error is not None:
            raise self.error
        assert self.reply is not None
        return self.reply

    def __repr__(self) -> str:
        state = "done" if self.reply is not None else ("failed" if self.error else "pending")
        return f"<Request {describe_datagram(self.datagram)} {state}>"


class CyclicFrame:
    """Ticket for a frame sent with :meth:`Scheduler.send_cyclic` or ``send_prepared``.

    ``wait`` returns the reply datagrams of the cyclic part (in the order
    given), or ``None`` when the frame was lost (no reply in time, or a
    malformed reply). For a prepared frame ``wait_raw`` returns the reply
    frame itself (its layout is the template's: read working counters and
    data at the template's offsets). Acyclic datagrams that rode along are
    handled by the scheduler and never show up here.
    """

    __slots__ = ("_scheduler", "count", "replies", "raw", "template", "lost", "error", "sent_at",
                 "received_at", "carried")

    def __init__(self, scheduler: Scheduler, count: int,
                 template: CyclicTemplate | None = None) -> None:
        self._scheduler = scheduler
        self.count = count
        self.replies: list[Datagram] | None = None
        #: The whole reply frame (prepared frames only; untagged, template layout).
        self.raw: bytes | None = None
        self.template = template
        self.lost = False
        #: Why the frame counts as lost when it came back malformed.
        self.error: EtherCATError | None = None
        self.sent_at = 0.0
        self.received_at = 0.0
        #: Number of acyclic datagrams that rode in this frame.
        self.carried = 0

    def done(self) -> bool:
        return self.replies is not None or self.raw is not None or self.lost

    def wait(self, timeout: float | None = None) -> list[Datagram] | None:
        """Reply datagrams of the cyclic part, or ``None`` if the frame was lost."""
        if not self.done():
            self._scheduler._wait_until(self.done, timeout)
        if self.replies is None and self.raw is not None:
            self.replies = decode_frame(self.raw).datagrams[:self.count]
        return self.replies

    def wait_raw(self, timeout: float | None = None) -> bytes | None:
        """The reply frame of a prepared frame, or ``None`` if it was lost."""
        if self.raw is None and not self.lost:
            self._scheduler._await(self, timeout)
        return self.raw

    @property
    def round_trip(self) -> float | None:
        """Seconds between send and receive, when the reply arrived."""
        if self.replies is None and self.raw is None:
            return None
        return self.received_at - self.sent_at


class CyclicTemplate:
    """A cyclic frame encoded once (made by :meth:`Scheduler.prepare_cyclic`).

    ``frame`` is the whole Ethernet frame; before each
    :meth:`Scheduler.send_prepared` the owner writes datagram ``i``'s data
    into ``frame[data_offsets[i]:data_offsets[i] + lengths[i]]``. A reply
    has the same layout: its working counter ``i`` is the little-endian word
    at ``wkc_offsets[i]``, its data at ``data_offsets[i]``. One template
    belongs to one sender thread (the bytes are copied when sent).
    """

    __slots__ = ("frame", "datagrams", "data_offsets", "wkc_offsets", "lengths", "size", "end",
                 "_index_offsets", "_checks", "_last_header")

    def __init__(self, datagrams: Sequence[Datagram], src: bytes = MASTER_MAC) -> None:
        self.datagrams = tuple(Datagram(d.command, 0, d.address, bytes(d.data), d.irq)
                               for d in datagrams)
        self.frame = bytearray(encode_frame(self.datagrams, src=src))
        data_offsets: list[int] = []
        index_offsets: list[int] = []
        checks: list[tuple[int, int, int, bytes, int]] = []
        h = ETH_HEADER_SIZE + ECAT_HEADER_SIZE
        last = h
        for d in self.datagrams:
            last = h
            index_offsets.append(h + 1)
            n = len(d.data)
            # What a reply must carry: command, index (checked apart), address (only
            # ADO where every slave increments ADP), data length.
            lo = h + 4 if int(d.command) in _ADP_GROWS else h + 2
            checks.append((h, int(d.command), lo, bytes(self.frame[lo:h + 6]), n))
            data_offsets.append(h + HEADER_SIZE)
            h += HEADER_SIZE + n + WKC_SIZE
        self.data_offsets = tuple(data_offsets)
        self.lengths = tuple(len(d.data) for d in self.datagrams)
        self.wkc_offsets = tuple(o + n for o, n in zip(data_offsets, self.lengths, strict=True))
        #: Bytes of datagrams (headers, data, working counters).
        self.size = h - ETH_HEADER_SIZE - ECAT_HEADER_SIZE
        #: Offset just after the last datagram.
        self.end = h
        self._index_offsets = tuple(index_offsets)
        self._checks = tuple(checks)
        self._last_header = last

    def wkc(self, raw: bytes, i: int) -> int:
        """Working counter of datagram ``i`` in a reply."""
        at = self.wkc_offsets[i]
        return raw[at] | (raw[at + 1] << 8)


@dataclass
class SchedulerStats:
    """Counters of the PDU loop (monotonic, never reset by the scheduler)."""

    frames_sent: int = 0
    frames_received: int = 0
    datagrams_sent: int = 0
    #: Frames that got no reply in time (each lost frame counts once).
    frames_lost: int = 0
    #: Datagrams sent again after a lost frame.
    retries: int = 0
    #: Requests that failed after their last retry.
    timeouts: int = 0
    #: Replies whose index belongs to no frame in flight (late, duplicate, foreign).
    stale: int = 0
    #: Replies to a frame that was already answered.
    duplicates: int = 0
    #: Our own frames seen again on the receive side.
    looped_back: int = 0
    #: Replies that could not be decoded or did not match their frame.
    malformed: int = 0
    #: Frames that were not EtherCAT datagram frames.
    foreign: int = 0
    #: Acyclic datagrams carried in cyclic frames.
    carried: int = 0


class _InFlight:
    """A frame on the wire: its index, requests and deadline."""

    __slots__ = ("index", "datagrams", "requests", "cyclic", "deadline", "sent_at", "template",
                 "sent")

    def __init__(self, index: int, datagrams: list[Datagram], requests: list[Request],
                 cyclic: CyclicFrame | None, deadline: float, sent_at: float) -> None:
        self.index = index
        #: The requests' datagrams as sent (for a cyclic frame the template's come
        #: first in the frame, decoded into here only to explain a bad reply).
        self.datagrams = datagrams
        self.requests = requests
        self.cyclic = cyclic
        self.deadline = deadline
        self.sent_at = sent_at
        self.template: CyclicTemplate | None = None
        #: The frame as sent (prepared frames; decoded only to explain a bad reply).
        self.sent = b""


def _reply_matches(sent: Datagram, got: Datagram) -> str | None:
    """Why ``got`` is not the reply to ``sent`` (None when it is)."""
    if int(got.command) != int(sent.command):
        return f"command {command_name(int(got.command))}, sent {command_name(int(sent.command))}"
    if len(got.data) != len(sent.data):
        return f"{len(got.data)} data bytes, sent {len(sent.data)}"
    cmd = int(sent.command)
    if cmd in _ADP_GROWS:
        # Every slave increments ADP of auto-increment and broadcast commands.
        if got.ado != sent.ado:
            return f"ADO 0x{got.ado:04X}, sent 0x{sent.ado:04X}"
    elif got.address != sent.address:
        return f"address 0x{got.address:08X}, sent 0x{sent.address:08X}"
    return None


_ADP_GROWS = frozenset({Command.APRD, Command.APWR, Command.APRW, Command.ARMW,
                        Command.BRD, Command.BWR, Command.BRW})


def _untagged(raw: bytes) -> bytes:
    """The frame without its VLAN tag (so offsets match what was sent)."""
    if len(raw) >= 18 and ((raw[12] << 8) | raw[13]) == ETHERTYPE_VLAN:
        return raw[:12] + raw[16:]
    return raw


def _peek_index(raw: bytes) -> int | None:
    """Index of the first datagram of a raw Ethernet frame, if there is one."""
    start = ETH_HEADER_SIZE
    if len(raw) < start + ECAT_HEADER_SIZE + 2:
        return None
    ethertype = (raw[12] << 8) | raw[13]
    if ethertype == ETHERTYPE_VLAN:
        start += 4
        if len(raw) < start + ECAT_HEADER_SIZE + 2:
            return None
        ethertype = (raw[16] << 8) | raw[17]
    if ethertype != ETHERTYPE_ETHERCAT:
        return None
    return raw[start + ECAT_HEADER_SIZE + 1]


class Scheduler:
    """Packs queued datagrams into frames, sends them and matches the replies.

    Thread-safe: any thread may submit and wait. ``timeout`` is the time one
    frame has to come back, ``retries`` how often a lost datagram is sent
    again, ``max_in_flight`` how many frames may be on the wire at once.
    ``src`` is the source MAC of our frames. With ``deterministic=True`` the
    link must answer synchronously inside ``send`` (the in-process pair link
    with a responder): a missing reply is then a lost frame at once.
    """

    def __init__(self, link: Link, *, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = DEFAULT_RETRIES, max_in_flight: int = DEFAULT_MAX_IN_FLIGHT,
                 src: bytes = MASTER_MAC, deterministic: bool = False,
                 capacity: int = MAX_PAYLOAD,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not 1 <= max_in_flight < _INDEX_COUNT:
            raise ValueError(f"max_in_flight must be 1..{_INDEX_COUNT - 1}, got {max_in_flight}")
        if timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.link = link
        self.timeout = timeout
        self.retries = retries
        self.max_in_flight = max_in_flight
        self.src = bytes(src)
        self.deterministic = deterministic
        self.capacity = min(capacity, MAX_PAYLOAD)
        # A returned frame has the locally administered bit set in its source MAC, so
        # a frame with our exact (universal) source MAC is our own seen again.
        self._own_src_visible = not (self.src[0] & LOCALLY_ADMINISTERED_BIT)
        self.clock = clock
        #: Seconds an acyclic request waits for a cyclic frame to carry it (0: never).
        self.acyclic_hold = 0.0
        #: Seconds the cyclic thread polls the link for a prepared frame's reply
        #: before it blocks (0: block at once). Waking from a blocking receive
        #: costs tens of microseconds on a busy or virtual machine, and the CPU
        #: comes back with cold caches; SOEM polls the same way. Only
        #: ``wait_raw`` (the cyclic path) polls; with one CPU it never does,
        #: as the spinning would keep the CPU from whoever has to answer.
        self.reply_spin = DEFAULT_REPLY_SPIN if (os.cpu_count() or 1) > 1 else 0.0
        self.stats = SchedulerStats()
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._queue: deque[Request] = deque()
        self._in_flight: dict[int, _InFlight] = {}
        self._next_index = 0
        #: Indices answered recently (duplicates are told apart from stale replies).
        self._answered: deque[int] = deque(maxlen=64)
        self._receiving = False
        #: Threads blocked in the condition's wait (nobody to wake: skip the notify).
        self._sleepers = 0
        self._closed = False

    # -- submitting ----------------------------------------------------------------

    def submit(self, datagrams: Iterable[Datagram], *, retries: int | None = None,
               flush: bool = True) -> list[Request]:
        """Queue datagrams (sent in this order); returns one request per datagram.

        The datagrams' ``index`` fields are ignored (the scheduler assigns
        frame indices). ``flush=False`` only queues: the next flush, wait or
        cyclic frame sends them, so several callers' datagrams share frames.
        """
        reqs: list[Request] = []
        tries = self.retries if retries is None else retries
        for d in datagrams:
            if len(d.data) > MAX_DATA:
                raise FrameTooLargeError(
                    f"{describe_datagram(d)}: {len(d.data)} data bytes, one frame holds {MAX_DATA}")
            reqs.append(Request(self, d, tries))
        with self._lock:
            self._check_open()
            now = self.clock()
            for r in reqs:
                r.queued_at = now
                self._queue.append(r)
            if flush:
                self._flush_locked(now)
        return reqs

    def submit_one(self, datagram: Datagram, *, retries: int | None = None) -> Request:
        """Queue one datagram and send it."""
        return self.submit([datagram], retries=retries)[0]

    def flush(self) -> None:
        """Send queued datagrams now (as far as the in-flight budget allows)."""
        with self._lock:
            self._check_open()
            self._flush_locked(self.clock(), force=True)

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
        if not self._wait_until(lambda: all(r.done() for r in requests), timeout):
            with self._lock:
                for r in requests:
                    if not r.done():
                        r.error = EcTimeoutError(
                            f"no reply to {describe_datagram(r.datagram)} within {timeout} s")
                        self._forget_locked(r)

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
        size = sum(d.size for d in datagrams)
        if not datagrams or size > self.capacity:
            raise FrameTooLargeError(
                f"cyclic frame of {len(datagrams)} datagrams needs {size} bytes, "
                f"a frame holds {self.capacity}")
        return CyclicTemplate(datagrams, self.src)

    def send_prepared(self, template: CyclicTemplate, *, carry_acyclic: bool = True,
                      timeout: float | None = None) -> CyclicFrame:
        """Send a prepared frame now (its data as the owner wrote it); like ``send_cyclic``.

        Queued acyclic datagrams ride behind the template's datagrams when
        they fit. ``wait_raw()`` on the ticket gives the reply frame.
        """
        ticket = CyclicFrame(self, len(template.datagrams), template)
        with self._lock:
            if self._closed:
                self._check_open()
            now = self.clock()
            idx = self._alloc_index()
            frame = template.frame
            for at in template._index_offsets:
                frame[at] = idx
            carried = (self._take_queued_locked(self.capacity - template.size)
                       if carry_acyclic and self._queue else [])
            sent: list[Datagram] = []
            if carried:
                raw = self._extend_locked(template, carried, idx, sent)
                ticket.carried = len(carried)
                self.stats.carried += len(carried)
            else:
                raw = bytes(frame)
            entry = _InFlight(idx, sent, carried, ticket,
                              now + (self.timeout if timeout is None else timeout), now)
            entry.template = template
            entry.sent = raw
            ticket.sent_at = now
            self._transmit_locked(entry, raw, len(template.datagrams) + len(carried))
        return ticket

    def exchange_prepared(self, template: CyclicTemplate, *, carry_acyclic: bool = True,
                          timeout: float | None = None) -> bytes | None:
        """``send_prepared`` and wait: the reply frame, or ``None`` when the frame was lost."""
        return self.send_prepared(template, carry_acyclic=carry_acyclic,
                                  timeout=timeout).wait_raw()

    # -- state -----------------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Frames on the wire now."""
        with self._lock:
            return len(self._in_flight)

    @property
    def queued(self) -> int:
        """Datagrams waiting to be sent."""
        with self._lock:
            return len(self._queue)

    def close(self) -> None:
        """Fail everything pending; further use raises :class:`LinkError`. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            err = LinkError(f"scheduler on {self.link.name} closed")
            for r in self._queue:
                r.error = err
            self._queue.clear()
            for f in self._in_flight.values():
                for r in f.requests:
                    r.error = err
                if f.cyclic is not None:
                    f.cyclic.lost = True
                    f.cyclic.error = err
            self._in_flight.clear()
            self._notify()

    def _notify(self) -> None:
        """Wake the threads waiting for another receiver (lock held)."""
        if self._sleepers:
            self._cond.notify_all()

    def _check_open(self) -> None:
        if self._closed:
            raise LinkError(f"scheduler on {self.link.name} is closed")

    # -- internals (hold self._lock) --------------------------------------------------

    def _alloc_index(self) -> int:
        for _ in range(_INDEX_COUNT):
            idx = self._next_index
            self._next_index = (idx + 1) % _INDEX_COUNT
            if idx not in self._in_flight:
                return idx
        raise FrameError("no free frame index (256 frames in flight)")  # pragma: no cover

    def _flush_locked(self, now: float, force: bool = False) -> None:
        """Pack queued requests into frames while the in-flight budget allows."""
        hold = 0.0 if force else self.acyclic_hold
        while self._queue and len(self._in_flight) < self.max_in_flight:
            if hold and self._queue[0].queued_at + hold > now:
                return  # waiting for a cyclic frame to carry them
            self._send_frame_locked(self._take_queued_locked(self.capacity), now)

    def _take_queued_locked(self, free: int) -> list[Request]:
        """Take queued requests from the front, in order, while they fit ``free`` bytes."""
        taken: list[Request] = []
        queue = self._queue
        while queue and queue[0].datagram.size <= free:
            r = queue.popleft()
            free -= r.datagram.size
            taken.append(r)
        return taken

    def _send_frame_locked(self, requests: list[Request], now: float) -> None:
        """Send the requests' datagrams as one acyclic frame."""
        idx = self._alloc_index()
        sent = [Datagram(d.command, idx, d.address, d.data, d.irq)
                for d in (r.datagram for r in requests)]
        entry = _InFlight(idx, sent, requests, None, now + self.timeout, now)
        self._transmit_locked(entry, encode_frame(sent, src=self.src), len(sent))

    def _extend_locked(self, template: CyclicTemplate, carried: list[Request], idx: int,
                       sent: list[Datagram]) -> bytes:
        """The template's frame with ``carried`` appended (their datagrams go to ``sent``)."""
        buf = bytearray(template.frame[:template.end])
        # The last cyclic datagram now has followers.
        buf[template._last_header + 7] |= MORE_BIT >> 8
        extra = 0
        for r in carried:
            d = r.datagram
            sent.append(Datagram(d.command, idx, d.address, d.data, d.irq))
            extra += d.size
        buf.extend(bytes(extra))
        at = template.end
        last = len(sent) - 1
        for n, d in enumerate(sent):
            at = encode_datagram_into(buf, at, d, n != last)
        word = ecat_header(template.size + extra)
        buf[_ECAT_AT] = word & 0xFF
        buf[_ECAT_AT + 1] = word >> 8
        if len(buf) < MIN_FRAME_SIZE:
            buf.extend(bytes(MIN_FRAME_SIZE - len(buf)))
        return bytes(buf)

    def _transmit_locked(self, entry: _InFlight, raw: bytes, count: int) -> None:
        """Register ``entry`` in flight and put ``raw`` on the link."""
        idx = entry.index
        for r in entry.requests:
            r.attempts += 1
        self._in_flight[idx] = entry
        try:
            self.link.send(raw)
        except EtherCATError as exc:
            del self._in_flight[idx]
            for r in entry.requests:
                r.error = exc
            cyclic = entry.cyclic
            if cyclic is not None:
                cyclic.lost = True
                cyclic.error = exc
            self._notify()
            raise
        stats = self.stats
        stats.frames_sent += 1
        stats.datagrams_sent += count

    def _forget_locked(self, req: Request) -> None:
        with contextlib.suppress(ValueError):
            self._queue.remove(req)

    def _expire_locked(self, now: float, everything: bool = False) -> None:
        """Handle frames whose deadline passed: retry their requests or fail them."""
        expired = [f for f in self._in_flight.values() if everything or f.deadline <= now]
        if not expired:
            return
        requeue: list[Request] = []
        for f in expired:
            del self._in_flight[f.index]
            self.stats.frames_lost += 1
            if f.cyclic is not None:
                f.cyclic.lost = True
            for r in f.requests:
                if r.done():
                    continue
                if r.attempts <= r.retries:
                    self.stats.retries += 1
                    requeue.append(r)
                else:
                    self.stats.timeouts += 1
                    r.error = EcTimeoutError(
                        f"no reply to {describe_datagram(r.datagram)} after {r.attempts} "
                        f"attempt{'s' if r.attempts != 1 else ''} "
                        f"({f.deadline - f.sent_at:.3g} s each) on {self.link.name}")
        # Retried requests go first, in their original order.
        for r in reversed(requeue):
            r.queued_at = now - self.acyclic_hold
            self._queue.appendleft(r)
        self._notify()

    def _handle_frame_locked(self, raw: bytes, now: float) -> None:
        if self._own_src_visible and raw[6:12] == self.src:
            # A slave sets the locally administered bit in what it returns.
            self.stats.looped_back += 1
            return
        if len(raw) > _FIRST_INDEX_AT + 4 and raw[12] == _ETHERTYPE_HI and raw[13] == _ETHERTYPE_LO:
            entry = self._in_flight.get(raw[_FIRST_INDEX_AT])
            if entry is not None and entry.template is not None and \
                    self._take_prepared_locked(entry, raw, now):
                return
        try:
            frame = decode_frame(raw)
        except NotEtherCATError:
            self.stats.foreign += 1
            return
        except FrameError as exc:
            self.stats.malformed += 1
            idx = _peek_index(raw)
            entry = self._in_flight.pop(idx, None) if idx is not None else None
            if entry is not None:
                self._fail_entry_locked(entry, FrameError(
                    f"malformed reply to frame {idx} on {self.link.name}: {exc}"), now)
            return
        if frame.frame_type != FrameType.DATAGRAMS or not frame.datagrams:
            self.stats.foreign += 1
            return
        idx = frame.datagrams[0].index
        entry = self._in_flight.get(idx)
        if entry is None:
            if idx in self._answered:
                self.stats.duplicates += 1
            else:
                self.stats.stale += 1
            return
        if entry.template is not None:
            # A prepared frame whose reply failed the quick check: compare in full.
            entry.datagrams = decode_frame(entry.sent).datagrams
        problem = self._mismatch(entry, frame.datagrams)
        if problem is not None:
            if problem[0]:
                # Another frame's reply that happens to carry this index: not ours.
                self.stats.stale += 1
                return
            del self._in_flight[idx]
            self.stats.malformed += 1
            self._fail_entry_locked(entry, FrameError(
                f"reply to frame {idx} on {self.link.name} does not match: {problem[1]}"), now)
            return
        del self._in_flight[idx]
        self._answered.append(idx)
        self.stats.frames_received += 1
        ncyc = entry.cyclic.count if entry.cyclic is not None else 0
        got = frame.datagrams
        for r, d in zip(entry.requests, got[ncyc:], strict=True):
            if not r.done():
                r.reply = d
        if entry.cyclic is not None:
            entry.cyclic.replies = got[:ncyc]
            entry.cyclic.received_at = now
            entry.cyclic.raw = _untagged(raw)
        self._notify()

    def _take_prepared_locked(self, entry: _InFlight, raw: bytes, now: float) -> bool:
        """Accept the reply to a prepared frame by its bytes; False: let the full path judge."""
        template = entry.template
        assert template is not None
        sent = entry.sent
        if len(raw) < template.end or raw[_ECAT_AT] != sent[_ECAT_AT] or \
                raw[_ECAT_AT + 1] != sent[_ECAT_AT + 1]:
            return False
        idx = entry.index
        for h, cmd, lo, address, length in template._checks:
            if raw[h] != cmd or raw[h + 1] != idx or raw[lo:h + 6] != address or \
                    (raw[h + 6] | (raw[h + 7] << 8)) & LEN_MASK != length:
                return False
        if entry.requests:
            end = ETH_HEADER_SIZE + ECAT_HEADER_SIZE + (
                (raw[_ECAT_AT] | (raw[_ECAT_AT + 1] << 8)) & LEN_MASK)
            try:
                got = decode_datagrams(memoryview(raw)[template.end:end])
            except FrameError:
                return False
            if self._mismatch(entry, got) is not None:
                return False
            for r, d in zip(entry.requests, got, strict=True):
                if not r.done():
                    r.reply = d
        del self._in_flight[idx]
        self._answered.append(idx)
        self.stats.frames_received += 1
        ticket = entry.cyclic
        assert ticket is not None
        ticket.raw = raw
        ticket.received_at = now
        self._notify()
        return True

    @staticmethod
    def _mismatch(entry: _InFlight, got: list[Datagram]) -> tuple[bool, str] | None:
        """None if ``got`` answers ``entry``; else (looks foreign, reason)."""
        if got and entry.datagrams and int(got[0].command) != int(entry.datagrams[0].command):
            # Another frame's reply that happens to carry this index.
            return (True, f"datagram 0 is {command_name(int(got[0].command))}, sent "
                          f"{command_name(int(entry.datagrams[0].command))}")
        if len(got) != len(entry.datagrams):
            return (False, f"{len(got)} datagrams, sent {len(entry.datagrams)}")
        for n, (s, g) in enumerate(zip(entry.datagrams, got, strict=True)):
            if g.index != s.index:
                return (False, f"datagram {n} has index {g.index}, sent {s.index}")
            why = _reply_matches(s, g)
            if why is not None:
                # A wrong first datagram means the index was a coincidence.
                return (n == 0 and int(g.command) != int(s.command),
                        f"datagram {n} ({describe_datagram(s)}): {why}")
        return None

    def _fail_entry_locked(self, entry: _InFlight, err: EtherCATError, now: float) -> None:
        for r in entry.requests:
            if not r.done():
                r.error = err
        if entry.cyclic is not None:
            entry.cyclic.lost = True
            entry.cyclic.error = err
            entry.cyclic.received_at = now
        self._notify()

    # -- the receive loop ---------------------------------------------------------------

    def _wait_until(self, done: Callable[[], bool], timeout: float | None) -> bool:
        """Drive or await the receive loop until ``done()``; False on ``timeout``."""
        clock = self.clock
        limit = None if timeout is None else clock() + timeout
        with self._lock:
            while not done():
                now = clock()
                if limit is not None and now >= limit:
                    return False
                if self._closed:
                    return done()
                if self._queue:
                    self._flush_locked(now)
                if self._receiving:
                    # Another thread receives for us; it notifies on every change.
                    wait = 0.05 if limit is None else min(0.05, max(0.0, limit - now))
                    self._sleepers += 1
                    try:
                        self._cond.wait(wait)
                    finally:
                        self._sleepers -= 1
                    continue
                if not self._in_flight and not self._queue:
                    # Nothing can finish what we wait for.
                    return done()
                self._receive_once_locked(now, limit)
        return True

    def _await(self, ticket: CyclicFrame, timeout: float | None) -> None:
        """``_wait_until(ticket.done)`` without the calls: the cyclic thread's wait."""
        clock = self.clock
        start = clock()
        limit = None if timeout is None else start + timeout
        spin_end = 0.0 if self.deterministic else start + self.reply_spin
        with self._lock:
            while ticket.raw is None and not ticket.lost and ticket.replies is None:
                now = clock()
                if self._closed or (limit is not None and now >= limit):
                    return
                if self._queue:
                    self._flush_locked(now)
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

    def _receive_once_locked(self, now: float, limit: float | None) -> None:
        """Receive one frame (lock released while blocking) and handle timeouts."""
        if self.deterministic:
            raw = self.link.recv(0)
            if raw is None:
                # The responder already answered everything it will ever answer.
                self._expire_locked(now, everything=True)
                self._flush_locked(now, force=True)
                return
            self._handle_frame_locked(raw, now)
            if self._queue:
                self._flush_locked(now)
            return
        first = min([f.deadline for f in self._in_flight.values()], default=now + self.timeout)
        if self._queue and self.acyclic_hold:
            first = min(first, self._queue[0].queued_at + self.acyclic_hold)
        if limit is not None and limit < first:
            first = limit
        wait = first - now if first > now else 0.0
        self._receiving = True
        lock = self._lock
        lock.release()
        got: bytes | None = None
        error: EtherCATError | None = None
        try:
            got = self.link.recv(wait)
        except EtherCATError as exc:
            error = exc
        finally:
            lock.acquire()
            self._receiving = False
        now = self.clock()
        if error is not None:
            self._notify()
            raise error
        if got is not None:
            self._handle_frame_locked(got, now)
        if now >= first:
            self._expire_locked(now)
        if self._queue:
            self._flush_locked(now)
        self._notify()
