"""Per-command rules of the node-addressed and broadcast datagrams.

The rules follow the command table of IEC 61158-4-12 (as gatorcat and
KickCAT ``EmulatedESC.cc`` implement it; Wireshark
``packet-ethercat-datagram.c`` names the commands):

- single-slave commands (APRD/APWR/APRW, FPRD/FPWR/FPRW) address one ESC,
  which applies its own access rules (``sim.esc``); APRW/FPRW read the old
  content into the frame and store the data as received, working counter +1
  for the read and +2 for the write, if the chip supports them
  (ESC features 0x0008 bit 10);
- ARMW/FRMW: the addressed slave reads, every other slave on the route
  writes the data as it then travels (before the reader: the master's data,
  after it: the data read);
- BRD ORs the register of every slave into the frame, BWR writes every
  slave, BRW does both per slave in route order.

Multi-slave writes and reads are array operations over the memory rows of
the route (one numpy call per ESC profile present) wherever the addressed
bytes have no per-slave side effects and lie outside every SM area;
otherwise they take each slave's :class:`~pyethercat.sim.esc.Esc`. BRD of a
1, 2, 4 or 8-byte register has a cached plan (:class:`BrdPlan`) that the
segment's frame path uses directly.
"""

from __future__ import annotations

import struct
import sys
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from pyethercat.sim.access import SIDE_EFFECT_MASK, SM_LOWEST, WRITE_TRIGGER, cleared_by_read
from pyethercat.sim.dc import DcClocks
from pyethercat.sim.esc import Esc
from pyethercat.sim.host import Dirty
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.sim.profiles import EscProfile
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import WKC, Command

__all__ = ["READS", "RMW", "WRITES", "BrdPlan", "CommandHost", "Commands", "FprdPlan", "station_map"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]

READS = frozenset((int(Command.APRD), int(Command.FPRD)))
WRITES = frozenset((int(Command.APWR), int(Command.FPWR)))
RMW = frozenset((int(Command.ARMW), int(Command.FRMW)))
_BWR = int(Command.BWR)
_BRW = int(Command.BRW)
_EMPTY = np.zeros(0, np.int64)
#: Longest route for which a BRD ORs a register column as Python ints (numpy above).
_BRD_PY_MAX = 64
#: Marker: every byte of the range is writable (one slice assignment).
_ALL: I64 = np.arange(1, dtype=np.int64)
_WORD_FORMAT: dict[int, Literal["B", "H", "I", "Q"]] = {1: "B", 2: "H", 4: "I", 8: "Q"}
#: Data word and working counter of a 1/2/4/8-byte datagram, little endian.
_DATA_WKC: dict[int, struct.Struct] = {n: struct.Struct("<" + f + "H") for n, f in _WORD_FORMAT.items()}
_WIDE: dict[int, str] = {1: "u1", 2: "<u2", 4: "<u4", 8: "<u8"}


def _per_slave_write_mask() -> npt.NDArray[np.bool_]:
    """Register bytes whose ECAT writes need the per-slave path.

    Those with side effects, less the ranges :meth:`Commands.multi_write`
    handles as array operations (addressing, event mask, FMMUs, DC latch and
    system time, watchdog divider and time)."""
    mask = SIDE_EFFECT_MASK.copy()
    for a, b in ((R.STATION_ADDRESS, R.STATION_ALIAS + 2), (R.ECAT_EVENT_MASK, R.ECAT_EVENT_MASK + 2),
                 (R.FMMU_BASE, R.SM_BASE), (R.DC_RECEIVE_TIME_PORT0, R.DC_SYSTEM_TIME + 8),
                 (R.WATCHDOG_DIVIDER, R.WATCHDOG_STATUS_PROCESS_DATA)):
        mask[a:b] = False
    mask.setflags(write=False)
    return mask


_PER_SLAVE_WRITE = _per_slave_write_mask()


class BrdPlan:
    """Cached work of one BRD shape (address, length, route length)."""

    __slots__ = ("slow", "rows", "contiguous", "systime", "block", "column", "clear", "words", "dw")

    def __init__(self) -> None:
        self.slow = False
        self.rows: I64 = _EMPTY
        self.contiguous = False
        self.systime = False
        self.block: U8 | None = None
        self.column: npt.NDArray[np.unsignedinteger[Any]] | None = None
        self.clear = 0
        #: Fast path (Segment.process): the register column as a strided
        #: memoryview of native words (all route slaves implement it) and the
        #: little-endian struct of the datagram's data and working counter.
        self.words: memoryview | None = None
        self.dw: struct.Struct = WKC


class FprdPlan:
    """The frame path's FPRD of one plain register range of one slave.

    ``source`` is the range in the segment's memory (the reply's data as it
    is now), ``event`` the slave's ECAT event request byte 0x0210 there and
    ``clear`` the events reading the range clears (DL status, AL status):
    while one of them is pending, the general path runs and clears it.
    """

    __slots__ = ("source", "event", "clear")

    def __init__(self, source: memoryview, event: memoryview, clear: int) -> None:
        self.source = source
        self.event = event
        self.clear = clear


class CommandHost(Protocol):
    """What the command rules need of the segment."""

    memory: EscMemory
    escs: list[Esc]
    dc: DcClocks
    sii_busy_ns: int
    #: ECAT event bits that may be set in some slave (cleared by vectorised reads).
    event_bits: int

    def invalidate(self, what: Dirty) -> None: ...
    def sm_span(self) -> tuple[int, int]: ...


class Commands:
    """The command rules of one segment, with their caches (see the module docstring)."""

    def __init__(self, host: CommandHost) -> None:
        self.host = host
        self.profiles: list[EscProfile] = []
        self._profile_esc: list[Esc] = []
        #: Index into :attr:`profiles` per slave.
        self.profile_id: I64 = np.zeros(0, np.int64)
        # Per-chip answers for multi-slave writes (emptied on slave/power
        # changes; _fast_ok when the SM areas are recompiled).
        self._takes: dict[tuple[int, int, int, bool], bool] = {}
        self._wcols: dict[tuple[int, int, int], I64] = {}
        self._fast_ok: dict[tuple[int, int], bool] = {}
        #: BRD plans by (lo, hi, passes) and, for the frame path, by an int key.
        self.brd_plans: dict[tuple[int, int, int, int] | int, BrdPlan] = {}
        #: The master port frames now enter at (a ring's two routes have plans of their own).
        self.route_tag = 0
        #: Longest route on which small BRDs take the Python-int path (0: numpy only).
        self.brd_py_max = _BRD_PY_MAX
        #: BRDs of 1/2/4/8-byte registers handled by the frame path itself
        #: (tests compare with the general path by switching this off).
        self.brd_fast = True
        #: FPRDs of plain registers handled by the frame path itself, by the int
        #: key (address field, length, master port): see :meth:`fprd_plan`. False
        #: remembers a shape that takes the general path.
        self.fprd_plans: dict[int, FprdPlan | Literal[False]] = {}
        self.fprd_fast = True

    def add_slave(self, esc: Esc) -> None:
        if esc.profile not in self.profiles:
            self.profiles.append(esc.profile)
            self._profile_esc.append(esc)
        self.profile_id = np.append(self.profile_id, self.profiles.index(esc.profile))

    def replace_slave(self, index: int, esc: Esc) -> None:
        """Slave ``index`` is another chip now (hot swap)."""
        if esc.profile not in self.profiles:
            self.profiles.append(esc.profile)
            self._profile_esc.append(esc)
        self.profile_id[index] = self.profiles.index(esc.profile)
        self.invalidate()

    def invalidate(self, sm_changed: bool = False) -> None:
        """Forget cached plans (slaves or power changed; ``sm_changed``: SM areas only)."""
        self.brd_plans.clear()
        self.fprd_plans.clear()
        self._fast_ok.clear()
        if not sm_changed:
            self._takes.clear()
            self._wcols.clear()

    # --- single slave ------------------------------------------------------------------

    def single(self, cmd: int, s: int, ado: int, data: U8, n: int) -> int:
        esc = self.host.escs[s]
        if cmd in READS:
            r = esc.ecat_read(ado, n)
            if r is None:
                return 0
            data[:] = np.frombuffer(r, np.uint8)
            return 1
        if cmd in WRITES:
            return 1 if esc.ecat_write(ado, data.tobytes()) else 0
        # APRW / FPRW: read the old content into the frame, store the data as received.
        if not esc.profile.rw_supported:
            return 0
        incoming = data.tobytes()
        wkc = 0
        r = esc.ecat_read(ado, n)
        if r is not None:
            data[:] = np.frombuffer(r, np.uint8)
            wkc += 1
        if esc.ecat_write(ado, incoming):
            wkc += 2
        return wkc

    def addressed(self, cmd: int, passes: I64, hits: list[int] | None, ado: int, data: U8, n: int) -> int:
        """Positional or configured-address command: ``hits`` are the route positions (in
        ``passes``) of the addressed slave(s), an RMW's reader first (None or []: none)."""
        count = len(passes)
        if cmd in RMW:
            return self.rmw(passes, hits[0] if hits and hits[0] < count else None, ado, data, n)
        wkc = 0
        for pos in hits or ():
            if pos < count:
                wkc += self.single(cmd, int(passes[pos]), ado, data, n)
        return wkc

    def rmw(self, passes: I64, reader: int | None, ado: int, data: U8, n: int) -> int:
        """ARMW/FRMW: the addressed slave reads, every other slave writes."""
        if reader is None:
            return self.multi_write(passes, ado, data.tobytes())
        wkc = self.multi_write(passes[:reader], ado, data.tobytes())
        r = self.host.escs[int(passes[reader])].ecat_read(ado, n)
        if r is not None:
            data[:] = np.frombuffer(r, np.uint8)
            wkc += 1
        return wkc + self.multi_write(passes[reader + 1:], ado, data.tobytes())

    # --- which chips take an access -------------------------------------------------------

    def _rows_implementing(self, rows: I64, lo: int, hi: int, write: bool = False) -> I64:
        """The slaves of ``rows`` whose chip implements (or, for writes, takes) a byte of [lo, hi)."""
        if not len(rows):
            return _EMPTY
        if len(self.profiles) == 1:
            return rows if self._profile_takes(0, lo, hi, write) else _EMPTY
        keep = np.zeros(len(rows), bool)
        pids = self.profile_id[rows]
        for pid in range(len(self.profiles)):
            sel = pids == pid
            if sel.any() and self._profile_takes(pid, lo, hi, write):
                keep |= sel
        return rows[keep]

    def _profile_takes(self, pid: int, lo: int, hi: int, write: bool) -> bool:
        """Whether chips of profile ``pid`` implement (write: take) a byte of [lo, hi); cached."""
        key = (pid, lo, hi, write)
        hit = self._takes.get(key)
        if hit is None:
            esc = self._profile_esc[pid]
            if write:
                hit = bool(esc.writable[lo:hi].any() or (WRITE_TRIGGER[lo:hi] & esc.impl[lo:hi]).any())
            else:
                hit = bool(esc.impl[lo:hi].any())
            self._takes[key] = hit
        return hit

    def _fast_write_ok(self, lo: int, hi: int) -> bool:
        """Whether a multi-slave write over [lo, hi) can be one array operation.

        Depends on the SM areas (the cache is emptied when they are recompiled)
        and on static masks only."""
        sm_lo, sm_hi = self.host.sm_span()
        ok = self._fast_ok.get((lo, hi))
        if ok is not None:
            return ok
        ok = not (lo < sm_hi and hi > sm_lo) and not _PER_SLAVE_WRITE[lo:hi].any()
        self._fast_ok[(lo, hi)] = ok
        return ok

    # --- several slaves ------------------------------------------------------------------------

    def multi_write(self, rows: I64, ado: int, data: bytes) -> int:
        """Write ``data`` at ``ado`` into every slave of ``rows`` (in route order)."""
        if not len(rows):
            return 0
        lo, hi = ado, ado + len(data)
        if hi > R.ADDRESS_SPACE:
            return 0
        host = self.host
        if not self._fast_write_ok(lo, hi) or hi > host.memory.stride:
            wkc = 0
            escs = host.escs
            for s in rows.tolist():
                if escs[s].ecat_write(ado, data):
                    wkc += 1
            return wkc
        rows = self._rows_implementing(rows, lo, hi, write=True)
        if not len(rows):
            return 0
        mem = host.memory.mem
        new = np.frombuffer(data, np.uint8)
        for pid in range(len(self.profiles)):
            key = (pid, lo, hi)
            cols = self._wcols.get(key)
            if cols is None:
                wmask = self._profile_esc[pid].writable[lo:hi]
                cols = _ALL if wmask.all() else np.nonzero(wmask)[0]
                self._wcols[key] = cols
            if not len(cols):
                continue  # nothing writable here for this chip
            sel = rows if len(self.profiles) == 1 else rows[self.profile_id[rows] == pid]
            if not len(sel):
                continue
            if cols is _ALL:
                mem[sel, lo:hi] = new
            else:
                mem[np.ix_(sel, cols + lo)] = new[cols]
        dirty = Dirty(0)
        if lo < R.STATION_ALIAS + 2 and hi > R.STATION_ADDRESS:
            dirty |= Dirty.ADDRESSING
        if lo < R.ECAT_EVENT_MASK + 2 and hi > R.ECAT_EVENT_MASK:
            dirty |= Dirty.IRQ
        if lo < R.SM_BASE and hi > R.FMMU_BASE:
            dirty |= Dirty.FMMU
        if lo < R.WATCHDOG_STATUS_PROCESS_DATA and hi > R.WATCHDOG_DIVIDER:
            dirty |= Dirty.WATCHDOG
        if dirty:
            host.invalidate(dirty)
        if lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_RECEIVE_TIME_PORT0:
            host.dc.written(rows, lo, data)
        return len(rows)

    def broadcast(self, cmd: int, route: Route, passes: I64, ado: int, data: U8, n: int) -> int:
        if not len(passes) or n == 0:
            return 0
        lo, hi = ado, ado + n
        if hi > R.ADDRESS_SPACE:
            return 0
        if cmd == _BWR:
            return self.multi_write(passes, ado, data.tobytes())
        escs = self.host.escs
        if cmd == _BRW:
            wkc = 0
            for s in passes.tolist():
                esc = escs[s]
                if not esc.profile.rw_supported:
                    continue
                incoming = data.tobytes()  # the data as it arrives at this slave
                r = esc.ecat_read(ado, n)
                if r is not None:
                    data |= np.frombuffer(r, np.uint8)
                    wkc += 1
                if esc.ecat_write(ado, incoming):
                    wkc += 2
            return wkc
        # BRD
        key = (lo, hi, len(passes), self.route_tag)
        plan = self.brd_plans.get(key)
        if plan is None:
            plan = self._brd_plan(route, passes, lo, hi)
            self.brd_plans[key] = plan
            if plan.column is not None and not plan.slow and not plan.systime and self.brd_fast:
                # Also under the int key the frame path looks up (ado, length, passes).
                self.brd_plans[(ado << 16) | n | (len(passes) << 32) | (self.route_tag << 48)] = plan
        if plan.slow:
            wkc = 0
            for s in passes.tolist():
                r = escs[s].ecat_read(ado, n)
                if r is not None:
                    data |= np.frombuffer(r, np.uint8)
                    wkc += 1
            return wkc
        rows = plan.rows
        if not len(rows):
            return 0
        if plan.systime:
            self.host.dc.refresh_system_time(rows)
        if plan.column is not None:
            # 1/2/4/8-byte reads: OR one strided column of wide integers.
            red = np.bitwise_or.reduce(plan.column)
            if red:
                dv = data.view(plan.column.dtype.str)
                dv |= red
        else:
            data |= np.bitwise_or.reduce(plan.block if plan.block is not None
                                         else self.host.memory.mem[rows, lo:hi], axis=0)
        clear = plan.clear
        if clear and self.host.event_bits & clear:
            mem = self.host.memory.mem
            if plan.contiguous:
                mem[: len(rows), R.ECAT_EVENT_REQUEST] &= np.uint8(~clear & 0xFF)
            else:
                mem[rows, R.ECAT_EVENT_REQUEST] &= np.uint8(~clear & 0xFF)
            self.host.event_bits &= ~clear
            self.host.invalidate(Dirty.IRQ)
        return len(rows)

    def fprd_plan(self, stations: dict[int, list[int]], passes: I64, adp: int, ado: int,
                  n: int) -> FprdPlan | Literal[False]:
        """How the frame path may answer an FPRD of ``n`` bytes at ``ado`` of station ``adp``.

        A plan when one slave on the route has the address and the range is a
        plain register read for its chip: implemented, below the SM-governed
        memory, and none of the registers a read brings up to date first
        (SII control, DC system time, SYNC status). Valid while the route and
        the station addresses stay as they were (the plans are dropped when
        either is compiled again); False: the general path.
        """
        lo, hi = ado, ado + n
        if (not self.fprd_fast or n == 0 or hi > SM_LOWEST
                or (lo < R.SII_CONTROL + 2 and hi > R.SII_CONTROL)
                or (lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME)
                or (lo <= R.DC_SYNC1_STATUS and hi > R.DC_SYNC0_STATUS)):
            return False
        hits = stations.get(adp)
        if hits is None or len(hits) != 1 or hits[0] >= len(passes):
            return False
        s = int(passes[hits[0]])
        esc = self.host.escs[s]
        if hi > len(esc.row) or not esc.impl[lo:hi].any():
            return False
        memory = self.host.memory
        base = s * memory.stride
        flat = memory.flat.data
        return FprdPlan(flat[base + lo: base + hi],
                        flat[base + R.ECAT_EVENT_REQUEST: base + R.ECAT_EVENT_REQUEST + 1],
                        cleared_by_read(lo, hi))

    def _brd_plan(self, route: Route, passes: I64, lo: int, hi: int) -> BrdPlan:
        host = self.host
        sm_lo, sm_hi = host.sm_span()
        plan = BrdPlan()
        sii_timed = host.sii_busy_ns > 0 or any(p.sii_read_ns or p.sii_write_ns for p in self.profiles)
        # (SYNC0/1 status depends on the time of the read: each slave works it out)
        plan.slow = bool((lo < sm_hi and hi > sm_lo) or hi > host.memory.stride or (
            sii_timed and lo < R.SII_CONTROL + 2 and hi > R.SII_CONTROL) or (
            lo <= R.DC_SYNC1_STATUS and hi > R.DC_SYNC0_STATUS))
        plan.rows = rows = self._rows_implementing(passes, lo, hi)
        plan.contiguous = contiguous = bool(route.contiguous and len(rows) == len(passes))
        plan.systime = lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME
        memory = host.memory
        n = hi - lo
        if contiguous and len(rows):
            plan.block = memory.mem[: len(rows), lo:hi]
            if n in _WIDE:
                plan.column = plan.block.view(_WIDE[n])[:, 0]
                plan.dw = _DATA_WKC[n]
            if (n in _WORD_FORMAT and lo % n == 0 and len(rows) <= self.brd_py_max and not plan.slow
                    and not plan.systime and sys.byteorder == "little" and memory.stride % 8 == 0):
                # Row stride is a multiple of every word size, so slot lo // n of
                # row k is element k * (stride // n) + lo // n of the flat words.
                step = memory.stride // n
                words = memory.flat.data.cast(_WORD_FORMAT[n])
                plan.words = words[lo // n: lo // n + len(rows) * step: step]
        plan.clear = cleared_by_read(lo, hi)
        return plan



def station_map(memory: EscMemory, passes: I64) -> dict[int, list[int]]:
    """Configured addresses of the slaves on the route: address -> route positions.

    A slave answers its station address 0x0010 and, when DL control 0x0100
    bit 24 enables it, its alias 0x0012 (KickCAT ``EmulatedESC.cc``
    ``matchesConfiguredAddress``)."""
    stations: dict[int, list[int]] = {}
    mem = memory.mem
    for pos, s in enumerate(passes.tolist()):
        st = int(mem[s, R.STATION_ADDRESS]) | (int(mem[s, R.STATION_ADDRESS + 1]) << 8)
        stations.setdefault(st, []).append(pos)
        if mem[s, R.DL_CONTROL_ALIAS] & 1:
            alias = int(mem[s, R.STATION_ALIAS]) | (int(mem[s, R.STATION_ALIAS + 1]) << 8)
            if alias != st:
                stations.setdefault(alias, []).append(pos)
    return stations
