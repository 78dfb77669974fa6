"""FMMU configuration compiled into gather/scatter index arrays.

When the FMMU or SM registers of any slave change, the segment compiles the
active FMMUs of all slaves on the frame's route into flat index arrays over
the memory array (``EscMemory.flat``):

- byte entries (logical start bit 0, stop bit 7, physical start bit 0): one
  logical byte <-> one physical byte;
- bit entries (anything else): one logical bit <-> one physical bit.

A logical datagram then costs a fixed number of numpy operations: two
``searchsorted`` to find the entries inside [address, address + length), a
gather for the read FMMUs and a scatter for the write FMMUs. The rules of
the FMMU rules hold (ESC datasheet section I, "FMMU"; KickCAT
``EmulatedESC.cc`` ``copyFmmu``): a logical byte may be read by one FMMU and
written by another,
bit operations leave unmapped bits untouched (``ufunc.at`` read-modify-write),
unconfigured logical addresses pass unchanged.

Sync managers (ESC datasheet section I, "SyncManager") are compiled in as well, so that a logical access
obeys the same rules as FPRD/FPWR: write entries whose physical byte lies in
an enabled ECAT-read SM (inputs, send mailbox) are dropped, as the ESC
refuses EtherCAT writes there (and they do not count in the working
counter); read entries on the last byte of an enabled buffered ECAT-read SM
complete a buffer read (status 'read event', the SM's AL event, its ECAT
event cleared). Each datagram shape's status updates are two cached fancy-
index operations.

Ordering along the ring matters only where mappings overlap: when a logical
byte read by one slave is written by a later slave on the route (cross
traffic), or when byte and bit entries of different slaves read the same
byte. Such bytes are listed in ``conflicts``; a datagram touching one is
processed pass by pass in route order (``_execute_ordered``). Several
readers of the same byte/bit otherwise resolve by ordered assignment (the
last slave on the route wins, as on the wire).
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


class _Plan:
    """Cached index slices of one logical datagram shape."""

    __slots__ = ("wkc", "ordered", "done", "r_phys", "r_rel", "t_pbyte", "t_shift", "t_rel",
                 "w_phys", "w_rel", "b_pbyte", "b_shift", "b_clear", "b_rel",
                 "or_idx", "or_val", "and_idx", "and_val", "and_hit")

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
        self.r_rel: I64 | None = None
        self.t_pbyte: I64 | None = None
        self.t_shift: I64 | None = None
        self.t_rel: I64 | None = None
        self.w_phys: I64 | None = None
        self.w_rel: I64 | None = None
        self.b_pbyte: I64 | None = None
        self.b_shift: I64 | None = None
        self.b_clear: U8 | None = None
        self.b_rel: I64 | None = None


class LogicalMap:
    """Compiled FMMU mappings of a route (see the module docstring).

    ``writable[slave]`` is the slave's ECAT-writable byte mask (written bytes
    outside it are dropped); ``complete[slave]`` lists the last bytes of the
    slave's enabled buffered write SMs (a write there completes a buffer).
    """

    def __init__(self, configs: list[FmmuConfig], writable: list[npt.NDArray[np.bool_]],
                 complete: dict[int, set[int]], implemented: list[npt.NDArray[np.bool_]],
                 sm_reads: SmReads | None = None, stride: int = SLAVE_STRIDE) -> None:
        self.configs = configs
        smr = sm_reads if sm_reads is not None else SmReads.empty()
        self._smr = smr
        rb_log, rb_phys, rb_pos, rb_sm = [], [], [], []
        wb_log, wb_phys, wb_pos, wb_done = [], [], [], []
        rt_lbit, rt_pbyte, rt_shift, rt_pos, rt_sm = [], [], [], [], []
        wt_lbit, wt_pbyte, wt_shift, wt_pos, wt_done = [], [], [], [], []
        # Logical bytes a write FMMU may count for (not refused by an ECAT-read SM).
        wc_log, wc_pos = [], []
        for c in configs:
            base = c.slave * stride
            impl = implemented[c.slave]
            wmask = writable[c.slave]
            done = complete.get(c.slave, set())
            refused = smr.refused.get(c.slave)
            last = smr.last.get(c.slave)
            if c.byte_aligned:
                log = np.arange(c.logical, c.logical + c.length, dtype=np.int64)
                phys = np.arange(c.physical, c.physical + c.length, dtype=np.int64)
                if c.write:
                    cnt = ~_in_ranges(phys, refused) if refused else np.ones(len(log), bool)
                    wc_log.append(log[cnt])
                    wc_pos.append(np.full(int(cnt.sum()), c.pos, np.int64))
                keep = phys < R.ADDRESS_SPACE
                log, phys = log[keep], phys[keep]
                pos = np.full(len(log), c.pos, np.int64)
                if c.read:
                    ok = impl[phys]
                    rb_log.append(log[ok])
                    rb_phys.append(phys[ok] + base)
                    rb_pos.append(pos[ok])
                    rb_sm.append(_sm_ids(phys[ok], last) if last else np.full(int(ok.sum()), -1, np.int64))
                if c.write:
                    ok = wmask[phys]
                    if refused:
                        ok &= ~_in_ranges(phys, refused)
                    wb_log.append(log[ok])
                    wb_phys.append(phys[ok] + base)
                    wb_pos.append(pos[ok])
                    wb_done.append(np.isin(phys[ok], list(done)) if done else np.zeros(int(ok.sum()), bool))
            else:
                k = np.arange(c.bits, dtype=np.int64)
                lbit = c.logical * 8 + c.start_bit + k
                pbit = c.physical * 8 + c.physical_bit + k
                if c.write:
                    cnt = ~_in_ranges(pbit >> 3, refused) if refused else np.ones(len(lbit), bool)
                    wc_log.append(np.unique(lbit[cnt] >> 3))
                    wc_pos.append(np.full(len(wc_log[-1]), c.pos, np.int64))
                keep = (pbit >> 3) < R.ADDRESS_SPACE
                lbit, pbit = lbit[keep], pbit[keep]
                pos = np.full(len(lbit), c.pos, np.int64)
                if c.read:
                    ok = impl[pbit >> 3]
                    rt_lbit.append(lbit[ok])
                    rt_pbyte.append((pbit[ok] >> 3) + base)
                    rt_shift.append(pbit[ok] & 7)
                    rt_pos.append(pos[ok])
                    rt_sm.append(_sm_ids(pbit[ok] >> 3, last) if last else np.full(int(ok.sum()), -1, np.int64))
                if c.write:
                    ok = wmask[pbit >> 3]
                    if refused:
                        ok &= ~_in_ranges(pbit >> 3, refused)
                    wt_lbit.append(lbit[ok])
                    wt_pbyte.append((pbit[ok] >> 3) + base)
                    wt_shift.append(pbit[ok] & 7)
                    wt_pos.append(pos[ok])
                    wt_done.append(np.isin(pbit[ok] >> 3, list(done)) if done else np.zeros(int(ok.sum()), bool))

        def sort(keys: I64, *cols: I64) -> tuple[I64, ...]:
            # Stable by (logical, route position): ordered assignment = last reader wins.
            order = np.lexsort((cols[-1], keys)) if len(keys) else np.zeros(0, np.int64)
            return (keys[order],) + tuple(c[order] for c in cols)

        self.rb_log, self.rb_phys, self.rb_sm, self.rb_pos = sort(
            _cat(rb_log), _cat(rb_phys), _cat(rb_sm), _cat(rb_pos))
        wdone = np.concatenate(wb_done).astype(bool) if wb_done else np.zeros(0, bool)
        self.wb_log, self.wb_phys, wdone_i, self.wb_pos = sort(
            _cat(wb_log), _cat(wb_phys), wdone.astype(np.int64), _cat(wb_pos))
        self.wb_done: BoolA = wdone_i.astype(bool)
        self.rt_lbit, self.rt_pbyte, self.rt_shift, self.rt_sm, self.rt_pos = sort(
            _cat(rt_lbit), _cat(rt_pbyte), _cat(rt_shift), _cat(rt_sm), _cat(rt_pos))
        self.wc_log, self.wc_pos = sort(_cat(wc_log), _cat(wc_pos))
        tdone = np.concatenate(wt_done).astype(bool) if wt_done else np.zeros(0, bool)
        self.wt_lbit, self.wt_pbyte, self.wt_shift, tdone_i, self.wt_pos = sort(
            _cat(wt_lbit), _cat(wt_pbyte), _cat(wt_shift), tdone.astype(np.int64), _cat(wt_pos))
        self.wt_done: BoolA = tdone_i.astype(bool)
        self.wt_slave: I64 = self.wt_pbyte // stride
        self.wb_slave: I64 = self.wb_phys // stride
        self.wt_clear: U8 = (~(np.left_shift(1, self.wt_shift))).astype(np.uint8)
        # FMMU-level ranges for the working counter (ordered by route position).
        self.f_lo = np.array([c.logical for c in configs], dtype=np.int64)
        self.f_hi = np.array([c.logical + c.length for c in configs], dtype=np.int64)
        self.f_pos = np.array([c.pos for c in configs], dtype=np.int64)
        self.f_read = np.array([c.read for c in configs], dtype=bool)
        self.has_bits = bool(len(self.rt_lbit) or len(self.wt_lbit))
        self.conflicts = self._find_conflicts()
        self.empty = not configs
        self._plans: dict[tuple[int, int, bool, bool], _Plan] = {}

    def _find_conflicts(self) -> I64:
        """Logical bytes whose result depends on the order along the route."""
        read_log = np.concatenate([self.rb_log, self.rt_lbit >> 3])
        read_pos = np.concatenate([self.rb_pos, self.rt_pos])
        write_log = np.concatenate([self.wb_log, self.wt_lbit >> 3])
        write_pos = np.concatenate([self.wb_pos, self.wt_pos])
        bad: list[I64] = []
        if len(read_log) and len(write_log):
            # Earliest reader of each logical byte versus the writers of that byte.
            order = np.lexsort((read_pos, read_log))
            rl, rp = read_log[order], read_pos[order]
            first = np.ones(len(rl), bool)
            first[1:] = rl[1:] != rl[:-1]
            ul, up = rl[first], rp[first]
            idx = np.searchsorted(ul, write_log)
            idx_c = np.minimum(idx, len(ul) - 1)
            hit = (idx < len(ul)) & (ul[idx_c] == write_log) & (up[idx_c] < write_pos)
            bad.append(write_log[hit])
        if len(self.rb_log) and len(self.rt_lbit):
            tb = self.rt_lbit >> 3
            common = np.intersect1d(self.rb_log, tb)
            for b in common.tolist():
                p1 = set(self.rb_pos[self.rb_log == b].tolist())
                p2 = set(self.rt_pos[tb == b].tolist())
                if len(p1 | p2) > 1:
                    bad.append(np.array([b], np.int64))
        if not bad:
            return np.zeros(0, np.int64)
        return np.unique(np.concatenate(bad))

    # --- execution --------------------------------------------------------------------

    def run(self, flat: U8, lo: int, data: U8, reads: bool, writes: bool) -> tuple[int, I64, bool]:
        """Apply a logical datagram: (working counter, slaves whose write SM completed,
        whether an ECAT event request bit was cleared).

        The index slices, the working counter, the completed slaves and the
        buffer reads depend only on (address, length, command), so they are
        computed once per datagram shape and cached: the cyclic cost is a
        gather, a scatter, a placement and the SM status updates.
        """
        key = (lo, len(data), reads, writes)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plan(lo, lo + len(data), reads, writes)
            if len(self._plans) > 4096:
                self._plans.clear()
            self._plans[key] = plan
        if not plan.wkc:
            return 0, plan.done, False
        if plan.ordered:
            done = self._execute_ordered(flat, lo, data, reads, writes)
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

    def _plan(self, lo: int, hi: int, reads: bool, writes: bool) -> _Plan:
        wkc = self.working_counter(lo, hi, reads, writes)
        plan = _Plan(wkc)
        if not wkc:
            return plan
        if len(self.conflicts):
            c0, c1 = np.searchsorted(self.conflicts, (lo, hi))
            plan.ordered = bool(c1 > c0)
        done_parts: list[I64] = []
        if reads:
            self._plan_sm_reads(plan, lo, hi)
            r0, r1 = np.searchsorted(self.rb_log, (lo, hi))
            if r1 > r0:
                plan.r_phys = self.rb_phys[r0:r1].copy()
                plan.r_rel = self.rb_log[r0:r1] - lo
            t0, t1 = np.searchsorted(self.rt_lbit, (lo * 8, hi * 8))
            if t1 > t0:
                plan.t_pbyte = self.rt_pbyte[t0:t1].copy()
                plan.t_shift = self.rt_shift[t0:t1].copy()
                plan.t_rel = self.rt_lbit[t0:t1] - lo * 8
        if writes:
            w0, w1 = np.searchsorted(self.wb_log, (lo, hi))
            if w1 > w0:
                plan.w_phys = self.wb_phys[w0:w1].copy()
                plan.w_rel = self.wb_log[w0:w1] - lo
                d = self.wb_done[w0:w1]
                done_parts.append(self.wb_slave[w0:w1][d])
            b0, b1 = np.searchsorted(self.wt_lbit, (lo * 8, hi * 8))
            if b1 > b0:
                plan.b_pbyte = self.wt_pbyte[b0:b1].copy()
                plan.b_shift = self.wt_shift[b0:b1].copy()
                plan.b_clear = self.wt_clear[b0:b1].copy()
                plan.b_rel = self.wt_lbit[b0:b1] - lo * 8
                d = self.wt_done[b0:b1]
                done_parts.append(self.wt_slave[b0:b1][d])
        if done_parts:
            plan.done = np.unique(np.concatenate(done_parts)).astype(np.int64)
        return plan

    def _plan_sm_reads(self, plan: _Plan, lo: int, hi: int) -> None:
        """The buffered ECAT-read SMs whose last byte this datagram reads, as status updates."""
        smr = self._smr
        if not len(smr.status):
            return
        r0, r1 = np.searchsorted(self.rb_log, (lo, hi))
        t0, t1 = np.searchsorted(self.rt_lbit, (lo * 8, hi * 8))
        ids = np.concatenate([self.rb_sm[r0:r1], self.rt_sm[t0:t1]])
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

    @staticmethod
    def _count(pos: I64) -> int:
        if len(pos) == 0:
            return 0
        return 1 + int(np.count_nonzero(pos[1:] != pos[:-1]))

    def working_counter(self, lo: int, hi: int, reads: bool, writes: bool) -> int:
        """WKC of a logical datagram over [lo, hi): +1 per slave read, +2 (LRW) / +1 (LWR) per slave written."""
        if self.empty:
            return 0
        hit = (self.f_lo < hi) & (self.f_hi > lo)
        wkc = 0
        if reads:
            wkc += self._count(self.f_pos[hit & self.f_read])
        if writes:
            # Per slave: at least one byte it may write (bytes an ECAT-read SM
            # refuses do not count, as for FPWR).
            w0, w1 = np.searchsorted(self.wc_log, (lo, hi))
            nw = len(np.unique(self.wc_pos[w0:w1])) if w1 > w0 else 0
            wkc += 2 * nw if reads else nw
        return wkc

    def _execute_ordered(self, flat: U8, lo: int, data: U8, reads: bool, writes: bool) -> I64:
        """Pass-by-pass processing in route order (only for datagrams over conflicting bytes)."""
        hi = lo + len(data)
        r0, r1 = np.searchsorted(self.rb_log, (lo, hi))
        t0, t1 = np.searchsorted(self.rt_lbit, (lo * 8, hi * 8))
        w0, w1 = np.searchsorted(self.wb_log, (lo, hi))
        b0, b1 = np.searchsorted(self.wt_lbit, (lo * 8, hi * 8))
        positions = sorted(set(self.rb_pos[r0:r1].tolist()) | set(self.rt_pos[t0:t1].tolist())
                           | set(self.wb_pos[w0:w1].tolist()) | set(self.wt_pos[b0:b1].tolist()))
        done: set[int] = set()
        for p in positions:
            arriving = data.copy()
            rsel = np.nonzero(self.rb_pos[r0:r1] == p)[0] + r0 if reads else np.zeros(0, np.int64)
            tsel = np.nonzero(self.rt_pos[t0:t1] == p)[0] + t0 if reads else np.zeros(0, np.int64)
            rvals = flat[self.rb_phys[rsel]]
            tvals = (flat[self.rt_pbyte[tsel]] >> self.rt_shift[tsel]) & 1
            if writes:
                wsel = np.nonzero(self.wb_pos[w0:w1] == p)[0] + w0
                if len(wsel):
                    flat[self.wb_phys[wsel]] = arriving[self.wb_log[wsel] - lo]
                    if self.wb_done[wsel].any():
                        done.update(self.wb_slave[wsel][self.wb_done[wsel]].tolist())
                bsel = np.nonzero(self.wt_pos[b0:b1] == p)[0] + b0
                if len(bsel):
                    lb = self.wt_lbit[bsel] - lo * 8
                    vals = ((arriving[lb >> 3] >> (lb & 7)) & 1).astype(np.uint8)
                    np.bitwise_and.at(flat, self.wt_pbyte[bsel], self.wt_clear[bsel])
                    np.bitwise_or.at(flat, self.wt_pbyte[bsel],
                                     (vals << self.wt_shift[bsel]).astype(np.uint8))
                    if self.wt_done[bsel].any():
                        done.update(self.wt_slave[bsel][self.wt_done[bsel]].tolist())
            if len(rsel):
                data[self.rb_log[rsel] - lo] = rvals
            if len(tsel):
                bits = np.unpackbits(data, bitorder="little")
                bits[self.rt_lbit[tsel] - lo * 8] = tvals
                data[:] = np.packbits(bits, bitorder="little")
        return np.array(sorted(done), dtype=np.int64)
