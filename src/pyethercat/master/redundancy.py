"""Cable redundancy in the PDU core: where a frame goes, and how its two copies become one.

A ring: the master's port A feeds the first slave, port B the last slave's
free port. This module is pure (bytes and port numbers in, decisions out);
:class:`~pyethercat.master.pdu.PduCore` asks it, the scheduler does the I/O
on :class:`~pyethercat.link.redundant.RedundantLink`.

Routing (the rules of a ring master with ports A and B, as in SOEM's
``ecx_outframe_red``/``ecx_waitinframe_red`` and KickCAT's ``Link``):

- most frames go out on both ports at once ("both"). Every slave processes
  exactly one copy: in an intact ring the copy sent on A passes every
  processing unit and comes back on B, the copy sent on B travels backwards
  through ports that only forward and comes back on A untouched; with a
  broken cable or a dead node each copy is processed by the slaves on its
  side of the break and loops back to its own port; with port A or B dead
  the other copy goes round the whole ring and loops back at the far end.
  The copies are merged (:func:`merge_copies`), so nothing above sees two;
- frames whose effect depends on the order the slaves see them in
  (auto-increment addressing counts slaves from the first one that
  processes the copy; ARMW/FRMW carry the first reader's value to the
  writers behind it; cross traffic in the logical image) go out on one port
  only ("chain"): on A, and when they come back on A (the ring is broken)
  the returned frame is sent on through B, so the slaves behind the break
  process it next, in bus order; when port A is dead it goes out on B and
  comes back on B having passed every slave. This is SOEM's resend through
  the secondary port.

Merging, per datagram: the data is the sent data with every bit changed by
either copy (``S ^ ((A ^ S) | (B ^ S))``): a read ORs (a BRD's OR survives,
an FPRD answered on one side comes from that side), a logical read-write
takes each half's inputs from the copy whose slaves wrote them (outputs are
unchanged in both), writes are echoes; working counters are added, IRQ
fields ORed, and the ADP of auto-increment and broadcast datagrams grows by
both copies' increments. This is exact whenever every slave processed one
copy, which the ring guarantees for all but order-dependent datagrams (sent
"chain").

Which ports work ("returning") is learnt from the copies, with hysteresis:
a port is given up (no longer waited for) when its link says it has no
carrier, or when its copy missed :data:`GIVE_UP_AFTER` frames in a row
while another copy of each came back. One late copy is a busy host, not a
dead port: a frame handed out at its deadline with an awaited copy missing
is *partial* (:attr:`CopySet.partial`), costs that frame only, and its
copies say nothing about sides (diagnosis reads again). Any frame that
arrives on a port brings it back. Frames with no copy back at all (the
host stalled, or both cables are gone) give up neither port; they make
:meth:`Redundancy.state` say ``no port`` after as many in a row.

Two copies tell the core to wait for more than it planned: a copy that
went through no slave (working counters all 0) while it was the only one
awaited (the ring may have closed again: the processed copy comes on the
other port), and a copy that came back on the port it was sent on (the
ring is open: the slaves behind the break are served by the other port's
copy, so every port still returning is waited for).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from pyethercat.errors import FrameError
from pyethercat.wire.datagram import (
    HEADER_SIZE,
    LEN_MASK,
    MORE_BIT,
    WKC_SIZE,
    Command,
    Datagram,
)
from pyethercat.wire.frame import (
    ECAT_HEADER_SIZE,
    SECONDARY_MARK,
    NotEtherCATError,
    decode_frame,
    ecat_offset,
)

__all__ = [
    "PORT_A",
    "PORT_B",
    "PORT_NAMES",
    "GIVE_UP_AFTER",
    "CopySet",
    "CopiesRequest",
    "CopiesTicket",
    "MasterPortCounters",
    "PortCopies",
    "Redundancy",
    "copy_wkcs",
    "hand_copies",
    "merge_copies",
    "order_dependent",
    "mark_for_port",
    "ring_gap",
    "sent_on",
    "split_counts",
    "ordered_command",
]

PORT_A = 0
PORT_B = 1
PORT_NAMES = ("A", "B")
#: Frames in a row whose copy on a port must be missing (while another copy came back)
#: before the port is given up (see the module text).
GIVE_UP_AFTER = 3

#: Commands whose result depends on which slaves processed the frame before.
_ORDERED = frozenset({int(Command.APRD), int(Command.APWR), int(Command.APRW), int(Command.ARMW),
                      int(Command.FRMW)})
#: Commands whose ADP every processing slave increments.
_ADP_GROWS = frozenset({int(Command.APRD), int(Command.APWR), int(Command.APRW),
                        int(Command.ARMW), int(Command.BRD), int(Command.BWR), int(Command.BRW)})
#: Frame offset of bytes 2-3 of the source MAC (the mark of a copy sent on port B).
_MARK_AT = 8
_HEAD = struct.Struct("<BBHHHH")  # cmd, idx, adp, ado, length word, irq
_U16 = struct.Struct("<H")


def _datagram_offsets(frame: bytes | bytearray) -> list[tuple[int, int, int]]:
    """(header offset, command, data length) of every datagram; [] when malformed."""
    start = ecat_offset(frame)
    if start is None:
        return []
    end = start + ECAT_HEADER_SIZE + (_U16.unpack_from(frame, start)[0] & LEN_MASK)
    if end > len(frame):
        return []
    out: list[tuple[int, int, int]] = []
    at = start + ECAT_HEADER_SIZE
    while at + HEADER_SIZE + WKC_SIZE <= end:
        cmd = frame[at]
        word = frame[at + 6] | (frame[at + 7] << 8)
        n = word & LEN_MASK
        if at + HEADER_SIZE + n + WKC_SIZE > end:
            return []
        out.append((at, cmd, n))
        at += HEADER_SIZE + n + WKC_SIZE
        if not word & MORE_BIT:
            break
    return out


def ordered_command(command: int) -> bool:
    """Whether a datagram of this command must pass the slaves in bus order (sent "chain")."""
    return command in _ORDERED


def order_dependent(frame: bytes | bytearray) -> bool:
    """Whether a frame carries a datagram that must pass the slaves in bus order (sent "chain")."""
    return any(cmd in _ORDERED for _, cmd, _ in _datagram_offsets(frame))


def copy_wkcs(frame: bytes | bytearray) -> list[int]:
    """The working counter of every datagram of a frame, in order."""
    return [_U16.unpack_from(frame, at + HEADER_SIZE + n)[0]
            for at, _, n in _datagram_offsets(frame)]


def merge_copies(sent: bytes | bytearray, copies: Sequence[bytes | bytearray]) -> bytes | None:
    """One reply from the copies of a frame (see the module text); None if they do not fit.

    ``sent`` is the frame as sent; every copy must have its length.
    """
    if not copies:
        return None
    if len(copies) == 1:
        return bytes(copies[0])
    size = len(sent)
    if any(len(c) != size for c in copies):
        return None
    s = int.from_bytes(sent, "little")
    changed = 0
    for c in copies:
        changed |= int.from_bytes(c, "little") ^ s
    out = bytearray((s ^ changed).to_bytes(size, "little"))
    first = copies[0]
    start = ecat_offset(sent)
    if start is None:
        return None
    out[:start + ECAT_HEADER_SIZE] = first[:start + ECAT_HEADER_SIZE]
    for at, cmd, n in _datagram_offsets(sent):
        s_cmd, s_idx, s_adp, s_ado, s_word, s_irq = _HEAD.unpack_from(sent, at)
        heads = [_HEAD.unpack_from(c, at) for c in copies]
        adp = s_adp
        if cmd in _ADP_GROWS:
            adp = (s_adp + sum(h[2] - s_adp for h in heads)) & 0xFFFF
        irq = s_irq
        for h in heads:
            irq |= h[5]
        _HEAD.pack_into(out, at, s_cmd, s_idx, adp, s_ado, s_word, irq)
        w = at + HEADER_SIZE + n
        _U16.pack_into(out, w, sum(_U16.unpack_from(c, w)[0] for c in copies) & 0xFFFF)
    return bytes(out)


def mark_for_port(frame: bytes, port: int) -> bytes:
    """The copy of ``frame`` to send on ``port``: a copy for port B has
    ``SECONDARY_MARK`` XORed into bytes 2-3 of its source MAC, so a copy that
    comes back tells which port it was sent on.

    SOEM marks its secondary port's frames in the same word (``secMAC`` in
    ``ecx_outframe_red``); slaves change only bit 1 of the first source-MAC
    byte (the locally administered bit), never these two.
    """
    if port != PORT_B or len(frame) < _MARK_AT + 2:
        return frame
    mark = bytes((frame[_MARK_AT] ^ SECONDARY_MARK[0], frame[_MARK_AT + 1] ^ SECONDARY_MARK[1]))
    return b"".join((frame[:_MARK_AT], mark, frame[_MARK_AT + 2:]))


def sent_on(frame: bytes | bytearray, src: bytes) -> int:
    """The port a copy was sent on (see :func:`mark_for_port`); ``src`` is the master's MAC."""
    return PORT_A if frame[_MARK_AT:_MARK_AT + 2] == src[2:4] else PORT_B


def split_counts(copies: dict[int, bytes], at: int, src: bytes) -> tuple[int, int] | None:
    """One datagram's working counts from the slaves before and behind a break of the ring.

    ``copies`` are a frame's copies by the port they came back on, ``at`` the
    offset of the datagram's working counter. A copy that came back on the
    port it was sent on looped back at a break: sent on A, it passed the slaves
    from the first one up to the break; sent on B, those from the last one
    back to it. A copy sent on A that came back on B went round a closed ring
    (None: nothing to split); one sent on B that came back on A passed no
    processing unit (it counts nothing). Returns (count from the A side,
    count from the B side), or None when no copy looped back.
    """
    from_a = from_b = 0
    looped = False
    for port, frame in copies.items():
        origin = sent_on(frame, src)
        count = frame[at] | (frame[at + 1] << 8)
        if origin == port:
            looped = True
            if port == PORT_A:
                from_a = count
            else:
                from_b = count
        elif origin == PORT_A:
            return None  # round a closed ring: every slave had its turn
    return (from_a, from_b) if looped else None


def ring_gap(shares: Sequence[int], from_a: int, from_b: int) -> tuple[int, int] | None:
    """The slaves an open ring's two sides did not reach, from one datagram's counts.

    ``shares`` are what each slave of the datagram adds to its count, in bus
    order; ``from_a``/``from_b`` the counts of the copies that looped back at
    a break on the A side and on the B side (:func:`split_counts`). The A
    side's count is the sum of a prefix of ``shares``, the B side's of a
    suffix, when every slave a copy reached counted in (one fault at a time,
    as a ring is built for). Returns ``(lo, hi)``: ``shares[lo:hi]`` are the
    slaves neither side reached (a node switched off or unplugged), or None
    when the counts fit no prefix and suffix.
    """
    lo, total = 0, 0
    while lo < len(shares) and total + shares[lo] <= from_a:
        total += shares[lo]
        lo += 1
    if total != from_a:
        return None
    hi, total = len(shares), 0
    while hi > lo and total + shares[hi - 1] <= from_b:
        total += shares[hi - 1]
        hi -= 1
    if total != from_b:
        return None
    return lo, hi


def _worked(frame: bytes | bytearray) -> bool:
    """Whether any slave processed a datagram of this copy."""
    return any(copy_wkcs(frame))


def _origin(copy: bytes | bytearray, mark: bytes) -> int:
    """The port a copy was sent on; ``mark``: bytes 2-3 of the source MAC sent on A."""
    return PORT_A if copy[_MARK_AT:_MARK_AT + 2] == mark else PORT_B


class PortCopies(dict[int, Datagram]):
    """One datagram as each copy of its ring frame brought it back, by the port the copy came
    in on; ``origin[port]`` is the port that copy was sent on.

    A slave reached from port A answers in the copy sent on A, wherever that copy
    came back (on B round a closed ring, on A at a break), so the origin, not the
    port of arrival, is the side a slave is reached from. ``origin`` is empty
    where the medium does not carry the mark (``Redundancy.marks``)."""

    __slots__ = ("origin",)

    def __init__(self, origin: dict[int, int]) -> None:
        super().__init__()
        self.origin = origin


@dataclass(slots=True)
class CopySet:
    """The copies of one frame in flight (see :class:`Redundancy`)."""

    #: Sent on one port and passed on through the other when it comes back ("chain").
    chain: bool
    #: The port a chain frame was sent on.
    tx: int = PORT_A
    #: Ports whose copy completes a "both" frame; ``need0``: as planned at sending.
    need: set[int] = field(default_factory=set)
    need0: frozenset[int] = frozenset()
    #: Copies received, by the port they came in on.
    got: dict[int, bytes] = field(default_factory=dict)
    #: Bytes 2-3 of the source MAC of the copy sent on A, where copies keep it
    #: (``Redundancy.marks``; None: which port sent a copy cannot be told).
    mark: bytes | None = None
    #: A chain frame was sent on through the other port; ``held`` is what came back first.
    forwarded: bool = False
    held: bytes | None = None
    #: Both copies came back on one port: the ring changed while the frame was out, so
    #: the ports tell nothing about sides (the copies are merged all the same).
    disturbed: bool = False
    extra: list[bytes] = field(default_factory=list)
    #: Handed out at its deadline with a copy awaited missing (late, or its port just
    #: died): the copies that came tell nothing about sides or about who is missing.
    partial: bool = False


@dataclass(slots=True)
class MasterPortCounters:
    """What went through one master port (frames, not the slaves' error counters)."""

    sent: int = 0
    received: int = 0
    #: Frames passed on through this port after coming back on the other (chain).
    forwarded: int = 0
    #: Frames whose copy on this port did not come back by the deadline.
    missing: int = 0
    refused: int = 0


class Redundancy:
    """Port state and the routing decisions of a ring master (see the module text).

    ``carrier[p]`` is what the link says (None: it cannot tell);
    ``returning`` the ports counted on (not given up); ``misses[p]`` the
    frames in a row whose copy on port ``p`` was missing while another copy
    came back; ``silent`` the frames in a row with no copy back at all.
    """

    def __init__(self, ports: int = 2, give_up_after: int = GIVE_UP_AFTER) -> None:
        if give_up_after < 1:
            raise ValueError(f"give_up_after must be at least 1, not {give_up_after}")
        self.ports = ports
        self.give_up_after = give_up_after
        self.carrier: list[bool | None] = [None] * ports
        self.returning: set[int] = set(range(ports))
        self.misses = [0] * ports
        self.silent = 0
        #: Whether copies come back with the source MAC they were sent with (the mark of
        #: port B; None: not known yet): learnt from the first frame whose two copies came
        #: back on two ports. A medium that does not carry MACs (EtherCAT over UDP) gives
        #: every copy the same source, so which port sent a copy is unknown there.
        self.marks: bool | None = None
        self._mark: bytes | None = None
        self.counters = [MasterPortCounters() for _ in range(ports)]
        #: Frames whose copies were merged, completed with fewer copies than
        #: awaited (at their deadline), and chain frames passed on.
        self.merged = 0
        self.partial = 0
        self.forwards = 0

    def _alive(self) -> list[int]:
        return [p for p in range(self.ports) if self.carrier[p] is not False]

    def usable(self) -> list[int]:
        """Ports to count on now: with carrier (or unknown) and returning frames, A first."""
        alive = self._alive()
        ok = [p for p in alive if p in self.returning]
        return ok or alive or list(range(self.ports))

    def returns(self, port: int) -> bool:
        """Whether frames come back on ``port`` (as far as the master can tell)."""
        return (self.carrier[port] is not False and port in self.returning
                and self.silent < self.give_up_after)

    def state(self) -> str:
        """'redundant' (both ports work), 'port A only', 'port B only' or 'no port'."""
        ok = [p for p in range(self.ports) if self.returns(p)]
        if len(ok) == self.ports:
            return "redundant"
        if not ok:
            return "no port"
        return f"port {PORT_NAMES[ok[0]]} only"

    def evidence(self, port: int) -> str:
        """What the master itself saw of a dead port: no carrier, or copies missing in a row
        (empty: nothing; one late copy is no evidence)."""
        if self.carrier[port] is False:
            return f"port {PORT_NAMES[port]}: no carrier"
        n = self.misses[port]
        if n >= self.give_up_after:
            return f"no copy back on port {PORT_NAMES[port]} in {n} frames in a row"
        return ""

    def _miss(self, port: int) -> None:
        """A copy on ``port`` missed its frame's deadline while another copy came back."""
        self.misses[port] += 1
        if self.misses[port] >= self.give_up_after:
            self.returning.discard(port)

    # -- sending ----------------------------------------------------------------------

    def plan(self, frame: bytes | bytearray, ordered: bool | None = None) -> tuple[CopySet, list[int]]:
        """How to send ``frame``: its copy set and the ports to send it on now.

        ``ordered``: whether it must pass the slaves in bus order (None: look
        at its datagrams)."""
        usable = self.usable()
        if ordered if ordered is not None else order_dependent(frame):
            tx = usable[0]
            self.counters[tx].sent += 1
            return CopySet(True, tx), [tx]
        need = set(usable)
        # Probe the silent ports too: a copy coming back there brings them back.
        ports = self._alive() or list(range(self.ports))
        for p in ports:
            self.counters[p].sent += 1
        return CopySet(False, need=need, need0=frozenset(need),
                       mark=self._mark if self.marks else None), ports

    def refused(self, copies: CopySet, port: int) -> None:
        """The link refused to send on ``port`` (no carrier, interface down)."""
        self.counters[port].refused += 1
        self.carrier[port] = False
        copies.need.discard(port)

    # -- receiving ----------------------------------------------------------------------

    def seen(self, port: int) -> None:
        """A frame came in on ``port`` (any frame: the port works); the core calls this
        before :meth:`arrived`."""
        self.counters[port].received += 1
        self.returning.add(port)
        if self.misses[port]:
            self.misses[port] = 0
        if self.silent:
            self.silent = 0

    def arrived(self, copies: CopySet, port: int, raw: bytes,
                sent: bytes) -> tuple[str, bytes | None, int]:
        """A copy came in on ``port``: ('done', reply, -1), ('forward', frame, port) or ('wait', None, -1)."""
        self.returning.add(port)
        if copies.chain:
            if not copies.forwarded:
                other = PORT_B if port == PORT_A else PORT_A
                passed_on = (port == copies.tx and self.carrier[other] is not False
                             and other in self.returning)
                # Sent on B and back on A: it went round backwards, untouched, so A works.
                went_round_backwards = port != copies.tx and copies.tx == PORT_B
                if passed_on or went_round_backwards:
                    copies.forwarded = True
                    copies.held = raw if passed_on else None
                    self.forwards += 1
                    target = other if passed_on else PORT_A
                    self.counters[target].forwarded += 1
                    return "forward", raw, target
            return "done", raw, -1
        if port in copies.got:
            copies.disturbed = True
            copies.extra.append(raw)
        else:
            copies.got[port] = raw
            if self.marks is None and len(copies.got) == 2:
                # One copy was sent on each port: two marks, unless MACs are not carried.
                first, second = (c[_MARK_AT:_MARK_AT + 2] for c in copies.got.values())
                self.marks = first != second
                self._mark = bytes(sent[_MARK_AT:_MARK_AT + 2])
        if len(copies.need) == 1 and len(copies.got) == 1:
            # (with both ports awaited already, neither rule adds one)
            if not _worked(raw):
                # The only copy awaited went through no slave: the ring may be closed
                # again, so the processed copy comes on the other port.
                copies.need.update(self._alive())
            elif copies.mark is not None and _origin(raw, copies.mark) == port:
                # Back on the port it was sent on: the ring is open, the slaves behind
                # the break are served by the other ports' copies.
                copies.need.update(p for p in self._alive() if p in self.returning)
        if copies.need <= copies.got.keys():
            return "done", self._merge(sent, copies), -1
        return "wait", None, -1

    def expired(self, copies: CopySet, sent: bytes) -> bytes | None:
        """The frame's deadline passed: the reply to hand out, or None (lost)."""
        if copies.chain:
            if copies.forwarded:
                target = PORT_B if copies.tx == PORT_A else PORT_A
                self.counters[target].missing += 1
                self._miss(target)
            return copies.held
        missing = [p for p in copies.need if p not in copies.got]
        for p in missing:
            self.counters[p].missing += 1
        if not copies.got:
            # Nothing back at all: a host that stalled, or no port works; it says
            # nothing about one port.
            self.silent += 1
            return None
        for p in missing:
            self._miss(p)
        if not copies.need0 <= copies.got.keys() and not any(map(_worked, copies.got.values())):
            return None  # the copies that came went through no slave: nothing learnt
        self.partial += 1
        copies.partial = bool(missing)
        return self._merge(sent, copies)

    def _merge(self, sent: bytes, copies: CopySet) -> bytes | None:
        got = [*copies.got.values(), *copies.extra]
        if len(got) > 1:
            self.merged += 1
        return merge_copies(sent, got)


class CopiesTicket(Protocol):
    """A frame's ticket as :func:`hand_copies` fills it (``master.pdu.CyclicFrame``)."""

    #: Cyclic datagrams at the front of the frame (the requests' datagrams follow).
    count: int
    copies: dict[int, bytes] | None


class CopiesRequest(Protocol):
    """A datagram's request as :func:`hand_copies` fills it (``master.pdu.Request``)."""

    copies: dict[int, Datagram] | None


def hand_copies(copies: CopySet, ticket: CopiesTicket | None,
                requests: Sequence[CopiesRequest]) -> None:
    """Give a completed ring frame's ticket and requests its copies by port (for diagnostics).

    A chain frame passed every slave in one copy, a disturbed one came back twice on one
    port, a partial one lacks a copy that was awaited (the slaves only that copy reached
    would look gone): they tell nothing about sides, and get no copies."""
    if copies.chain or copies.disturbed or copies.partial:
        return
    got = dict(copies.got)
    if ticket is not None:
        ticket.copies = got
    if not requests:
        return
    ncyc = ticket.count if ticket is not None else 0
    mark = copies.mark
    origin = {} if mark is None else {p: _origin(c, mark) for p, c in got.items()}
    for port, c in got.items():
        try:
            dgs = decode_frame(c).datagrams[ncyc:]
        except (FrameError, NotEtherCATError):
            continue
        for r, d in zip(requests, dgs, strict=False):
            if r.copies is None:
                r.copies = PortCopies(origin)
            r.copies[port] = d
