"""Fault localisation: which cable, node or master port failed, from what the slaves answered.

Pure: the cabling known from a scan (:func:`cables_of`), one reading of
every slave (:class:`SlaveReading`: the side its answer came from, its DL
status 0x0110 and error counters 0x0300-0x0313) and the master's ports in,
:class:`Fault` objects out.

In a ring (ports A and B; ETG.1000.4 section 5.4 on frame forwarding):

- both copies of a frame come back and the copy received on A went through
  no slave: the ring is whole; the copy received on B has every answer;
- copies come back on both ports with answers in each: the ring is split.
  Slaves that answered in the copy received on A sit on A's side of the
  break, those in the copy received on B on B's side. A cable whose ends
  answered on different sides is the broken link; a slave answering on
  neither side whose neighbours answered on both is a failed node;
- only port B brings copies back, with every answer: port A's cable (or NIC)
  failed; the same the other way round. A master port is named only when
  something confirms it: the master's own evidence (no carrier, or no copy
  back on that port in several frames in a row; one late copy is a busy
  host) or the DL status of the slave port at the cable's far end (no
  link). A port whose copies go round the whole ring and come back on the
  other port, while none come back on it, is named the same way (its
  receive side failed); that needs the master's evidence.

On a line (one port) and in branches off the ring a cut leaves the slaves
behind it silent: the fault is on the cable into the silent part (or its
first slave failed: the two cannot be told apart from outside).

DL status says which ports lost their link (bits 4-7) and the lost-link
counters (0x0310 + port) which ports had a link and lost it; they confirm
the cable found from the sides and pick the port when the cabling is not
known. CRC errors (ESC datasheet section I, "Error counters"): the port
that receives a corrupted frame counts it as invalid (0x0300 + 2 * port),
every port after it on the frame's way counts a forwarded error (0x0308 +
port). A port whose invalid-frame counter rose therefore names the cable
plugged into it, in a tree as well as on a line.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from pyethercat.master.diag import SlaveCounters
from pyethercat.wire import registers as reg

__all__ = [
    "MASTER",
    "Cable",
    "End",
    "Fault",
    "SlaveReading",
    "cables_of",
    "crc_faults",
    "end_text",
    "locate",
]

#: Position of the master in an :data:`End` (its port: 0 = A, 1 = B).
MASTER = -1

#: One end of a cable: (slave position, port), or (MASTER, master port).
End = tuple[int, int]


@dataclass(frozen=True, slots=True)
class Cable:
    """A cable between two ports (the first end is the one nearer master port A)."""

    a: End
    b: End

    def ends(self) -> tuple[End, End]:
        return self.a, self.b

    def other(self, end: End) -> End:
        return self.b if end == self.a else self.a

    @property
    def text(self) -> str:
        return f"between {end_text(self.a)} and {end_text(self.b)}"


def end_text(end: End) -> str:
    """``slave 4 port 1``, or ``master port A``."""
    pos, port = end
    if pos == MASTER:
        return f"master port {'AB'[port] if port in (0, 1) else port}"
    return f"slave {pos} port {port}"


@dataclass(frozen=True)
class Fault:
    """A located fault.

    ``kind``: ``"link"`` (a broken cable between two slaves), ``"node"`` (a
    slave that stopped forwarding: off, removed), ``"port"`` (a master
    port's cable or NIC), ``"cut"`` (a cable on a line or branch, or the
    first slave behind it, with the slaves behind it silent), ``"crc"`` (a
    cable corrupting frames). ``where`` is the place in words, ``ends`` the
    cable's ends (for link, port, cut and crc faults), ``slaves`` the
    positions concerned (the failed node, the silent slaves).
    """

    kind: str
    where: str
    ends: tuple[End, ...] = ()
    slaves: tuple[int, ...] = ()
    detail: str = ""

    @property
    def text(self) -> str:
        return self.where + (f" ({self.detail})" if self.detail else "")

    def __str__(self) -> str:
        return self.text


@dataclass(frozen=True, slots=True)
class SlaveReading:
    """One slave as a diagnosis read it.

    ``side``: the master port its answer came back on, as the ring goes:
    ``"A"`` (reached from port A), ``"B"`` (from port B), None (no answer).
    """

    position: int
    side: str | None
    dl_status: int | None = None
    counters: SlaveCounters | None = None
    #: AL status (0x0130) and AL status code (0x0134), when read.
    al_status: int | None = None
    al_code: int | None = None


def cables_of(slaves: Iterable[object], ring_end: End | None = None) -> list[Cable]:
    """The cables of a scanned segment: master A to the first slave, each parent port to its
    child's port 0, and (a ring) ``ring_end`` to master port B.

    ``slaves`` are scanned slaves (``position``, ``parent``, ``parent_port``).
    """
    out: list[Cable] = []
    for s in slaves:
        pos = int(getattr(s, "position"))  # noqa: B009  (SlaveInfo or Slave)
        parent = getattr(s, "parent")  # noqa: B009
        if parent is None:
            if pos == 0:
                out.append(Cable((MASTER, 0), (0, 0)))
            continue
        out.append(Cable((int(getattr(parent, "position")), int(getattr(s, "parent_port") or 0)),  # noqa: B009
                         (pos, 0)))
    if ring_end is not None:
        out.append(Cable(ring_end, (MASTER, 1)))
    return out


def _link_down(reading: SlaveReading | None, port: int) -> bool | None:
    if reading is None or reading.dl_status is None:
        return None
    return not reading.dl_status & reg.dl_status_link(port)


def _lost(reading: SlaveReading | None, port: int) -> int:
    if reading is None or reading.counters is None:
        return 0
    return reading.counters.ports[port].lost_links


def _confirm(cable: Cable, readings: Mapping[int, SlaveReading]) -> str:
    """What DL status and lost-link counters say about a cable found from the sides."""
    notes = []
    for pos, port in cable.ends():
        if pos == MASTER:
            continue
        r = readings.get(pos)
        down = _link_down(r, port)
        if down is None:
            continue
        lost = _lost(r, port)
        notes.append(f"{end_text((pos, port))}: {'no link' if down else 'link up'}"
                     + (f", {lost} lost link{'s' if lost != 1 else ''}" if lost else ""))
    return "; ".join(notes)


def locate(cables: Sequence[Cable], readings: Sequence[SlaveReading], *, ring: bool,
           returned: Sequence[str], port_evidence: Mapping[str, str] | None = None,
           ) -> list[Fault]:
    """The faults the readings show (see the module text).

    ``returned``: the master ports copies came back on (``"A"``, ``"B"``);
    ``port_evidence``: per master port, what the master saw of it being dead
    (``"port A: no carrier"``; absent or empty: nothing).
    """
    by_pos = {r.position: r for r in readings}

    def side_of(end: End) -> str | None:
        pos, port = end
        if pos == MASTER:
            return "AB"[port] if port in (0, 1) else None
        r = by_pos.get(pos)
        return None if r is None else r.side

    faults: list[Fault] = []
    silent = sorted(r.position for r in readings if r.side is None)
    sides = {r.side for r in readings if r.side is not None}
    if ring:
        port_fault = None
        if not silent:
            port_fault = (_port_fault(0, cables, by_pos, sides, returned, port_evidence)
                          or _port_fault(1, cables, by_pos, sides, returned, port_evidence))
        if port_fault is not None:
            faults.append(port_fault)
        elif sides == {"A", "B"} and not silent:
            for c in cables:
                sa, sb = side_of(c.a), side_of(c.b)
                if MASTER in (c.a[0], c.b[0]):
                    continue
                if sa is not None and sb is not None and sa != sb:
                    faults.append(Fault("link", c.text, c.ends(), detail=_confirm(c, by_pos)))
    # Silent slaves: failed nodes (neighbours answered on both sides of a ring) or a cut.
    for group in _groups(silent, cables):
        around = [(c, end) for c in cables for end in c.ends()
                  if end[0] in group and c.other(end)[0] not in group]
        outside = {side_of(c.other(end)) for c, end in around}
        outside.discard(None)
        members = tuple(sorted(group))
        if ring and outside >= {"A", "B"}:
            # The member with neighbours on both sides of the ring failed (its
            # branches went silent with it); two or more such: several nodes.
            both = [p for p in members
                    if {side_of(c.other(e)) for c, e in around if e[0] == p} >= {"A", "B"}]
            ends = tuple(c.other(e) for c, e in around)
            down = "; ".join(f"{end_text(e)}: no link" for e in ends
                             if _link_down(by_pos.get(e[0]), e[1]))
            if len(both) == 1:
                rest = [p for p in members if p != both[0]]
                faults.append(Fault("node", f"slave {both[0]}", ends, members,
                                    detail="no answer" + (f"; {down}" if down else "")
                                    + (f"; slaves {_span(rest)} behind it silent" if rest else "")))
            else:
                faults.append(Fault("node", f"slaves {_span(members)}", ends, members,
                                    detail="no answer" + (f"; {down}" if down else "")))
            continue
        if not around:
            continue
        c, e = min(around, key=lambda ce: ce[1][0])
        first = e[0]
        faults.append(Fault("cut", f"{c.text} (or slave {first} failed)", c.ends(), members,
                            detail=f"slaves {_span(members)} silent"
                            + (f"; {_confirm(c, by_pos)}" if _confirm(c, by_pos) else "")))
    return faults


def _port_fault(port: int, cables: Sequence[Cable], by_pos: Mapping[int, SlaveReading],
                sides: set[str], returned: Sequence[str],
                evidence: Mapping[str, str] | None) -> Fault | None:
    """Master port ``port`` failed, if the readings show it and something confirms it."""
    name, other = "AB"[port], "BA"[port]
    if name in returned or other not in returned:
        return None
    seen = (evidence or {}).get(name, "")
    cable = next((c for c in cables if (MASTER, port) in c.ends()), None)
    if cable is None and port == 0:
        cable = Cable((MASTER, 0), (0, 0))
    far = cable.other((MASTER, port)) if cable is not None else None
    far_down = far is not None and bool(_link_down(by_pos.get(far[0]), far[1]))
    if sides <= {other}:
        # Every slave reached from the other port: this port's cable or NIC, if confirmed.
        if not (seen or far_down):
            return None
    elif not (sides <= {name} and seen):
        # (the copies this port sends go round and come back on the other: its receive)
        return None
    where = f"master port {name}" + (f" (its cable to {end_text(far)})" if far is not None else "")
    detail = "; ".join(x for x in (_confirm(cable, by_pos) if cable is not None else "", seen)
                       if x) or f"no frame back on port {name}"
    return Fault("port", where, cable.ends() if cable is not None else ((MASTER, port),),
                 detail=detail)


def _groups(silent: Sequence[int], cables: Sequence[Cable]) -> list[set[int]]:
    """Silent slaves grouped by the cables between them."""
    left = set(silent)
    groups: list[set[int]] = []
    while left:
        seed = left.pop()
        group = {seed}
        todo = [seed]
        while todo:
            p = todo.pop()
            for c in cables:
                for end in c.ends():
                    if end[0] == p:
                        q = c.other(end)[0]
                        if q in left:
                            left.discard(q)
                            group.add(q)
                            todo.append(q)
        groups.append(group)
    return groups


def _span(positions: Sequence[int]) -> str:
    ps = sorted(positions)
    if not ps:
        return ""
    if ps == list(range(ps[0], ps[-1] + 1)) and len(ps) > 2:
        return f"{ps[0]}-{ps[-1]}"
    return ", ".join(map(str, ps))


def crc_faults(cables: Sequence[Cable], now: Mapping[int, SlaveCounters],
               before: Mapping[int, SlaveCounters] | None = None) -> list[Fault]:
    """Cables whose receiving ports counted invalid frames or RX errors (since ``before``)."""
    rises: dict[End, int] = {}
    for pos, c in now.items():
        old = before.get(pos) if before is not None else None
        for port in range(4):
            p = c.ports[port]
            count = p.invalid_frames + p.rx_errors
            if old is not None:
                q = old.ports[port]
                count -= q.invalid_frames + q.rx_errors
            if count > 0:
                rises[(pos, port)] = count
    faults: list[Fault] = []
    done: set[End] = set()
    for end, count in sorted(rises.items()):
        if end in done:
            continue
        cable = next((c for c in cables if end in c.ends()), None)
        if cable is None:
            faults.append(Fault("crc", f"{end_text(end)} (the cable plugged into it)", (end,),
                                detail=f"{count} CRC error{'s' if count != 1 else ''}"))
            done.add(end)
            continue
        parts = []
        for e in cable.ends():
            n = rises.get(e, 0)
            done.add(e)
            if n:
                parts.append(f"{n} at {end_text(e)}")
        faults.append(Fault("crc", f"bad cable {cable.text}", cable.ends(),
                            detail="CRC errors: " + ", ".join(parts)))
    return faults

