"""Logical addressing: the FMMUs of a route compiled into gather/scatter index arrays.

Each logical datagram shape (address, length, command) gets a plan, made the
first time the shape is seen and then cached: the FMMUs of the route that
overlap the datagram's window are resolved, for that window only, into flat
index arrays over the memory array (``EscMemory.flat``):

- byte entries (logical start bit 0, stop bit 7, physical start bit 0): one
  logical byte <-> one physical byte;
- bit entries (anything else): one logical bit <-> one physical bit.

A plan covers at most the datagram's bytes (2047) times the FMMUs that
overlap them, whatever the FMMUs say: an FMMU of 64 KiB, or one whose
logical range runs past 0xFFFFFFFF (logical addresses wrap at 32 bits, as
the ESC compares them), costs what its part inside the window costs. The
plan cache is bounded too.

Executing a plan costs a fixed number of numpy operations: a gather for the
read FMMUs, a scatter for the write FMMUs, the placing of the read values.
The FMMU rules hold (ESC datasheet section I, "FMMU"; KickCAT
``EmulatedESC.cc`` ``copyFmmu``): a logical byte may be read by one FMMU and
written by another, bit operations leave unmapped bits untouched
(``ufunc.at`` read-modify-write), unconfigured logical addresses pass
unchanged, a physical byte the chip lacks is neither read nor written.

Sync managers (ESC datasheet section I, "SyncManager") are compiled in as
well, so that a logical access obeys the same rules as FPRD/FPWR: write
entries whose physical byte lies in an enabled ECAT-read SM (inputs, send
mailbox) are dropped, as the ESC refuses EtherCAT writes there (and they do
not count in the working counter); read entries on the last byte of an
enabled buffered ECAT-read SM complete a buffer read (status 'read event',
the SM's AL event, its ECAT event cleared).

Ordering along the ring matters only where mappings overlap: when a logical
byte read by one slave is written by a later slave on the route (cross
traffic), or when byte and bit entries of different slaves read the same
byte. A datagram touching such a byte is processed pass by pass in route
order (``_execute_ordered``). Several readers of the same byte/bit otherwise
resolve by ordered assignment (the last slave on the route wins, as on the
wire).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.ma  # noqa: F401  (np.unique imports it lazily: ~12 ms in the first LRW plan compile)
import numpy.typing as npt

from pyethercat.wire import registers as R

__all__ = [
    "SLAVE_STRIDE",
    "FmmuConfig",
    "LogicalMap",
    "SmReads",
    "parse_fmmus",
]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
BoolA = npt.NDArray[np.bool_]

SLAVE_STRIDE = R.ADDRESS_SPACE
_SPACE = 1 << 32
#: Plans kept (each is bounded by the datagram size times the FMMUs it covers).
_PLAN_CACHE = 1024


@dataclass
class FmmuConfig:
    """One active FMMU of the slave at route position ``pos``."""

    pos: int
    slave: int
    logical: int
    length: int
    start_bit: int
    stop_bit: int
    physical: int
    physical_bit: int
    read: bool
    write: bool

    @property
    def bits(self) -> int:
        return 8 * self.length - self.start_bit - (7 - self.stop_bit)

    @property
    def byte_aligned(self) -> bool:
        return self.start_bit == 0 and self.stop_bit == 7 and self.physical_bit == 0


def parse_fmmus(raw: bytes, count: int, pos: int, slave: int) -> list[FmmuConfig]:
    """Active FMMUs from the bytes of a slave's FMMU register block."""
    out = []
    for n in range(count):
        (logical, length, sbit, ebit, phys, pbit, ftype, act) = R.FMMU_STRUCT.unpack_from(raw, 16 * n)
        if not act & 1 or length == 0 or not ftype & 3:
            continue
        cfg = FmmuConfig(pos, slave, logical, length, sbit & 7, ebit & 7, phys, pbit & 7,
                         bool(ftype & R.FmmuType.READ), bool(ftype & R.FmmuType.WRITE))
        if cfg.bits > 0:
            out.append(cfg)
    return out


def _cat(parts: list[I64]) -> I64:
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


@dataclass
class SmReads:
    """ECAT-read sync managers of a route, compiled by the segment (see the module docstring).

    ``refused[slave]`` lists the [start, end) ranges of the slave's enabled
    ECAT-read SMs; ``last[slave]`` maps the last byte of each enabled
    buffered ECAT-read SM to its entry in the flat arrays: SM status byte,
    AL event byte and bit (0: no AL event), ECAT event byte and bit (0: no
    ECAT event), all as indices into the flat memory.
    """

    refused: dict[int, list[tuple[int, int]]]
    last: dict[int, dict[int, int]]
    status: I64
    al_byte: I64
    al_bit: U8
    ev_byte: I64
    ev_bit: U8

    @staticmethod
    def empty() -> SmReads:
        z = np.zeros(0, np.int64)
        return SmReads({}, {}, z, z, np.zeros(0, np.uint8), z, np.zeros(0, np.uint8))


def _in_ranges(phys: I64, ranges: list[tuple[int, int]]) -> BoolA:
    m = np.zeros(len(phys), bool)
    for a, b in ranges:
        m |= (phys >= a) & (phys < b)
    return m


def _sm_ids(phys: I64, last: dict[int, int]) -> I64:
    """Per physical byte: the SM entry whose last byte it is, else -1."""
    ids = np.full(len(phys), -1, np.int64)
    for byte, k in last.items():
        ids[phys == byte] = k
    return ids


def _combine(idx: I64, val: U8, op: np.ufunc) -> tuple[I64, U8]:
    """Unique indices with their values combined by ``op`` (one fancy assignment then)."""
    if not len(idx):
        return idx, val
    order = np.argsort(idx, kind="stable")
    idx, val = idx[order], val[order]
    first = np.ones(len(idx), bool)
    first[1:] = idx[1:] != idx[:-1]
    starts = np.nonzero(first)[0]
    return idx[starts], op.reduceat(val, starts).astype(np.uint8)


def _pieces(logical: int, length: int, lo: int, n: int) -> list[tuple[int, int, int]]:
    """Byte offsets [i0, i1) of an FMMU at ``logical`` (``length`` bytes) inside the window
    [lo, lo + n) of the 32-bit logical space, with the window offset of i0 (both wrap)."""
    d = (lo - logical) % _SPACE  # FMMU offset of the window's first byte
    out = []
    for start in (d, d - _SPACE):
        i0, i1 = max(start, 0), min(start + n, length)
        if i1 > i0:
            out.append((i0, i1, i0 - start))
    return out


@dataclass
class _Entries:
    """The mapped entries of one window, sorted by (window offset, route position)."""

    rb_rel: I64     # byte reads: window byte, flat index, SM entry, position
    rb_phys: I64
    rb_sm: I64
    rb_pos: I64
    wb_rel: I64     # byte writes: window byte, flat index, completes a buffer, position
    wb_phys: I64
    wb_done: BoolA
    wb_pos: I64
    rt_rel: I64     # bit reads: window bit, flat byte, bit, SM entry, position
    rt_pbyte: I64
    rt_shift: I64
    rt_sm: I64
    rt_pos: I64
    wt_rel: I64     # bit writes: window bit, flat byte, bit, completes a buffer, position
    wt_pbyte: I64
    wt_shift: I64
    wt_done: BoolA
    wt_pos: I64
    stride: int

    @property
    def wb_slave(self) -> I64:
        return self.wb_phys // self.stride

    @property
    def wt_slave(self) -> I64:
        return self.wt_pbyte // self.stride


class _Plan:
    """Cached index arrays of one logical datagram shape."""

    __slots__ = ("wkc", "ordered", "done", "r_phys", "r_rel", "t_pbyte", "t_shift", "t_rel",
                 "w_phys", "w_rel", "b_pbyte", "b_shift", "b_clear", "b_rel",
                 "or_idx", "or_val", "and_idx", "and_val", "and_hit", "entries", "size")

    def __init__(self, wkc: int) -> None:
        self.wkc = wkc
        #: Buffer-read completion: status/AL event bytes to OR, ECAT event bytes to AND.
        self.or_idx: I64 | None = None
        self.or_val: U8 | None = None
        self.and_idx: I64 | None = None
        self.and_val: U8 | None = None
        self.and_hit: U8 | None = None
        self.ordered = False
        self.done: I64 = np.zeros(0, np.int64)
        self.r_phys: I64 | None = None
        #: Window offsets of the gathered bytes: a slice where they are one run
        #: (the usual image: a view of the datagram, not a gather of its bytes).
        self.r_rel: I64 | slice | None = None
        self.t_pbyte: I64 | None = None
        self.t_shift: I64 | None = None
        self.t_rel: I64 | None = None
        self.w_phys: I64 | None = None
        self.w_rel: I64 | slice | None = None
        self.b_pbyte: I64 | None = None
        self.b_shift: I64 | None = None
        self.b_clear: U8 | None = None
        self.b_rel: I64 | None = None
        #: The window's entries (kept for the ordered path only).
        self.entries: _Entries | None = None
        #: Index entries the plan holds (for the cache bound).
        self.size = 0


class LogicalMap:
    """The FMMUs of a route (see the module docstring).

    ``writable[slave]`` is the slave's ECAT-writable byte mask (written bytes
    outside it are dropped), ``implemented[slave]`` the bytes its chip has;
    ``complete[slave]`` lists the last bytes of the slave's enabled buffered
    write SMs (a write there completes a buffer).
    """

    def __init__(self, configs: list[FmmuConfig], writable: list[npt.NDArray[np.bool_]],
                 complete: dict[int, set[int]], implemented: list[npt.NDArray[np.bool_]],
                 sm_reads: SmReads | None = None, stride: int = SLAVE_STRIDE) -> None:
        self.configs = configs
        self._writable = writable
        self._implemented = implemented
        self._complete = complete
        self._smr = sm_reads if sm_reads is not None else SmReads.empty()
        self._stride = stride
        self.empty = not configs
        # FMMU-level arrays, to find the FMMUs a window overlaps with array operations.
        self.f_lo = np.array([c.logical for c in configs], dtype=np.int64)
        self.f_len = np.array([c.length for c in configs], dtype=np.int64)
        self.f_pos = np.array([c.pos for c in configs], dtype=np.int64)
        self.f_read = np.array([c.read for c in configs], dtype=bool)
        self.f_write = np.array([c.write for c in configs], dtype=bool)
        self._plans: dict[tuple[int, int, bool, bool], _Plan] = {}
        self._plan_entries = 0

    # --- execution --------------------------------------------------------------------

    def plan_keys(self) -> list[tuple[int, int, bool, bool]]:
        """The datagram shapes (address, length, reads, writes) planned so far."""
        return list(self._plans)

    def span_key(self) -> tuple[int, int, bool, bool] | None:
        """The shape of one LRW over every mapped byte (what most masters send), or None."""
        if self.empty:
            return None
        lo = int(self.f_lo.min())
        return lo, int((self.f_lo + self.f_len).max()) - lo, True, True

    def prepare(self, keys: list[tuple[int, int, bool, bool]]) -> list[I64]:
        """Plan these datagram shapes now (those a previous map had seen); returns the
        sets of slaves whose write SMs each of them completes."""
        done: list[I64] = []
        for key in keys[:_PLAN_CACHE]:
            plan = self._plans.get(key)
            if plan is None:
                plan = self._plans[key] = self._plan(*key)
                self._plan_entries += plan.size
            if len(plan.done):
                done.append(plan.done)
        return done

    def run(self, flat: U8, lo: int, data: U8, reads: bool, writes: bool) -> tuple[int, I64, bool]:
        """Apply a logical datagram: (working counter, slaves whose write SM completed,
        whether an ECAT event request bit was cleared).

        The index arrays, the working counter, the completed slaves and the
        buffer reads depend only on (address, length, command), so they are
        computed once per datagram shape and cached: the cyclic cost is a
        gather, a scatter, a placement and the SM status updates.
        """
        key = (lo, len(data), reads, writes)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plan(lo, len(data), reads, writes)
            if len(self._plans) >= _PLAN_CACHE or self._plan_entries > 8_000_000:
                self._plans.clear()
                self._plan_entries = 0
            self._plans[key] = plan
            self._plan_entries += plan.size
        if not plan.wkc:
            return 0, plan.done, False
        if plan.ordered:
            assert plan.entries is not None
            done = _execute_ordered(plan.entries, flat, data, reads, writes)
            return plan.wkc, done, self._sm_read_events(flat, plan)
        # Gather first (a slave reads its memory as it was), scatter the data as
        # it arrived (``data`` is unchanged until the reads are placed), then place.
        rvals = flat[plan.r_phys] if plan.r_phys is not None else None
        tvals = None
        if plan.t_pbyte is not None:
            assert plan.t_shift is not None
            tvals = (flat[plan.t_pbyte] >> plan.t_shift) & 1
        if plan.w_phys is not None:
            flat[plan.w_phys] = data[plan.w_rel]
        if plan.b_pbyte is not None:
            assert plan.b_rel is not None and plan.b_shift is not None and plan.b_clear is not None
            vals = ((data[plan.b_rel >> 3] >> (plan.b_rel & 7)) & 1).astype(np.uint8)
            np.bitwise_and.at(flat, plan.b_pbyte, plan.b_clear)
            np.bitwise_or.at(flat, plan.b_pbyte, (vals << plan.b_shift).astype(np.uint8))
        if rvals is not None:
            data[plan.r_rel] = rvals
        if tvals is not None:
            bits = np.unpackbits(data, bitorder="little")
            bits[plan.t_rel] = tvals
            data[:] = np.packbits(bits, bitorder="little")
        if plan.or_idx is None:
            return plan.wkc, plan.done, False
        return plan.wkc, plan.done, self._sm_read_events(flat, plan)

    @staticmethod
    def _sm_read_events(flat: U8, plan: _Plan) -> bool:
        """Buffers read completely: status read event and AL events set, ECAT events cleared."""
        if plan.or_idx is None:
            return False
        assert plan.or_val is not None
        flat[plan.or_idx] |= plan.or_val
        if plan.and_idx is None:
            return False
        assert plan.and_val is not None and plan.and_hit is not None
        old = flat[plan.and_idx]
        if not (old & plan.and_hit).any():
            return False
        flat[plan.and_idx] = old & plan.and_val
        return True

    # --- plans ---------------------------------------------------------------------------

    def _overlapping(self, lo: int, n: int) -> I64:
        """Indices of the FMMUs with a byte in the window (32-bit wrap included)."""
        if self.empty:
            return np.zeros(0, np.int64)
        d = (lo - self.f_lo) % _SPACE
        hit = (d < self.f_len) | (d + n > _SPACE)
        return np.nonzero(hit)[0]

    def _entries(self, lo: int, n: int, fmmus: I64, reads: bool, writes: bool
                 ) -> tuple[_Entries, I64, I64]:
        """The entries of the window (sorted) and the write-countable (window byte, position) pairs."""
        smr = self._smr
        rb: list[list[I64]] = [[], [], [], []]
        wb: list[list[I64]] = [[], [], [], []]
        rt: list[list[I64]] = [[], [], [], [], []]
        wt: list[list[I64]] = [[], [], [], [], []]
        wc_rel: list[I64] = []
        wc_pos: list[I64] = []
        stride = self._stride
        for f in fmmus.tolist():
            c = self.configs[f]
            if not ((c.read and reads) or (c.write and writes)):
                continue
            base = c.slave * stride
            impl = self._implemented[c.slave]
            wmask = self._writable[c.slave]
            done = self._complete.get(c.slave)
            refused = smr.refused.get(c.slave)
            last = smr.last.get(c.slave)
            for i0, i1, r0 in _pieces(c.logical, c.length, lo, n):
                if c.byte_aligned:
                    rel = np.arange(r0, r0 + i1 - i0, dtype=np.int64)
                    phys = np.arange(c.physical + i0, c.physical + i1, dtype=np.int64)
                    pbyte = phys
                else:
                    j0 = max(8 * i0, c.start_bit)
                    j1 = min(8 * i1, c.start_bit + c.bits)
                    if j1 <= j0:
                        continue
                    jj = np.arange(j0, j1, dtype=np.int64)
                    rel = 8 * r0 + (jj - 8 * i0)
                    pbit = c.physical * 8 + c.physical_bit + (jj - c.start_bit)
                    pbyte = pbit >> 3
                if c.write and writes:
                    cnt = ~_in_ranges(pbyte, refused) if refused else np.ones(len(rel), bool)
                    wc_rel.append(np.unique(rel[cnt] >> (0 if c.byte_aligned else 3)))
                    wc_pos.append(np.full(len(wc_rel[-1]), c.pos, np.int64))
                keep = pbyte < R.ADDRESS_SPACE
                rel, pbyte = rel[keep], pbyte[keep]
                shift = None if c.byte_aligned else (pbit[keep] & 7)
                pos = np.full(len(rel), c.pos, np.int64)
                if c.read and reads:
                    ok = impl[pbyte]
                    sm = _sm_ids(pbyte[ok], last) if last else np.full(int(ok.sum()), -1, np.int64)
                    parts = (rel[ok], pbyte[ok] + base, sm, pos[ok])
                    if shift is None:
                        for k, p in enumerate(parts):
                            rb[k].append(p)
                    else:
                        for k, p in enumerate((parts[0], parts[1], shift[ok], parts[2], parts[3])):
                            rt[k].append(p)
                if c.write and writes:
                    ok = wmask[pbyte]
                    if refused:
                        ok &= ~_in_ranges(pbyte, refused)
                    fin = (np.isin(pbyte[ok], list(done)) if done else np.zeros(int(ok.sum()), bool))
                    parts = (rel[ok], pbyte[ok] + base, fin.astype(np.int64), pos[ok])
                    if shift is None:
                        for k, p in enumerate(parts):
                            wb[k].append(p)
                    else:
                        for k, p in enumerate((parts[0], parts[1], shift[ok], parts[2], parts[3])):
                            wt[k].append(p)

        def sort(cols: list[list[I64]]) -> list[I64]:
            arrays = [_cat(c) for c in cols]
            if not len(arrays[0]):
                return arrays
            # Stable by (window offset, route position): ordered assignment = last reader wins.
            order = np.lexsort((arrays[-1], arrays[0]))
            return [a[order] for a in arrays]

        rbs, wbs, rts, wts = sort(rb), sort(wb), sort(rt), sort(wt)
        entries = _Entries(rbs[0], rbs[1], rbs[2], rbs[3],
                           wbs[0], wbs[1], wbs[2].astype(bool), wbs[3],
                           rts[0], rts[1], rts[2], rts[3], rts[4],
                           wts[0], wts[1], wts[2], wts[3].astype(bool), wts[4], stride)
        return entries, _cat(wc_rel), _cat(wc_pos)

    def _plan(self, lo: int, n: int, reads: bool, writes: bool) -> _Plan:
        fmmus = self._overlapping(lo, n)
        if not len(fmmus) or n == 0:
            return _Plan(0)
        e, wc_rel, wc_pos = self._entries(lo, n, fmmus, reads, writes)
        wkc = 0
        if reads:
            wkc += len(np.unique(self.f_pos[fmmus][self.f_read[fmmus]]))
        if writes:
            # Per slave: at least one byte it may write (bytes an ECAT-read SM
            # refuses do not count, as for FPWR).
            nw = len(np.unique(wc_pos))
            wkc += 2 * nw if reads else nw
        plan = _Plan(wkc)
        if not wkc:
            return plan
        plan.size = len(e.rb_rel) + len(e.wb_rel) + len(e.rt_rel) + len(e.wt_rel)
        plan.ordered = _ordered(e)
        if plan.ordered:
            plan.entries = e
        if len(e.rb_rel):
            plan.r_phys, plan.r_rel = e.rb_phys, _run(e.rb_rel)
        if len(e.rt_rel):
            plan.t_pbyte, plan.t_shift, plan.t_rel = e.rt_pbyte, e.rt_shift, e.rt_rel
        done_parts: list[I64] = []
        if len(e.wb_rel):
            plan.w_phys, plan.w_rel = e.wb_phys, _run(e.wb_rel)
            done_parts.append(e.wb_slave[e.wb_done])
        if len(e.wt_rel):
            plan.b_pbyte, plan.b_shift, plan.b_rel = e.wt_pbyte, e.wt_shift, e.wt_rel
            plan.b_clear = (~(np.left_shift(1, e.wt_shift))).astype(np.uint8)
            done_parts.append(e.wt_slave[e.wt_done])
        if done_parts:
            plan.done = np.unique(np.concatenate(done_parts)).astype(np.int64)
        if reads:
            self._plan_sm_reads(plan, e)
        return plan

    def _plan_sm_reads(self, plan: _Plan, e: _Entries) -> None:
        """The buffered ECAT-read SMs whose last byte this datagram reads, as status updates."""
        smr = self._smr
        if not len(smr.status):
            return
        ids = np.concatenate([e.rb_sm, e.rt_sm])
        ids = np.unique(ids[ids >= 0])
        if not len(ids):
            return
        al = smr.al_bit[ids] != 0
        or_idx = np.concatenate([smr.status[ids], smr.al_byte[ids][al]])
        or_val = np.concatenate([np.full(len(ids), R.SM_STATUS_READ_EVENT, np.uint8), smr.al_bit[ids][al]])
        plan.or_idx, plan.or_val = _combine(or_idx, or_val, np.bitwise_or)
        ev = smr.ev_bit[ids] != 0
        if ev.any():
            and_idx, hit = _combine(smr.ev_byte[ids][ev], smr.ev_bit[ids][ev], np.bitwise_or)
            plan.and_idx, plan.and_hit = and_idx, hit
            plan.and_val = (~hit).astype(np.uint8)


def _run(rel: I64) -> I64 | slice:
    """``rel`` as a slice when it is consecutive offsets, else itself."""
    first = int(rel[0])
    if int(rel[-1]) - first == len(rel) - 1 and bool((np.diff(rel) == 1).all()):
        return slice(first, first + len(rel))
    return rel


def _ordered(e: _Entries) -> bool:
    """Whether the window's result depends on the order along the route (see the module docstring)."""
    read_rel = np.concatenate([e.rb_rel, e.rt_rel >> 3])
    read_pos = np.concatenate([e.rb_pos, e.rt_pos])
    write_rel = np.concatenate([e.wb_rel, e.wt_rel >> 3])
    write_pos = np.concatenate([e.wb_pos, e.wt_pos])
    if len(read_rel) and len(write_rel):
        # Earliest reader of each logical byte versus the writers of that byte.
        order = np.lexsort((read_pos, read_rel))
        rl, rp = read_rel[order], read_pos[order]
        first = np.ones(len(rl), bool)
        first[1:] = rl[1:] != rl[:-1]
        ul, up = rl[first], rp[first]
        idx = np.searchsorted(ul, write_rel)
        idx_c = np.minimum(idx, len(ul) - 1)
        if ((idx < len(ul)) & (ul[idx_c] == write_rel) & (up[idx_c] < write_pos)).any():
            return True
    if len(e.rb_rel) and len(e.rt_rel):
        tb = e.rt_rel >> 3
        for b in np.intersect1d(e.rb_rel, tb).tolist():
            if len(set(e.rb_pos[e.rb_rel == b].tolist()) | set(e.rt_pos[tb == b].tolist())) > 1:
                return True
    return False


def _execute_ordered(e: _Entries, flat: U8, data: U8, reads: bool, writes: bool) -> I64:
    """Pass-by-pass processing in route order (only for windows whose result depends on it)."""
    positions = sorted(set(e.rb_pos.tolist()) | set(e.rt_pos.tolist())
                       | set(e.wb_pos.tolist()) | set(e.wt_pos.tolist()))
    done: set[int] = set()
    wb_slave, wt_slave = e.wb_slave, e.wt_slave
    for p in positions:
        arriving = data.copy()
        rsel = np.nonzero(e.rb_pos == p)[0] if reads else np.zeros(0, np.int64)
        tsel = np.nonzero(e.rt_pos == p)[0] if reads else np.zeros(0, np.int64)
        rvals = flat[e.rb_phys[rsel]]
        tvals = (flat[e.rt_pbyte[tsel]] >> e.rt_shift[tsel]) & 1
        if writes:
            wsel = np.nonzero(e.wb_pos == p)[0]
            if len(wsel):
                flat[e.wb_phys[wsel]] = arriving[e.wb_rel[wsel]]
                done.update(wb_slave[wsel][e.wb_done[wsel]].tolist())
            bsel = np.nonzero(e.wt_pos == p)[0]
            if len(bsel):
                lb = e.wt_rel[bsel]
                vals = ((arriving[lb >> 3] >> (lb & 7)) & 1).astype(np.uint8)
                np.bitwise_and.at(flat, e.wt_pbyte[bsel], (~np.left_shift(1, e.wt_shift[bsel])).astype(np.uint8))
                np.bitwise_or.at(flat, e.wt_pbyte[bsel], (vals << e.wt_shift[bsel]).astype(np.uint8))
                done.update(wt_slave[bsel][e.wt_done[bsel]].tolist())
        if len(rsel):
            data[e.rb_rel[rsel]] = rvals
        if len(tsel):
            bits = np.unpackbits(data, bitorder="little")
            bits[e.rt_rel[tsel]] = tvals
            data[:] = np.packbits(bits, bitorder="little")
    return np.array(sorted(done), dtype=np.int64)
