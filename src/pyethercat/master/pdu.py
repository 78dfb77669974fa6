"""The PDU core: datagrams in, frames out; frames in, replies out. No I/O, no clock, no threads.

:class:`PduCore` is the frame logic of the master in the manner of h11's
``Connection`` and ethercrab's ``PduTx``/``PduRx``: its caller (the
:class:`~pyethercat.master.scheduler.Scheduler`, a test, later a redundant
link or an engine in another process) feeds it bytes and the current time
and carries out what it hands back:

- ``submit(datagrams, now)`` queues datagrams and returns one
  :class:`Request` (a small future) per datagram;
- ``next_frames(now)`` packs queued datagrams into frames (in queue order,
  many per frame, up to 1498 bytes of datagrams), gives every frame its own
  index (all datagrams of a frame carry it), registers it in flight and
  returns ``(index, frame bytes)`` pairs to put on the wire;
- ``send_prepared(template, now)`` does the same for a cyclic frame encoded
  once (:class:`CyclicTemplate`), letting queued datagrams ride in its spare
  room;
- ``on_frame(raw, now)`` matches a received frame to the frame in flight with
  its index and completes the requests (or the cyclic ticket);
- ``next_deadline()`` says when ``expire(now)`` has work: frames whose reply
  did not come in time are retried (their requests go back to the front of
  the queue, to be sent with a new index) up to ``retries`` times, then fail
  with :class:`~pyethercat.errors.TimeoutError`;
- ``send_failed(index, error)`` takes back a frame the link refused.

Matching rules. A reply must have the same datagrams as the frame sent
(command, address, length; the ADP of auto-increment and broadcast commands
is allowed to grow, as every slave increments it), otherwise the requests of
that frame fail with :class:`~pyethercat.errors.FrameError`. Replies whose
index belongs to no frame in flight are counted and dropped: ``duplicates``
when the index was answered recently, ``stale`` otherwise (a late reply to a
frame already retried, another master's frame). Our own frames seen again on
a medium that cannot tell sent from received frames are recognised by their
source MAC (a slave sets the locally administered bit of the source MAC in
the frames it returns, ETG.1000.4 section 5.1) when ``drop_own_frames`` is
set.

Cable redundancy (a ring on a two-port link): with ``redundancy`` set (a
:class:`~pyethercat.master.redundancy.Redundancy`), the driver asks
:meth:`route` on which ports to send each frame, passes the port a frame
came in on to :meth:`on_frame`, and sends what :meth:`take_forwards` hands
out. A frame sent on both ports comes back twice, each copy processed by
the slaves on one side of a break; the copies of one index are merged
(``master.redundancy.merge_copies``) before the reply is matched and handed
out, so everything above sees one reply. Requests and tickets keep the
copies by port (``copies``) for diagnostics.
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from pyethercat.errors import EtherCATError, FrameError, FrameTooLargeError, LinkError
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.redundancy import (
    PORT_B,
    CopySet,
    Redundancy,
    hand_copies,
    mark_for_port,
    ordered_command,
)
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
    LOCALLY_ADMINISTERED_BIT,
    MASTER_MAC,
    MIN_FRAME_SIZE,
    FrameType,
    NotEtherCATError,
    decode_frame,
    ecat_header,
    encode_frame,
    first_index,
    untagged,
)

__all__ = [
    "DEFAULT_MAX_IN_FLIGHT",
    "DEFAULT_RETRIES",
    "DEFAULT_TIMEOUT",
    "CyclicFrame",
    "CyclicTemplate",
    "PduCore",
    "PduStats",
    "Request",
    "Waiter",
    "describe_datagram",
]

#: Default time to wait for the reply of one frame, seconds.
DEFAULT_TIMEOUT = 0.05
#: Default number of re-sends after the first attempt.
DEFAULT_RETRIES = 3
#: Default number of frames in flight at once.
DEFAULT_MAX_IN_FLIGHT = 8

_INDEX_COUNT = 256
# ``queued_at`` of a retried request: ``acyclic_hold`` never holds it back again.
_NOT_HELD = float("-inf")
# Where the EtherCAT header and the first datagram's index sit in an untagged frame.
_ECAT_AT = ETH_HEADER_SIZE
_FIRST_INDEX_AT = ETH_HEADER_SIZE + ECAT_HEADER_SIZE + 1
_ETHERTYPE_HI = ETHERTYPE_ETHERCAT >> 8
_ETHERTYPE_LO = ETHERTYPE_ETHERCAT & 0xFF
# Commands whose ADP every slave increments on the way (auto-increment, broadcast).
_ADP_GROWS = frozenset({Command.APRD, Command.APWR, Command.APRW, Command.ARMW,
                        Command.BRD, Command.BWR, Command.BRW})


def describe_datagram(d: Datagram) -> str:
    """Short text naming a datagram's command and address, for messages."""
    name = command_name(int(d.command))
    if d.is_logical:
        return f"{name} 0x{d.logical_address:08X} ({len(d.data)} bytes)"
    return f"{name} adp=0x{d.adp:04X} ado=0x{d.ado:04X} ({len(d.data)} bytes)"


class Waiter(Protocol):
    """What drives the core for a waiting caller (the scheduler)."""

    def wait(self, requests: Sequence[Request], timeout: float | None = None) -> None: ...

    def wait_until(self, done: Callable[[], bool], timeout: float | None) -> bool: ...

    def wait_ticket(self, ticket: CyclicFrame, timeout: float | None) -> None: ...


class Request:
    """One queued datagram and its outcome: a small future.

    ``result()`` waits (through the scheduler that made it, which drives the
    receive loop when no other thread does) and returns the reply datagram
    (data and working counter as they came back), or raises the error the
    request failed with.
    """

    __slots__ = ("datagram", "reply", "error", "attempts", "retries", "queued_at", "_waiter",
                 "copies")

    def __init__(self, waiter: Waiter | None, datagram: Datagram, retries: int) -> None:
        self._waiter = waiter
        self.datagram = datagram
        self.reply: Datagram | None = None
        self.error: EtherCATError | None = None
        #: Number of frames this datagram was sent in so far.
        self.attempts = 0
        self.retries = retries
        self.queued_at = 0.0
        #: On a ring: this datagram as each copy brought it back, by port (A = 0, B = 1).
        self.copies: dict[int, Datagram] | None = None

    def done(self) -> bool:
        """Whether the request has a reply or an error."""
        return self.reply is not None or self.error is not None

    def result(self, timeout: float | None = None) -> Datagram:
        """The reply datagram; raises the request's error."""
        if not self.done() and self._waiter is not None:
            self._waiter.wait([self], timeout)
        if self.error is not None:
            raise self.error
        if self.reply is None:
            raise EcTimeoutError(f"no reply to {describe_datagram(self.datagram)} yet")
        return self.reply

    def __repr__(self) -> str:
        state = "done" if self.reply is not None else ("failed" if self.error else "pending")
        return f"<Request {describe_datagram(self.datagram)} {state}>"


class CyclicFrame:
    """Ticket for a cyclic frame (``send_cyclic`` or ``send_prepared``).

    ``wait`` returns the reply datagrams of the cyclic part (in the order
    given), or ``None`` when the frame was lost (no reply in time, or a
    malformed reply). For a prepared frame ``wait_raw`` returns the reply
    frame itself (its layout is the template's: read working counters and
    data at the template's offsets). Acyclic datagrams that rode along are
    handled by the core and never show up here.
    """

    __slots__ = ("_waiter", "count", "replies", "raw", "template", "lost", "error", "sent_at",
                 "received_at", "carried", "copies")

    def __init__(self, waiter: Waiter | None, count: int,
                 template: CyclicTemplate | None = None) -> None:
        self._waiter = waiter
        self.count = count
        self.replies: list[Datagram] | None = None
        #: The whole reply frame (untagged, template layout).
        self.raw: bytes | None = None
        self.template = template
        self.lost = False
        #: Why the frame counts as lost when it came back malformed.
        self.error: EtherCATError | None = None
        self.sent_at = 0.0
        self.received_at = 0.0
        #: Number of acyclic datagrams that rode in this frame.
        self.carried = 0
        #: On a ring: the copies of the reply frame by the port they came in on.
        self.copies: dict[int, bytes] | None = None

    def done(self) -> bool:
        return self.replies is not None or self.raw is not None or self.lost

    def wait(self, timeout: float | None = None) -> list[Datagram] | None:
        """Reply datagrams of the cyclic part, or ``None`` if the frame was lost."""
        if not self.done() and self._waiter is not None:
            self._waiter.wait_until(self.done, timeout)
        if self.replies is None and self.raw is not None:
            self.replies = decode_frame(self.raw).datagrams[:self.count]
        return self.replies

    def wait_raw(self, timeout: float | None = None) -> bytes | None:
        """The reply frame of a prepared frame, or ``None`` if it was lost."""
        if self.raw is None and not self.lost and self._waiter is not None:
            self._waiter.wait_ticket(self, timeout)
        return self.raw

    @property
    def round_trip(self) -> float | None:
        """Seconds between send and receive, when the reply arrived."""
        if self.replies is None and self.raw is None:
            return None
        return self.received_at - self.sent_at


class CyclicTemplate:
    """A cyclic frame encoded once (made by :meth:`PduCore.prepare_cyclic`).

    ``frame`` is the whole Ethernet frame; before each ``send_prepared`` the
    owner writes datagram ``i``'s data into
    ``frame[data_offsets[i]:data_offsets[i] + lengths[i]]``. A reply has the
    same layout: its working counter ``i`` is the little-endian word at
    ``wkc_offsets[i]``, its data at ``data_offsets[i]``. One template belongs
    to one sender thread (the bytes are copied when sent).
    """

    __slots__ = ("frame", "datagrams", "data_offsets", "wkc_offsets", "lengths", "size", "end",
                 "index_offsets", "checks", "last_header", "ordered")

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
        #: Offsets of the index byte of each datagram (patched per send).
        self.index_offsets = tuple(index_offsets)
        #: Per datagram: (header offset, command, address offset, address bytes, length).
        self.checks = tuple(checks)
        #: Offset of the last datagram's header (its "more follows" bit).
        self.last_header = last
        #: The frame must pass the slaves in bus order (auto-increment or RMW
        #: datagrams; set by the owner for cross traffic): on a ring it goes out on
        #: one port and on through the other (master.redundancy).
        self.ordered = any(ordered_command(int(d.command)) for d in self.datagrams)

    def wkc(self, raw: bytes, i: int) -> int:
        """Working counter of datagram ``i`` in a reply."""
        at = self.wkc_offsets[i]
        return raw[at] | (raw[at + 1] << 8)


@dataclass
class PduStats:
    """Counters of the PDU core (monotonic, never reset by the core)."""

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
                 "sent", "copies")

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
        #: On a ring: how the frame went out and the copies back so far.
        self.copies: CopySet | None = None


def _reply_matches(sent: Datagram, got: Datagram) -> str | None:
    """Why ``got`` is not the reply to ``sent`` (None when it is)."""
    if int(got.command) != int(sent.command):
        return f"command {command_name(int(got.command))}, sent {command_name(int(sent.command))}"
    if len(got.data) != len(sent.data):
        return f"{len(got.data)} data bytes, sent {len(sent.data)}"
    if int(sent.command) in _ADP_GROWS:
        if got.ado != sent.ado:
            return f"ADO 0x{got.ado:04X}, sent 0x{sent.ado:04X}"
    elif got.address != sent.address:
        return f"address 0x{got.address:08X}, sent 0x{sent.address:08X}"
    return None


class PduCore:
    """Index allocation, packing, the in-flight table, reply matching, expiry and retries.

    ``timeout`` is the time one frame has to come back (seconds, in the
    caller's time base), ``retries`` how often a lost datagram is sent again,
    ``max_in_flight`` how many frames may be on the wire at once, ``src`` the
    source MAC of our frames, ``capacity`` the datagram bytes per frame.
    ``drop_own_frames``: drop received frames that carry ``src`` unchanged
    (for media that show our own transmissions as received frames). ``name``
    names the link in messages. Not thread-safe: the driver serialises calls.
    """

    def __init__(self, *, timeout: float = DEFAULT_TIMEOUT, retries: int = DEFAULT_RETRIES,
                 max_in_flight: int = DEFAULT_MAX_IN_FLIGHT, src: bytes = MASTER_MAC,
                 capacity: int = MAX_PAYLOAD, drop_own_frames: bool = True,
                 name: str = "link") -> None:
        if not 1 <= max_in_flight < _INDEX_COUNT:
            raise ValueError(f"max_in_flight must be 1..{_INDEX_COUNT - 1}, got {max_in_flight}")
        if timeout <= 0:
            raise ValueError(f"timeout must be positive, got {timeout}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.timeout = timeout
        self.retries = retries
        self.max_in_flight = max_in_flight
        self.src = bytes(src)
        #: Source MACs of our own frames: as sent on port A, and as marked for port B.
        self._own = (self.src, mark_for_port(bytes(12) + self.src, PORT_B)[6:12])
        self.capacity = min(capacity, MAX_PAYLOAD)
        self.name = name
        # A frame that still carries our universal source MAC was not returned by a
        # slave. A locally administered ``src`` cannot be told apart: never drop then.
        self.drop_own_frames = drop_own_frames and not (self.src[0] & LOCALLY_ADMINISTERED_BIT)
        #: Seconds an acyclic request waits for a cyclic frame to carry it (0: never).
        self.acyclic_hold = 0.0
        self.stats = PduStats()
        self._queue: deque[Request] = deque()
        self._in_flight: dict[int, _InFlight] = {}
        self._next_index = 0
        #: Indices answered recently (duplicates are told apart from stale replies).
        self._answered: deque[int] = deque(maxlen=64)
        self._closed: LinkError | None = None
        #: Cable redundancy (a ring on a two-port link), or None.
        self.redundancy: Redundancy | None = None
        self._forwards: list[tuple[int, bytes]] = []

    # -- state ------------------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Frames on the wire now."""
        return len(self._in_flight)

    @property
    def queued(self) -> int:
        """Datagrams waiting to be sent."""
        return len(self._queue)

    @property
    def closed(self) -> bool:
        return self._closed is not None

    def check_open(self) -> None:
        """Raise :class:`LinkError` once :meth:`close` ran."""
        if self._closed is not None:
            raise LinkError(str(self._closed))

    def next_deadline(self) -> float | None:
        """When :meth:`expire` or :meth:`next_frames` will have work without a frame arriving.

        The earliest reply deadline of the frames in flight, or the moment a
        held acyclic request stops waiting for a cyclic frame; ``None`` when
        nothing is pending.
        """
        first = min([f.deadline for f in self._in_flight.values()], default=None)
        if self._queue and self.acyclic_hold and self._queue[0].queued_at != _NOT_HELD:
            release = self._queue[0].queued_at + self.acyclic_hold
            first = release if first is None else min(first, release)
        return first

    # -- submitting -------------------------------------------------------------------

    def submit(self, datagrams: Iterable[Datagram], now: float, *, retries: int | None = None,
               waiter: Waiter | None = None) -> list[Request]:
        """Queue datagrams (sent in this order); returns one request per datagram.

        The datagrams' ``index`` fields are ignored (the core assigns frame
        indices). Nothing is sent before :meth:`next_frames`.
        """
        tries = self.retries if retries is None else retries
        reqs: list[Request] = []
        for d in datagrams:
            if len(d.data) > MAX_DATA:
                raise FrameTooLargeError(
                    f"{describe_datagram(d)}: {len(d.data)} data bytes, one frame holds {MAX_DATA}")
            reqs.append(Request(waiter, d, tries))
        self.check_open()
        for r in reqs:
            r.queued_at = now
            self._queue.append(r)
        return reqs

    def forget(self, req: Request) -> None:
        """Take a request out of the queue (the caller gave up on it)."""
        with contextlib.suppress(ValueError):
            self._queue.remove(req)

    def next_frame(self, now: float, *, force: bool = False) -> tuple[int, bytes] | None:
        """The next frame to send now, or ``None``: queued requests packed into one frame.

        The frame is registered in flight (index, deadline) before it is
        handed out; a driver whose link refuses it calls :meth:`send_failed`.
        ``force`` sends requests that ``acyclic_hold`` would keep waiting for
        a cyclic frame. ``None`` when nothing is queued, the in-flight budget
        is used up, or the queue waits for a cyclic frame.
        """
        queue = self._queue
        if not queue or len(self._in_flight) >= self.max_in_flight:
            return None
        if not force and self.acyclic_hold and queue[0].queued_at + self.acyclic_hold > now:
            return None  # waiting for a cyclic frame to carry them
        requests = self._take_queued(self.capacity)
        idx = self._alloc_index()
        sent = [Datagram(d.command, idx, d.address, d.data, d.irq)
                for d in (r.datagram for r in requests)]
        entry = _InFlight(idx, sent, requests, None, now + self.timeout, now)
        return idx, self._register(entry, encode_frame(sent, src=self.src), len(sent))

    def next_frames(self, now: float, *, force: bool = False) -> list[tuple[int, bytes]]:
        """Every frame :meth:`next_frame` would hand out now, as ``(index, bytes)`` pairs."""
        out: list[tuple[int, bytes]] = []
        while (frame := self.next_frame(now, force=force)) is not None:
            out.append(frame)
        return out

    def prepare_cyclic(self, datagrams: Sequence[Datagram]) -> CyclicTemplate:
        """Encode a cyclic frame once, for :meth:`send_prepared` (see :class:`CyclicTemplate`)."""
        size = sum(d.size for d in datagrams)
        if not datagrams or size > self.capacity:
            raise FrameTooLargeError(
                f"cyclic frame of {len(datagrams)} datagrams needs {size} bytes, "
                f"a frame holds {self.capacity}")
        return CyclicTemplate(datagrams, self.src)

    def send_prepared(self, template: CyclicTemplate, now: float, *, carry_acyclic: bool = True,
                      timeout: float | None = None,
                      waiter: Waiter | None = None) -> tuple[CyclicFrame, int, bytes]:
        """Register a prepared frame in flight: (ticket, index, frame bytes to send now).

        Queued acyclic datagrams ride behind the template's datagrams when
        they fit. The frame is never retried: the next cycle is the retry.
        """
        if self._closed is not None:
            self.check_open()
        ticket = CyclicFrame(waiter, len(template.datagrams), template)
        idx = self._next_index
        if idx in self._in_flight:
            idx = self._alloc_index()
        else:  # (what _alloc_index does when the next index is free, inline: the hot path)
            self._next_index = (idx + 1) % _INDEX_COUNT
        frame = template.frame
        for at in template.index_offsets:
            frame[at] = idx
        carried = (self._take_queued(self.capacity - template.size)
                   if carry_acyclic and self._queue else [])
        sent: list[Datagram] = []
        if carried:
            raw = self._extend(template, carried, idx, sent)
            ticket.carried = len(carried)
            self.stats.carried += len(carried)
        else:
            raw = bytes(frame)
        entry = _InFlight(idx, sent, carried, ticket,
                          now + (self.timeout if timeout is None else timeout), now)
        entry.template = template
        entry.sent = raw
        ticket.sent_at = now
        # (what _register does, inline: this is the cyclic hot path)
        for r in carried:
            r.attempts += 1
        self._in_flight[idx] = entry
        stats = self.stats
        stats.frames_sent += 1
        stats.datagrams_sent += ticket.count + len(carried)
        return ticket, idx, raw

    # -- a ring (see the module text) ---------------------------------------------------

    def route(self, index: int, raw: bytes) -> list[int]:
        """The ports to send the frame ``index`` (bytes ``raw``) on; it is a ring's now."""
        red = self.redundancy
        entry = self._in_flight.get(index)
        if red is None or entry is None:
            return [0]
        template = entry.template
        ordered = (template is not None and template.ordered) or any(
            ordered_command(int(r.datagram.command)) for r in entry.requests)
        entry.copies, ports = red.plan(raw, ordered)
        entry.sent = raw
        return ports

    def port_refused(self, index: int, port: int) -> None:
        """The link refused the frame ``index`` on ``port`` (sent on the others)."""
        entry = self._in_flight.get(index)
        if self.redundancy is not None and entry is not None and entry.copies is not None:
            self.redundancy.refused(entry.copies, port)

    def take_forwards(self) -> list[tuple[int, bytes]]:
        """Frames to send on (port, frame): chain frames that came back on their own port."""
        out, self._forwards = self._forwards, []
        return out

    def _copy(self, raw: bytes, port: int) -> bytes | None:
        """A frame came in on ``port`` of a ring: the reply to match now, or None (wait, forward)."""
        red = self.redundancy
        assert red is not None
        red.seen(port)
        idx = first_index(raw)
        entry = self._in_flight.get(idx) if idx is not None else None
        if entry is None or entry.copies is None:
            return raw
        action, out, target = red.arrived(entry.copies, port, raw, entry.sent)
        if action == "forward":
            assert out is not None
            self._forwards.append((target, out))
            return None
        if action == "wait":
            return None
        if not entry.copies.got:
            entry.copies.got[port] = raw
        return raw if out is None else out

    def send_failed(self, index: int, error: EtherCATError) -> None:
        """The link refused the frame with ``index``: fail what it carried."""
        entry = self._in_flight.pop(index, None)
        if entry is None:
            return
        stats = self.stats
        stats.frames_sent -= 1
        stats.datagrams_sent -= len(entry.requests) + (entry.cyclic.count if entry.cyclic else 0)
        for r in entry.requests:
            r.error = error
        cyclic = entry.cyclic
        if cyclic is not None:
            cyclic.lost = True
            cyclic.error = error

    # -- internals --------------------------------------------------------------------

    def _alloc_index(self) -> int:
        for _ in range(_INDEX_COUNT):
            idx = self._next_index
            self._next_index = (idx + 1) % _INDEX_COUNT
            if idx not in self._in_flight:
                return idx
        raise FrameError("no free frame index (256 frames in flight)")  # pragma: no cover

    def _take_queued(self, free: int) -> list[Request]:
        """Take queued requests from the front, in order, while they fit ``free`` bytes."""
        taken: list[Request] = []
        queue = self._queue
        while queue and queue[0].datagram.size <= free:
            r = queue.popleft()
            free -= r.datagram.size
            taken.append(r)
        return taken

    def _register(self, entry: _InFlight, raw: bytes, count: int) -> bytes:
        for r in entry.requests:
            r.attempts += 1
        self._in_flight[entry.index] = entry
        stats = self.stats
        stats.frames_sent += 1
        stats.datagrams_sent += count
        return raw

    def _extend(self, template: CyclicTemplate, carried: list[Request], idx: int,
                sent: list[Datagram]) -> bytes:
        """The template's frame with ``carried`` appended (their datagrams go to ``sent``)."""
        buf = bytearray(template.frame[:template.end])
        # The last cyclic datagram now has followers.
        buf[template.last_header + 7] |= MORE_BIT >> 8
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

    # -- time -------------------------------------------------------------------------

    def expire(self, now: float, *, everything: bool = False) -> bool:
        """Handle frames whose deadline passed: requeue their requests or fail them.

        Returns whether anything changed. ``everything`` expires every frame
        in flight whatever its deadline.
        """
        expired = [f for f in self._in_flight.values() if everything or f.deadline <= now]
        if not expired:
            return False
        requeue: list[Request] = []
        stats = self.stats
        red = self.redundancy
        for f in expired:
            if red is not None and f.copies is not None and not everything:
                # A ring frame with fewer copies back than awaited: what came may do.
                out = red.expired(f.copies, f.sent)
                if out is not None:
                    self._deliver(out, now)
                    if self._in_flight.get(f.index) is not f:
                        continue
            del self._in_flight[f.index]
            stats.frames_lost += 1
            if f.cyclic is not None:
                f.cyclic.lost = True
            for r in f.requests:
                if r.done():
                    continue
                if r.attempts <= r.retries:
                    stats.retries += 1
                    requeue.append(r)
                else:
                    stats.timeouts += 1
                    r.error = EcTimeoutError(
                        f"no reply to {describe_datagram(r.datagram)} after {r.attempts} "
                        f"attempt{'s' if r.attempts != 1 else ''} "
                        f"({f.deadline - f.sent_at:.3g} s each) on {self.name}")
        # Retried requests go first, in their original order, and are not held back.
        for r in reversed(requeue):
            r.queued_at = _NOT_HELD
            self._queue.appendleft(r)
        return True

    # -- receiving ----------------------------------------------------------------------

    def on_frame(self, raw: bytes, now: float, port: int = 0) -> bool:
        """Handle one received frame (on ``port`` of a ring); whether a request or ticket completed."""
        if self.drop_own_frames and raw[6:12] in self._own:
            self.stats.looped_back += 1
            return False
        if self.redundancy is not None:
            got = self._copy(raw, port)
            if got is None:
                return False
            raw = got
        return self._deliver(raw, now)

    def _deliver(self, raw: bytes, now: float) -> bool:
        """Match a reply (a ring's copies merged) to its frame in flight."""
        if len(raw) > _FIRST_INDEX_AT + 4 and raw[12] == _ETHERTYPE_HI and raw[13] == _ETHERTYPE_LO:
            entry = self._in_flight.get(raw[_FIRST_INDEX_AT])
            if entry is not None and entry.template is not None and \
                    self._complete_prepared(entry, raw, now):
                return True
        try:
            frame = decode_frame(raw)
        except NotEtherCATError:
            self.stats.foreign += 1
            return False
        except FrameError as exc:
            self.stats.malformed += 1
            idx = first_index(raw)
            entry = self._in_flight.pop(idx, None) if idx is not None else None
            if entry is None:
                return False
            self._fail_entry(entry, FrameError(
                f"malformed reply to frame {idx} on {self.name}: {exc}"), now)
            return True
        if frame.frame_type != FrameType.DATAGRAMS or not frame.datagrams:
            self.stats.foreign += 1
            return False
        idx = frame.datagrams[0].index
        entry = self._in_flight.get(idx)
        if entry is None:
            if idx in self._answered:
                self.stats.duplicates += 1
            else:
                self.stats.stale += 1
            return False
        if entry.template is not None:
            # A prepared frame whose reply failed the quick check: compare in full.
            entry.datagrams = decode_frame(entry.sent).datagrams
        problem = _reply_mismatch(entry, frame.datagrams)
        if problem is not None:
            if problem[0]:
                # Another frame's reply that happens to carry this index: not ours.
                self.stats.stale += 1
                return False
            del self._in_flight[idx]
            self.stats.malformed += 1
            self._fail_entry(entry, FrameError(
                f"reply to frame {idx} on {self.name} does not match: {problem[1]}"), now)
            return True
        self._complete(entry, frame.datagrams, raw, now)
        return True

    def _complete(self, entry: _InFlight, got: list[Datagram], raw: bytes, now: float) -> None:
        """Hand a matched reply out (a ring's copies were merged before this)."""
        del self._in_flight[entry.index]
        if entry.copies is not None:
            hand_copies(entry.copies, entry.cyclic, entry.requests)
        self._answered.append(entry.index)
        self.stats.frames_received += 1
        ncyc = entry.cyclic.count if entry.cyclic is not None else 0
        for r, d in zip(entry.requests, got[ncyc:], strict=True):
            if not r.done():
                r.reply = d
        if entry.cyclic is not None:
            entry.cyclic.replies = got[:ncyc]
            entry.cyclic.received_at = now
            entry.cyclic.raw = untagged(raw)

    def _complete_prepared(self, entry: _InFlight, raw: bytes, now: float) -> bool:
        """Accept the reply to a prepared frame by its bytes; False: let the full path judge."""
        template = entry.template
        assert template is not None
        sent = entry.sent
        if len(raw) < template.end or raw[_ECAT_AT] != sent[_ECAT_AT] or \
                raw[_ECAT_AT + 1] != sent[_ECAT_AT + 1]:
            return False
        idx = entry.index
        for h, cmd, lo, address, length in template.checks:
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
            if _reply_mismatch(entry, got) is not None:
                return False
            for r, d in zip(entry.requests, got, strict=True):
                if not r.done():
                    r.reply = d
        del self._in_flight[idx]
        self._answered.append(idx)
        self.stats.frames_received += 1
        if entry.copies is not None:
            hand_copies(entry.copies, entry.cyclic, entry.requests)
        ticket = entry.cyclic
        assert ticket is not None
        ticket.raw = raw
        ticket.received_at = now
        return True

    def _fail_entry(self, entry: _InFlight, err: EtherCATError, now: float) -> None:
        for r in entry.requests:
            if not r.done():
                r.error = err
        if entry.cyclic is not None:
            entry.cyclic.lost = True
            entry.cyclic.error = err
            entry.cyclic.received_at = now

    # -- closing ----------------------------------------------------------------------

    def close(self) -> None:
        """Fail everything pending; further submits raise :class:`LinkError`. Idempotent."""
        if self._closed is not None:
            return
        err = self._closed = LinkError(f"scheduler on {self.name} is closed")
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


def _reply_mismatch(entry: _InFlight, got: list[Datagram]) -> tuple[bool, str] | None:
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
