"""The ring service of a master: port state, fault localisation, fault events.

``master.ring`` (:class:`RingService`) answers "where is the fault?" for a
ring (two master ports, cable redundancy) and for a plain line or tree:

- :meth:`RingService.ports`: each master port's state (carrier, whether
  frames come back on it, frames sent/received/passed on, copies missing);
- :meth:`RingService.diagnose`: one multiple read of DL status (0x0110) and
  the error counters (0x0300-0x0313) of every slave, sent on both ports;
  which copy each answer came back in says from which side each slave is
  reached, and ``master.locate`` turns that, the DL status and the
  lost-link and CRC counters into :class:`~pyethercat.master.locate.Fault`
  objects ("between slave 4 port 1 and slave 5 port 0");
- :meth:`RingService.start_diagnosis` does the same without blocking (its
  requests ride in cyclic frames), for the cyclic monitor;
- every fault found or gone is a :class:`FaultEvent` (``events``, and the
  callbacks given to :meth:`RingService.subscribe`).

The cabling is learnt from the scan (:meth:`RingService.learn`, called
after every scan): a fault found later is named by the cables the ring had
then.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pyethercat.master import diag
from pyethercat.master.locate import (
    MASTER,
    Cable,
    End,
    Fault,
    SlaveReading,
    cables_of,
    crc_faults,
    locate,
)
from pyethercat.master.redundancy import PORT_NAMES
from pyethercat.master.scheduler import Request, Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram

__all__ = ["Diagnosis", "FaultBoard", "FaultEvent", "PendingDiagnosis", "PortStatus",
           "RingService"]

_DL = 2  # bytes of DL status
_AL = 6  # AL status, reserved, AL status code
_log = logging.getLogger("pyethercat.master")


@dataclass(frozen=True, slots=True)
class PortStatus:
    """One master port (A or B) as the PDU core sees it."""

    name: str
    carrier: bool | None
    returning: bool
    sent: int
    received: int
    forwarded: int
    missing: int
    #: Frames in a row whose copy on this port was missing while another copy came back
    #: (a port is given up after ``Redundancy.give_up_after`` of them).
    misses: int = 0

    @property
    def text(self) -> str:
        link = {True: "carrier", False: "NO CARRIER", None: "carrier unknown"}[self.carrier]
        back = ("frames come back" if self.returning and self.carrier is not False
                else "NO FRAMES BACK")
        row = f" ({self.misses} in a row)" if self.misses else ""
        return (f"port {self.name}: {link}, {back}; sent {self.sent}, received {self.received}, "
                f"passed on {self.forwarded}, copies missing {self.missing}{row}")


#: How a fault event's line begins (:attr:`FaultEvent.text`; :class:`FaultBoard` reads it).
_FOUND, _CLEARED = "fault: ", "cleared: "


@dataclass(frozen=True)
class FaultEvent:
    """A fault found (``cleared`` False) or gone (True); ``time_ns`` on the service's clock."""

    fault: Fault
    cleared: bool
    time_ns: int

    @property
    def text(self) -> str:
        return (_CLEARED if self.cleared else _FOUND) + self.fault.kind + " " + self.fault.text


class FaultBoard:
    """The faults standing now, kept from a loop's event lines (:attr:`FaultEvent.text`).

    A fault stays on the board until its ``cleared:`` line comes, however many
    other lines scroll past in the meantime; the lines may come from this
    process's ring watch or from an isolated engine's (they carry text only).
    """

    def __init__(self) -> None:
        self._standing: dict[str, str] = {}

    def take(self, line: str) -> None:
        """Note one event line (lines that are not fault events are ignored)."""
        if line.startswith(_FOUND):
            what = line[len(_FOUND):]
            self._standing[_place(what)] = what
        elif line.startswith(_CLEARED):
            self._standing.pop(_place(line[len(_CLEARED):]), None)

    @property
    def lines(self) -> list[str]:
        """The standing faults, oldest first (``cut between slave 2 port 1 and ...``)."""
        return list(self._standing.values())


def _place(what: str) -> str:
    # "kind where (detail)": a fault is the same fault while its kind and place are,
    # whatever its detail says (the ring service keys faults by place too).
    return what.split(" (", 1)[0]


@dataclass
class Diagnosis:
    """What one diagnosis found (see :meth:`RingService.diagnose`)."""

    ring: bool
    state: str
    ports: tuple[PortStatus, ...]
    readings: tuple[SlaveReading, ...]
    faults: tuple[Fault, ...]
    #: Master ports that brought copies back during the reading.
    returned: tuple[str, ...] = ()
    names: dict[int, str] = field(default_factory=dict)
    #: Per slave: the ports with a cable (as the scan found them).
    cabled: dict[int, tuple[int, ...]] = field(default_factory=dict)
    #: Slaves that answer a broadcast (present, whether their address answers or not).
    present: int | None = None
    #: False when no reading showed which side it came from (a ring read in frames
    #: sent one way round only): the faults are then not ring faults.
    sides_known: bool = True

    @property
    def unaddressed(self) -> int:
        """Slaves present that do not answer at a known station address (power-cycled, swapped)."""
        answered = sum(r.side is not None for r in self.readings)
        return max(0, (self.present or 0) - answered)

    @property
    def ring_state(self) -> str:
        """``closed``, ``open`` (split: both halves reached), ``port A only``/``port B only``."""
        sides = {r.side for r in self.readings} - {None}
        if sides == {"A", "B"}:
            return "open: reached from both ports"
        if len(self.returned) == 1 and self.returned[0] in sides:
            return f"open: reached from port {self.returned[0]} only"
        return "closed"

    @property
    def ok(self) -> bool:
        return not self.faults

    def format(self) -> list[str]:
        """The report ``pyethercat diag`` prints."""
        out = []
        if self.ring:
            out.append(f"ring: {self.ring_state}")
            out.extend("  " + p.text for p in self.ports)
        else:
            out.append("line (one master port)")
        out.append("slaves (side: the master port each is reached from):")
        for r in self.readings:
            name = self.names.get(r.position, "")
            side = {"A": "from A", "B": "from B", None: "NO ANSWER"}[r.side]
            links = ""
            if r.dl_status is not None:
                dl = r.dl_status
                ports = self.cabled.get(r.position) or tuple(
                    p for p in range(4) if dl & reg.dl_status_link(p))
                links = " ".join(f"p{p}:{'up' if dl & reg.dl_status_link(p) else 'DOWN'}"
                                 for p in ports)
            lost = ""
            if r.counters is not None:
                ll = [f"p{p}:{c.lost_links}" for p, c in enumerate(r.counters.ports) if c.lost_links]
                crc = [f"p{p}:{c.invalid_frames}/{c.rx_errors}/{c.forwarded_rx_errors}"
                       for p, c in enumerate(r.counters.ports)
                       if c.invalid_frames or c.rx_errors or c.forwarded_rx_errors]
                if ll:
                    lost += "  lost links " + " ".join(ll)
                if crc:
                    lost += "  crc/phy/fwd " + " ".join(crc)
            out.append(f"  {r.position:>3} {side:<9} {links:<22}{name}{lost}")
        if self.faults:
            out.append("faults:")
            out.extend(f"  {f.kind}: {f.text}" for f in self.faults)
        else:
            out.append("no fault found")
        return out


class PendingDiagnosis:
    """A diagnosis whose requests are on their way (:meth:`RingService.start_diagnosis`).

    A paced one queues its reads a slice at a time (:meth:`feed`, once per
    cycle): ``unsent`` are the datagrams not queued yet.
    """

    def __init__(self, service: RingService, datagrams: list[Datagram], positions: list[int],
                 al: bool) -> None:
        self._service = service
        #: The requests of the reads queued so far, in the order of the datagrams.
        self.requests: list[Request] = []
        self.positions = positions
        self.al = al
        self.unsent = datagrams

    def feed(self, budget: int | None, flush: bool = False) -> None:
        """Queue the next unsent reads, ``budget`` datagram bytes of them (at least one;
        None: all)."""
        unsent = self.unsent
        if not unsent:
            return
        take = len(unsent)
        if budget is not None:
            used = 0
            for i, d in enumerate(unsent):
                used += d.size
                if used > budget and i:
                    take = i
                    break
        part, self.unsent = unsent[:take], unsent[take:]
        self.requests.extend(self._service.scheduler.submit(part, flush=flush))

    def done(self) -> bool:
        return not self.unsent and all(r.done() for r in self.requests)

    def result(self) -> Diagnosis:
        """Wait for the requests (if needed) and evaluate them."""
        self.feed(None, flush=True)
        self._service.scheduler.wait(self.requests)
        return self._service.evaluate(self)


class RingService:
    """Port state, fault localisation and fault events (see the module text).

    ``slaves()`` gives the scanned slaves; ``now_ns`` the clock of the events.
    """

    def __init__(self, scheduler: Scheduler, slaves: Callable[[], Sequence[object]],
                 now_ns: Callable[[], int] | None = None) -> None:
        self.scheduler = scheduler
        self._slaves = slaves
        self.now_ns = now_ns or time.monotonic_ns
        #: The cables learnt from the last scan.
        self.cables: list[Cable] = []
        #: Faults found by the last diagnosis.
        self.faults: tuple[Fault, ...] = ()
        self.events: deque[FaultEvent] = deque(maxlen=500)
        self.last: Diagnosis | None = None
        #: Fault events so far (``events`` keeps the last 500).
        self.published = 0
        self._listeners: list[Callable[[FaultEvent], None]] = []
        self._counters: dict[int, diag.SlaveCounters] = {}
        #: Each slave's last error counters as read and as decoded: a reading in the
        #: cyclic loop's thread decodes only what changed (the decode was half of a
        #: reading's evaluation, 1 ms at 100 slaves; the counters seldom move).
        self._decoded: dict[int, tuple[bytes, diag.SlaveCounters]] = {}
        #: Cables that corrupted frames lately: (fault, when their counters last rose).
        self._crc: dict[str, tuple[Fault, int]] = {}
        #: How long a cable stays named after its CRC counters last rose.
        self.crc_hold_ns = 10_000_000_000
        self._lock = threading.Lock()

    # -- ports ------------------------------------------------------------------------

    @property
    def redundant(self) -> bool:
        """Whether the master has two ports (a ring)."""
        return self.scheduler.core.redundancy is not None

    def ports(self) -> tuple[PortStatus, ...]:
        """Both master ports of a ring (empty on a one-port master)."""
        red = self.scheduler.core.redundancy
        if red is None:
            return ()
        return tuple(PortStatus(PORT_NAMES[p], red.carrier[p], red.returns(p),
                                c.sent, c.received, c.forwarded, c.missing, red.misses[p])
                     for p, c in enumerate(red.counters))

    def state(self) -> str:
        """``redundant``, ``port A only``, ``port B only`` or ``line`` (one port)."""
        red = self.scheduler.core.redundancy
        return "line" if red is None else red.state()

    # -- cabling ----------------------------------------------------------------------

    @property
    def ring_end(self) -> End | None:
        """The (position, port) cabled to the master's second port (None: no ring)."""
        for c in self.cables:
            if (MASTER, 1) in c.ends():
                return c.other((MASTER, 1))
        return None

    def learn(self) -> None:
        """Take the cabling from the scanned slaves (after a scan)."""
        slaves = list(self._slaves())
        ring_end: End | None = None
        if self.redundant and slaves:
            last = max(slaves, key=lambda s: int(getattr(s, "position")))  # noqa: B009
            ports = getattr(last, "ports")  # noqa: B009
            free = [p for p in (1, 2, 3) if ports[p].implemented and ports[p].peer is None]
            linked = [p for p in free if ports[p].link]
            if linked or free:
                ring_end = (int(getattr(last, "position")), (linked or free)[0])  # noqa: B009
        self.cables = cables_of(slaves, ring_end)
        self._counters = {}
        self._decoded = {}
        self._crc = {}

    # -- diagnosis ----------------------------------------------------------------------

    def start_diagnosis(self, flush: bool = False, al: bool = False,
                        pace: int | None = None) -> PendingDiagnosis:
        """Queue the reads of a diagnosis (they ride in the next frames); see :meth:`diagnose`.

        ``al``: read AL status and code too (what the cyclic watch names state
        changes by; reading 0x0130 also clears the AL-status event). ``pace``:
        queue only that many datagram bytes now, the rest by
        :meth:`PendingDiagnosis.feed`."""
        slaves = list(self._slaves())
        # How many slaves answer at all (present, addressed or not).
        dgs: list[Datagram] = [Datagram.device(Command.BRD, 0, reg.TYPE, 1)]
        positions = []
        for s in slaves:
            st = int(getattr(s, "station_address"))  # noqa: B009
            positions.append(int(getattr(s, "position")))  # noqa: B009
            dgs.append(Datagram.device(Command.FPRD, st, reg.DL_STATUS, _DL))
            dgs.append(Datagram.device(Command.FPRD, st, reg.RX_ERROR_COUNTER,
                                       diag.ERROR_COUNTERS_SIZE))
            if al:
                dgs.append(Datagram.device(Command.FPRD, st, reg.AL_STATUS, _AL))
        pending = PendingDiagnosis(self, dgs, positions, al)
        pending.feed(pace, flush=flush)
        return pending

    def diagnose(self) -> Diagnosis:
        """Read every slave once and locate the faults (blocking; a few frames)."""
        return self.start_diagnosis(flush=True).result()

    def evaluate(self, pending: PendingDiagnosis) -> Diagnosis:
        """Turn the finished reads of a diagnosis into its result (and fault events)."""
        count_req, requests = pending.requests[0], pending.requests[1:]
        positions, stride = pending.positions, 3 if pending.al else 2
        ring = self.redundant
        red = self.scheduler.core.redundancy
        returned: set[int] = set()
        # Reads that rode in frames sent one way round (with an auto-increment datagram
        # of someone else's), came back twice on one port or lacked an awaited copy (a
        # late copy: the slaves only it reached would look gone) show no sides; one
        # such frame among the reading's makes the whole reading one without sides.
        answered = [r for r in requests if r.reply is not None]
        seen_sides = not ring or (bool(answered) and all(r.copies is not None for r in answered))
        a_worked = False
        for r in requests:
            if r.copies:
                returned.update(r.copies)
                got = r.copies.get(0)
                a_worked = a_worked or (got is not None and got.wkc > 0)
        readings: list[SlaveReading] = []
        counters: dict[int, diag.SlaveCounters] = {}
        a_returned = 0 in returned
        decoded = self._decoded
        for i, pos in enumerate(positions):
            dl_req, ctr_req = requests[stride * i], requests[stride * i + 1]
            side = _side(dl_req, ring, a_worked, a_returned)
            if side is None:
                side = _side(ctr_req, ring, a_worked, a_returned)
            dl = None
            if dl_req.reply is not None and dl_req.reply.wkc == 1:
                dl = int.from_bytes(dl_req.reply.data[:_DL], "little")
            ctr = None
            if ctr_req.reply is not None and ctr_req.reply.wkc == 1:
                raw = bytes(ctr_req.reply.data)
                known = decoded.get(pos)
                if known is not None and known[0] == raw:
                    ctr = known[1]
                else:
                    ctr = diag.decode_error_counters(pos, 0, raw)
                    decoded[pos] = (raw, ctr)
                counters[pos] = ctr
            al_status = al_code = None
            if pending.al:
                al_req = requests[stride * i + 2]
                if al_req.reply is not None and al_req.reply.wkc == 1:
                    data = bytes(al_req.reply.data)
                    al_status = int.from_bytes(data[0:2], "little")
                    al_code = int.from_bytes(data[4:6], "little")
            readings.append(SlaveReading(pos, side, dl, ctr, al_status, al_code))
        names = {int(getattr(s, "position")): str(getattr(s, "name", ""))  # noqa: B009
                 for s in self._slaves()}
        ret = tuple(PORT_NAMES[p] for p in sorted(returned)) if ring else ("A",)
        present = count_req.reply.wkc if count_req.reply is not None else None
        silent = [r.position for r in readings if r.side is None]
        unaddressed: list[int] = []
        if silent and present is not None and present >= len(positions):
            # Every slave answers a broadcast: the silent ones lost their address
            # (power-cycled, swapped); they are there, so the cables around them work.
            unaddressed = silent
        evidence = {} if red is None else {
            PORT_NAMES[p]: e for p in range(red.ports) if (e := red.evidence(p))}
        faults = locate(self.cables, [r for r in readings if r.position not in unaddressed],
                        ring=ring and seen_sides, returned=ret, port_evidence=evidence)
        faults += [Fault("unaddressed", f"slave {p}", slaves=(p,),
                         detail="present but silent at its station address: power-cycled or "
                                "replaced") for p in unaddressed]
        with self._lock:
            now = self.now_ns()
            # A cable stays named for crc_hold seconds after its counters last rose.
            for f in crc_faults(self.cables, counters, self._counters or None):
                self._crc[f.where] = (f, now)
            for where, (f, seen) in list(self._crc.items()):
                if now - seen > self.crc_hold_ns:
                    del self._crc[where]
                else:
                    faults.append(f)
            self._counters.update(counters)
        cabled: dict[int, set[int]] = {}
        for c in self.cables:
            for pos, port in c.ends():
                if pos >= 0:
                    cabled.setdefault(pos, set()).add(port)
        result = Diagnosis(ring, self.state(), self.ports(), tuple(readings), tuple(faults),
                           ret, names, {p: tuple(sorted(v)) for p, v in cabled.items()}, present,
                           seen_sides)
        if seen_sides:
            self._publish(result)
        return result

    # -- events -------------------------------------------------------------------------

    def subscribe(self, callback: Callable[[FaultEvent], None]) -> None:
        """Call ``callback(event)`` for every fault found or gone (from the thread that diagnosed)."""
        self._listeners.append(callback)

    def _publish(self, result: Diagnosis) -> None:
        now = self.now_ns()
        with self._lock:
            old = {f.where: f for f in self.faults}
            new = {f.where: f for f in result.faults}
            # A CRC fault stays until the counters stop rising (a diagnosis without it).
            events = [FaultEvent(f, False, now) for w, f in new.items() if w not in old]
            events += [FaultEvent(f, True, now) for w, f in old.items() if w not in new]
            self.faults = result.faults
            self.last = result
            self.events.extend(events)
            self.published += len(events)
        for ev in events:
            for fn in list(self._listeners):
                try:
                    fn(ev)
                except Exception:  # a subscriber's bug must not stop the diagnosis
                    _log.exception("fault event callback %r failed", fn)


def _side(req: Request, ring: bool, a_worked: bool, a_returned: bool) -> str | None:
    """The master port a slave's answer shows it is reached from (see ``master.locate``):
    the port the copy it answered in was sent on (round a closed ring the copy sent on
    A comes back on B; at a break each copy comes back on its own port)."""
    if req.reply is None:
        return None
    copies = req.copies
    if not ring or copies is None:
        return "A" if req.reply.wkc >= 1 else None
    origin = getattr(copies, "origin", None)
    if origin:
        for port in sorted(copies):
            if copies[port].wkc >= 1:
                return PORT_NAMES[origin.get(port, port)]
        return None
    # The medium does not carry the mark of the port a copy was sent on (UDP): a copy
    # back on A with answers looped at a break; one back on B went round a whole ring
    # (then A brought the other copy back untouched) or looped at a break on B's side.
    a, b = copies.get(0), copies.get(1)
    if a is not None and a.wkc >= 1:
        return "A"
    if b is not None and b.wkc >= 1:
        return "B" if a_worked or not a_returned else "A"
    return None
