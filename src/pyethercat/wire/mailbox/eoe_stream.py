"""EoE frame streams, sans-IO: Ethernet frames in, mailbox payloads out, and back.

Both ends of an EoE link (the master's client and a simulated slave) use the
same two state machines; neither does I/O or keeps a clock (``now`` comes
from the caller, in seconds).

:class:`EoeSender` queues whole Ethernet frames and hands out one fragment
payload at a time (the EoE header and up to one mailbox of data). The caller
sends it and calls :meth:`EoeSender.taken` once the peer has it (the SM0
write had working counter 1, or SM1 was read); until then
:meth:`EoeSender.current` returns the same bytes, so a refused or lost write
is repeated unchanged. Fragmentation follows the rules every public stack
uses (IgH ``master/ethernet.c`` ``ec_eoe_send``, SOEM ``src/ec_eoe.c``
``ecx_EOEsend``): every fragment but the last carries a multiple of 32 bytes
(``(mailbox size - 10) // 32 * 32``), fragment 0 announces the frame size in
32-byte blocks (rounded up), later fragments their byte offset / 32; the
frame number counts frames modulo 16. A frame whose fragments are not taken
within ``timeout`` seconds is dropped (a slave that stopped reading its
mailbox must not stall the queue forever).

:class:`EoeReceiver` rebuilds frames from fragments with the shared
:class:`~pyethercat.wire.mailbox.eoe.EoeReassembler` and adds what a frame
must satisfy before it is handed on, so that no damaged frame is ever
delivered:

- fragment, frame number and byte offset continue the frame in progress
  (IgH ``ec_eoe_state_rx_fetch_data``, SOES ``EOE_receive_fragment``);
- a fragment that is not the last carries a multiple of 32 bytes;
- the frame ends with the size fragment 0 announced: the block count equals
  ``ceil(size / 32)``, or ``size / 32 + 1`` for a size that is a multiple of
  32 (IgH's sender announces one block more there);
- the frame holds at least an Ethernet header, and no less than its own IPv4,
  IPv6 or ARP header says (a last fragment cut short inside its final
  32-byte block is invisible to the EoE header; the IP length shows it);
- a frame not finished within ``timeout`` seconds is discarded.

Anything else discards the frame in progress and counts an error.
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.eoe import (
    EOE_BLOCK,
    EOE_HEADER_SIZE,
    EoeFragment,
    EoeReassembler,
    decode_eoe,
    eoe_fragment,
)

__all__ = [
    "DEFAULT_EOE_TIMEOUT",
    "DEFAULT_QUEUE_LIMIT",
    "ETH_HEADER",
    "EoeDirectionStats",
    "EoeReceiver",
    "EoeSender",
    "frame_length_ok",
]

#: Seconds a frame may take to cross (all its fragments) before it is dropped.
DEFAULT_EOE_TIMEOUT = 1.0
#: Frames an :class:`EoeSender` queues before it drops new ones.
DEFAULT_QUEUE_LIMIT = 64
#: Bytes of an Ethernet header (destination, source, EtherType).
ETH_HEADER = 14
#: Largest Ethernet frame EoE carries here (MTU 1500, header, one VLAN tag).
MAX_ETH_FRAME = 1518

_ETHERTYPE_VLAN = 0x8100
_ETHERTYPE_IPV4 = 0x0800
_ETHERTYPE_IPV6 = 0x86DD
_ETHERTYPE_ARP = 0x0806
_ARP_SIZE = 28
_IPV6_HEADER = 40


@dataclass
class EoeDirectionStats:
    """Counters of one direction of an EoE link (monotonic)."""

    frames: int = 0
    bytes: int = 0
    fragments: int = 0
    #: Frames given up: queue full, time-out, or (receiving) discarded as damaged.
    dropped: int = 0
    #: Fragments that broke the rules (receiving) or payloads that could not be built.
    errors: int = 0
    #: Frames dropped because they did not complete in time.
    timeouts: int = 0


def frame_length_ok(frame: bytes) -> bool:
    """Whether ``frame`` is at least as long as its own network header says.

    IPv4 (total length), IPv6 (payload length + 40) and ARP (28 bytes) are
    checked, behind one optional VLAN tag; other EtherTypes only need the
    Ethernet header.
    """
    if len(frame) < ETH_HEADER:
        return False
    at = 12
    ethertype = (frame[at] << 8) | frame[at + 1]
    if ethertype == _ETHERTYPE_VLAN:
        at += 4
        if len(frame) < at + 2:
            return False
        ethertype = (frame[at] << 8) | frame[at + 1]
    body = at + 2
    if ethertype == _ETHERTYPE_IPV4:
        if len(frame) < body + 20:
            return False
        return len(frame) >= body + ((frame[body + 2] << 8) | frame[body + 3])
    if ethertype == _ETHERTYPE_IPV6:
        if len(frame) < body + _IPV6_HEADER:
            return False
        return len(frame) >= body + _IPV6_HEADER + ((frame[body + 4] << 8) | frame[body + 5])
    if ethertype == _ETHERTYPE_ARP:
        return len(frame) >= body + _ARP_SIZE
    return True


class EoeSender:
    """Ethernet frames to EoE fragment payloads for one mailbox (see the module text).

    ``mailbox_size`` is the receiving SM's length (the whole mailbox, header
    included); ``port`` the EoE port field of every fragment.
    """

    def __init__(self, mailbox_size: int, *, port: int = 0,
                 queue_limit: int = DEFAULT_QUEUE_LIMIT,
                 timeout: float = DEFAULT_EOE_TIMEOUT) -> None:
        # A mailbox too small for one fragment (slaves without EoE may have 40 bytes; the
        # master makes an EoE client for every mailbox) is no error here: every frame
        # pushed is dropped and counted as an error when its turn comes.
        self.mailbox_size = mailbox_size
        self.port = port
        self.queue_limit = queue_limit
        self.timeout = timeout
        self.stats = EoeDirectionStats()
        self._queue: deque[tuple[bytes, float, bool, int | None]] = deque()
        self._parts: list[bytes] = []
        self._next = 0
        self._started = 0.0
        self._size = 0
        self._frame_number = 15  # the first frame gets number 0

    @property
    def queued(self) -> int:
        """Frames waiting, the one being sent included."""
        return len(self._queue) + (1 if self._parts else 0)

    @property
    def busy(self) -> bool:
        """Whether a fragment is waiting to be sent."""
        return bool(self._parts) or bool(self._queue)

    @property
    def room(self) -> bool:
        """Whether :meth:`push` would accept another frame."""
        return len(self._queue) < self.queue_limit

    def push(self, frame: bytes, now: float, *, request_time: bool = False,
             timestamp: int | None = None) -> bool:
        """Queue one Ethernet frame; False (and counted as dropped) when it cannot go.

        ``request_time`` sets the time-request flag (the slave answers with a
        timestamp response); ``timestamp`` is appended to the last fragment
        (the time-appended flag).
        """
        if not ETH_HEADER <= len(frame) <= MAX_ETH_FRAME or len(self._queue) >= self.queue_limit:
            self.stats.dropped += 1
            return False
        self._queue.append((bytes(frame), now, request_time, timestamp))
        return True

    def current(self, now: float) -> bytes | None:
        """The fragment payload to send now (the same until :meth:`taken`), or None."""
        if self._parts and now - self._started > self.timeout:
            self._give_up(timeout=True)
        while not self._parts and self._queue:
            frame, queued, request_time, timestamp = self._queue.popleft()
            if now - queued > self.timeout:
                self.stats.dropped += 1
                self.stats.timeouts += 1
                continue
            self._frame_number = (self._frame_number + 1) & 0xF
            try:
                frags = eoe_fragment(frame, self.mailbox_size, self._frame_number,
                                     port=self.port, timestamp=timestamp)
            except MailboxError:
                self.stats.dropped += 1
                self.stats.errors += 1
                continue
            if request_time:
                last = frags[-1]
                frags[-1] = EoeFragment(last.data, last.fragment_number, last.offset,
                                        last.frame_number, True, last.port, last.timestamp,
                                        time_requested=True)
            self._parts = [f.encode() for f in frags]
            self._next = 0
            self._started = now
            self._size = len(frame)
        return self._parts[self._next] if self._parts else None

    def taken(self) -> None:
        """The peer has the current fragment: move on (a frame is done after its last)."""
        if not self._parts:
            return
        self.stats.fragments += 1
        self._next += 1
        if self._next == len(self._parts):
            self.stats.frames += 1
            self.stats.bytes += self._size
            self._parts = []

    def clear(self) -> None:
        """Drop everything queued (the peer went away); counted as dropped."""
        if self._parts:
            self._give_up(timeout=False)
        self.stats.dropped += len(self._queue)
        self._queue.clear()

    def _give_up(self, *, timeout: bool) -> None:
        self._parts = []
        self.stats.dropped += 1
        if timeout:
            self.stats.timeouts += 1


class EoeReceiver:
    """EoE fragments to whole, checked Ethernet frames (see the module text)."""

    def __init__(self, *, timeout: float = DEFAULT_EOE_TIMEOUT) -> None:
        self.timeout = timeout
        self.stats = EoeDirectionStats()
        #: Timestamp appended to the last frame delivered (None: none appended).
        self.timestamp: int | None = None
        #: Whether the last frame delivered carried the time-request flag.
        self.time_requested = False
        #: Why the last frame was discarded (for logs).
        self.last_error = ""
        self._reassembler = EoeReassembler()
        self._announced = 0
        self._started = 0.0

    @property
    def in_progress(self) -> bool:
        """True while a frame is partly received."""
        return self._reassembler.in_progress

    def expire(self, now: float) -> bool:
        """Discard a frame that did not finish within the time-out; True if one was."""
        if self._reassembler.in_progress and now - self._started > self.timeout:
            self._reassembler.reset()
            self.stats.dropped += 1
            self.stats.timeouts += 1
            self.last_error = f"frame incomplete after {self.timeout:g} s"
            return True
        return False

    def feed(self, fragment: EoeFragment, now: float) -> bytes | None:
        """Add one fragment; the checked frame after its last fragment, else None."""
        self.expire(now)
        self.stats.fragments += 1
        first = fragment.fragment_number == 0
        if first:
            if self._reassembler.in_progress:
                self.stats.dropped += 1  # superseded by a new frame
                self.last_error = "frame superseded by the next one's first fragment"
            self._announced = fragment.offset
            self._started = now
        active = first or self._reassembler.in_progress
        if not fragment.last and len(fragment.data) % EOE_BLOCK:
            return self._discard(active, f"fragment {fragment.fragment_number} of "
                                 f"{len(fragment.data)} bytes is not the last and not a "
                                 f"multiple of {EOE_BLOCK}")
        try:
            frame = self._reassembler.feed(fragment)
        except MailboxError as exc:
            return self._discard(active, str(exc))
        if frame is None:
            return None
        size = len(frame)
        blocks = -(-size // EOE_BLOCK)
        if not (self._announced == blocks
                or (size % EOE_BLOCK == 0 and self._announced == blocks + 1)):
            return self._discard(True, f"frame of {size} bytes, fragment 0 announced "
                                 f"{self._announced} blocks of {EOE_BLOCK}")
        if not frame_length_ok(frame):
            return self._discard(True, f"frame of {size} bytes is shorter than its headers say")
        self.timestamp = fragment.timestamp
        self.time_requested = fragment.time_requested
        self.stats.frames += 1
        self.stats.bytes += size
        return frame

    def feed_payload(self, payload: bytes, now: float) -> bytes | None:
        """Like :meth:`feed` for an EoE mailbox payload of frame type 0 (a fragment)."""
        try:
            fragment = _decode_fragment(payload)
        except MailboxError as exc:
            self.stats.fragments += 1
            return self._discard(self._reassembler.in_progress, str(exc))
        return self.feed(fragment, now)

    def _discard(self, active: bool, why: str) -> bytes | None:
        """Count a broken fragment; ``active``: a frame in progress is lost with it."""
        self._reassembler.reset()
        self.stats.errors += 1
        if active:
            self.stats.dropped += 1
        self.last_error = why
        return None  # so callers can ``return self._discard(...)``


def _decode_fragment(payload: bytes) -> EoeFragment:
    if len(payload) < EOE_HEADER_SIZE:
        raise MailboxError(f"EoE header needs {EOE_HEADER_SIZE} bytes, got {len(payload)}")
    if struct.unpack_from("<H", payload, 0)[0] & 0xF:
        raise MailboxError("EoE payload is not a fragment")
    msg = decode_eoe(payload)
    assert isinstance(msg, EoeFragment)
    return msg
