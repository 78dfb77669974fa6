"""Logical addressing: the FMMUs of a route compiled into gather/scatter index arrays.

Each logical datagram shape (address, length, command) gets a plan, made the
first time the shape is seen and then cached: the FMMUs of the route that
overlap the datagram's window are resolved, for that window only, into flat
index arrays over the memory array (``EscMemory.flat``), one entry per byte:

- a read entry fills (some bits of) one datagram byte from one or two
  physical bytes: an FMMU maps logical bit j to physical bit j + k for a
  constant k, so a logical byte's bits come from two neighbouring physical
  bytes, shifted (a byte-aligned FMMU: one byte, no shift);
- a write entry fills (some bits of) one physical byte from one or two
  datagram bytes in the same way.

A plan therefore holds at most one read and one write entry per datagram
byte (plus one for a bit offset) and FMMU over it, whatever the FMMUs say:
an FMMU of 64 KiB, or one whose logical range runs past 0xFFFFFFFF (logical
addresses wrap at 32 bits, as the ESC compares them), costs what its part
inside the window costs. Planning expands the entries a few thousand at a
time, and the plan cache is bounded by its entries.

Executing a plan costs a fixed number of numpy operations: a gather for the
read FMMUs, a scatter for the write FMMUs, the placing of the read values.
Bytes read or written whole by one entry are plain copies; entries of the
same byte own disjoint bits (the last on the route wins, within a slave its
last FMMU) and are merged with one OR per further entry of a byte (at most
8). The FMMU rules hold (ESC datasheet section I, "FMMU"; KickCAT
``EmulatedESC.cc`` ``copyFmmu``): a logical byte may be read by one FMMU and
written by another, bit operations leave unmapped bits untouched,
unconfigured logical addresses pass unchanged, a physical byte the chip
lacks is neither read nor written.

Sync managers (ESC datasheet section I, "SyncManager") are compiled in as
well, so that a logical access obeys the same rules as FPRD/FPWR: write
entries whose physical byte lies in an enabled ECAT-read SM (inputs, send
mailbox) are dropped, as the ESC refuses EtherCAT writes there (and they do
not count in the working counter); read entries on the last byte of an
enabled buffered ECAT-read SM complete a buffer read (status 'read event',
the SM's AL event, its ECAT event cleared).

Ordering along the ring matters only for cross traffic: a logical byte read
into the frame by one slave and written from the frame by a later slave
must carry the first slave's value to the second. The plan then runs in
stages, in route order, each starting at such a writer (usually two stages;
a stage is again one gather, scatter and placement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.ma  # noqa: F401  (np.unique imports it lazily: ~12 ms in the first LRW plan compile)
import numpy.typing as npt

from pyethercat.sim.fused import FusedLogical, Publisher, fuse
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import MAX_DATA

__all__ = [
    "SLAVE_STRIDE",
    "DatagramPlan",
    "FmmuConfig",
    "LogicalMap",
    "SmReads",
    "parse_fmmus",
]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
BoolA = npt.NDArray[np.bool_]
I32 = npt.NDArray[np.int32]

SLAVE_STRIDE = R.ADDRESS_SPACE
_SPACE = 1 << 32
_AS = R.ADDRESS_SPACE
#: Plans kept, and index entries kept in all of them (each plan holds at most a
#: few entries per datagram byte and FMMU that covers it).
_PLAN_CACHE = 1024
_CACHE_ENTRIES = 2_000_000
#: Longest datagram a frame carries (a plan made ahead of time is no longer).
_MAX_DATAGRAM = MAX_DATA
_POS_SPAN = 1 << 32
#: Entries expanded at once while planning.
_CHUNK = 1 << 12
_EMPTY = np.zeros(0, np.int64)


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



def _combine(idx: I64, val: U8, op: np.ufunc) -> tuple[I64, U8]:
    """Unique indices with their values combined by ``op`` (one fancy assignment then)."""
    if not len(idx):
        return idx, val
    order = np.argsort(idx, kind="stable")
    idx, val = idx[order], val[order]
    starts, _ = _runs(idx)
    return idx[starts], op.reduceat(val, starts).astype(np.uint8)


def _expand(lo: I64, hi: I64) -> tuple[I64, I64]:
    """Every element of the ranges [lo, hi): (its range's index, its value), ranges in order."""
    counts = hi - lo
    total = int(counts.sum())
    idx = np.repeat(np.arange(len(lo), dtype=np.int64), counts)
    first = np.cumsum(counts) - counts
    vals = np.arange(total, dtype=np.int64) - np.repeat(first - lo, counts)
    return idx, vals


def _chunks(sizes: I64) -> list[I64]:
    """Consecutive groups of the parts of these sizes, each of about :data:`_CHUNK` entries
    (the arrays that expand them stay small whatever the FMMUs)."""
    if not len(sizes):
        return []
    if int(sizes.sum()) <= _CHUNK:
        return [np.arange(len(sizes), dtype=np.int64)]
    group = (np.cumsum(sizes) - sizes) // _CHUNK
    cuts = np.nonzero(np.diff(group))[0] + 1
    return np.split(np.arange(len(sizes), dtype=np.int64), cuts)


def _bit_mask(a: I64, b: I64) -> I64:
    """Per byte: the bits k with a <= k < b (both clipped to 0..8)."""
    return (1 << np.minimum(np.maximum(b, 0), 8)) - (1 << np.minimum(np.maximum(a, 0), 8))


def _lookup(keys: I64, values: I64, q: I64) -> I64:
    """``values`` at the positions of ``q`` in the sorted ``keys``; -1 where absent."""
    if not len(keys):
        return np.full(len(q), -1, np.int64)
    i = np.minimum(np.searchsorted(keys, q), len(keys) - 1)
    return np.where(keys[i] == q, values[i], -1)


def _in_intervals(lo: I64, hi: I64, q: I64) -> BoolA:
    """Whether each ``q`` lies in one of the disjoint, sorted intervals [lo, hi)."""
    if not len(lo):
        return np.zeros(len(q), bool)
    i = np.searchsorted(lo, q, side="right") - 1
    return (i >= 0) & (q < hi[np.maximum(i, 0)])


def _runs(key: I64) -> tuple[I64, I64]:
    """Of a sorted key column: the start of each run of equal keys, and each entry's run."""
    first = np.ones(len(key), bool)
    first[1:] = key[1:] != key[:-1]
    return np.nonzero(first)[0], np.cumsum(first) - 1


def _last_wins(key: I64, mask: U8) -> U8:
    """Per entry (sorted by key, then by precedence): the bits of ``mask`` no later entry
    of the same key covers, so that the entries of one key own disjoint bits."""
    if len(key) < 2 or bool((key[1:] != key[:-1]).all()):
        return mask
    eff = np.zeros(len(key), np.uint8)
    for k in range(8):
        sel = np.nonzero((mask >> k) & 1)[0]
        if not len(sel):
            continue
        ks = key[sel]
        last = np.ones(len(sel), bool)
        last[:-1] = ks[1:] != ks[:-1]
        eff[sel[last]] |= 1 << k
    return eff


class _Side:
    """Entries of one direction: read entries place bits of two gathered source bytes into
    a destination byte, under a mask (a byte entry: the whole of one source byte).

    Reads: destination = window byte, sources = flat memory bytes; writes:
    destination = flat memory byte, sources = window bytes. ``shift`` selects
    the 8 bits of (lo | hi << 8) that land on the destination byte.
    """

    __slots__ = ("dst", "lo", "hi", "shift", "mask", "pos")

    def __init__(self, dst: I64, lo: I64, hi: I64, shift: U8, mask: U8, pos: I32) -> None:
        self.dst, self.lo, self.hi, self.shift, self.mask, self.pos = dst, lo, hi, shift, mask, pos

    @staticmethod
    def join(parts: list[_Side]) -> _Side:
        if len(parts) == 1:
            return parts[0]
        if not parts:
            z = _EMPTY
            return _Side(z, z, z, np.zeros(0, np.uint8), np.zeros(0, np.uint8), np.zeros(0, np.int32))
        return _Side(*(np.concatenate([getattr(p, a) for p in parts]) for a in _Side.__slots__))

    def __len__(self) -> int:
        return len(self.dst)


class _Moves:
    """One side of a stage, compiled: destinations taken whole from one source byte (a plain
    gather and assignment), the others merged bit by bit from their entries (see
    :func:`_last_wins`; a byte has at most 8 entries then, one per layer).

    ``idx`` selects the stage's entries of ``side``, sorted by destination (then
    precedence)."""

    __slots__ = ("whole_src", "whole_dst", "whole_view", "lo", "hi", "shift", "mask", "layers",
                 "dst", "keep", "fused")

    _EMPTY_U8: U8 = np.zeros(0, np.uint8)

    def __init__(self, side: _Side, idx: I64) -> None:
        # (Slices where the indices are one run: the usual image is a copy, not a gather.)
        self.whole_src: I64 | slice | None = None
        self.whole_dst: I64 | slice | None = None
        self.whole_view = False
        self.lo: I64 | None = None
        self.hi: I64 | None = None
        self.shift: npt.NDArray[np.uint16] = np.zeros(0, np.uint16)
        self.mask: U8 = self._EMPTY_U8
        #: Entries past the first of their destination: (start, end, destination numbers).
        self.layers: list[tuple[int, int, I64]] = []
        self.dst: I64 = _EMPTY
        self.keep: U8 = self._EMPTY_U8
        #: Whole and bit entries as one masked move (source, destination, mask, keep), when
        #: every destination has one entry from one source byte: fewer numpy calls per frame.
        self.fused: tuple[I64, I64, U8, U8] | None = None
        dst, mask, shift = side.dst[idx], side.mask[idx], side.shift[idx]
        if bool((mask == 0xFF).all()) and not shift.any() and bool((dst[1:] != dst[:-1]).all()):
            self._whole(side.lo[idx], dst)  # the usual byte-aligned image: nothing to merge
            return
        starts, run = _runs(dst)
        count = np.append(starts[1:], len(idx)) - starts
        whole = (count[run] == 1) & (mask == 0xFF) & (shift == 0)
        if whole.any():
            self._whole(side.lo[idx[whole]], dst[whole])
        rest = np.nonzero(~whole)[0]
        if not len(rest):
            return
        dst = dst[rest]
        eff = _last_wins(dst, mask[rest])
        nz = np.nonzero(eff)[0]
        rest, dst, eff = rest[nz], dst[nz], eff[nz]
        starts, run = _runs(dst)
        self.dst = dst[starts]
        self.keep = (~np.bitwise_or.reduceat(eff, starts)).astype(np.uint8)
        # Layer l: the l-th entry of each destination that has one; layer 0 is every
        # destination in order, so the merge is one OR per further layer.
        rank = np.arange(len(rest)) - starts[run]
        order = np.lexsort((run, rank))
        rank, run = rank[order], run[order]
        bounds = np.searchsorted(rank, np.arange(int(rank[-1]) + 2)).tolist()
        self.layers = [(a, b, run[a:b]) for a, b in zip(bounds[1:-1], bounds[2:], strict=True)]
        sel = idx[rest[order]]
        self.lo, self.shift, self.mask = side.lo[sel], side.shift[sel].astype(np.uint16), eff[order].astype(np.uint8)
        # (No second source byte when every entry takes its bits from one byte.)
        self.hi = side.hi[sel] if self.shift.any() else None
        if self.hi is None and not self.layers and self.whole_src is not None and self.whole_dst is not None:
            ws, wd = _indices(self.whole_src), _indices(self.whole_dst)
            self.fused = (np.concatenate([ws, self.lo]), np.concatenate([wd, self.dst]),
                          np.concatenate([np.full(len(ws), 0xFF, np.uint8), self.mask]),
                          np.concatenate([np.zeros(len(ws), np.uint8), self.keep]))

    def _whole(self, src: I64, dst: I64) -> None:
        self.whole_src, self.whole_dst = _run(src), _run(dst)
        self.whole_view = isinstance(self.whole_src, slice)

    def merged(self, src: U8) -> U8:
        """The merged bits of each destination of the bit entries, from source ``src``."""
        assert self.lo is not None
        if self.hi is None:
            v = src[self.lo] & self.mask
        else:
            v = (((src[self.lo].astype(np.uint16) | (src[self.hi].astype(np.uint16) << 8))
                  >> self.shift).astype(np.uint8) & self.mask)
        if not self.layers:
            return v
        acc = v[: len(self.dst)]
        for a, b, ids in self.layers:
            acc[ids] |= v[a:b]
        return acc


def _indices(idx: I64 | slice) -> I64:
    """An index run (a slice) as an index array."""
    if isinstance(idx, slice):
        return np.arange(idx.start, idx.stop, dtype=np.int64)
    return idx


class _Stage:
    """Slaves of the route whose reads and writes may be applied at once: a gather of what
    they read, a scatter of what they write, the placing of the reads."""

    __slots__ = ("reads", "writes")

    def __init__(self, reads: _Side, r_idx: I64, writes: _Side, w_idx: I64) -> None:
        self.reads = _Moves(reads, r_idx) if len(r_idx) else None
        self.writes = _Moves(writes, w_idx) if len(w_idx) else None

    def gather(self, flat: U8) -> tuple[U8 | None, U8 | None]:
        """What the slaves read (before their writes): :meth:`place` puts it in a frame."""
        r = self.reads
        rvals = tvals = None
        if r is not None:
            if r.fused is not None:
                tvals = flat[r.fused[0]] & r.fused[2]
            elif r.whole_src is not None:
                rvals = flat[r.whole_src]
                if r.whole_view:
                    rvals = rvals.copy()
                if r.lo is not None:
                    tvals = r.merged(flat)
            elif r.lo is not None:
                tvals = r.merged(flat)
        return rvals, tvals

    def place(self, data: U8, got: tuple[U8 | None, U8 | None]) -> None:
        """Put what :meth:`gather` read into the datagram's bytes ``data``."""
        r = self.reads
        if r is None:
            return
        rvals, tvals = got
        if r.fused is not None:
            assert tvals is not None
            data[r.fused[1]] = (data[r.fused[1]] & r.fused[3]) | tvals
            return
        if rvals is not None:
            data[r.whole_dst] = rvals
        if tvals is not None:
            data[r.dst] = (data[r.dst] & r.keep) | tvals

    def write(self, flat: U8, data: U8) -> None:
        """Write the datagram's bytes as they arrived (``data``) into the memory."""
        w = self.writes
        if w is None:
            return
        if w.fused is not None:
            f_src, f_dst, f_mask, f_keep = w.fused
            flat[f_dst] = (flat[f_dst] & f_keep) | (data[f_src] & f_mask)
        else:
            if w.whole_src is not None:
                flat[w.whole_dst] = data[w.whole_src]
            if w.lo is not None:
                flat[w.dst] = (flat[w.dst] & w.keep) | w.merged(data)

    def apply(self, flat: U8, data: U8) -> None:
        """Gather first (a slave reads its memory as it was), scatter the data as it
        arrived (``data`` is unchanged until the reads are placed), then place."""
        got = self.gather(flat)
        self.write(flat, data)
        self.place(data, got)


class DatagramPlan:
    """One logical datagram shape compiled (``LogicalMap.plan``): its working counter,
    the stages that move its data, the slaves whose write buffers it completes,
    and its register updates as one program (``fused``)."""

    __slots__ = ("wkc", "stages", "done", "or_idx", "or_val", "and_idx", "and_val", "and_hit",
                 "size", "fused")

    def __init__(self, wkc: int) -> None:
        self.wkc = wkc
        #: One stage, or (cross traffic) several in route order.
        self.stages: list[_Stage] = []
        #: Slaves whose write SM this datagram completes.
        self.done: I64 = _EMPTY
        #: Buffer-read completion: status/AL event bytes to OR, ECAT event bytes to AND.
        self.or_idx: I64 | None = None
        self.or_val: U8 | None = None
        self.and_idx: I64 | None = None
        self.and_val: U8 | None = None
        self.and_hit: U8 | None = None
        #: Index entries the plan holds (for the cache bound).
        self.size = 0
        #: Its register updates and the publish of the buffers it completes as one
        #: program (``sim.fused``), compiled with the plan (None: nothing to do, wkc 0).
        self.fused: FusedLogical | None = None

    @property
    def ordered(self) -> bool:
        """Whether the datagram is applied in several stages (cross traffic)."""
        return len(self.stages) > 1


class LogicalMap:
    """The FMMUs of a route (see the module docstring).

    ``writable[slave]`` is the slave's ECAT-writable byte mask (written bytes
    outside it are dropped), ``implemented[slave]`` the bytes its chip has;
    ``complete[slave]`` lists the last bytes of the slave's enabled buffered
    write SMs (a write there completes a buffer); ``publisher`` (the SM areas)
    says what completing them does, compiled into each plan (``sim.fused``).
    """

    def __init__(self, configs: list[FmmuConfig], writable: list[npt.NDArray[np.bool_]],
                 complete: dict[int, set[int]], implemented: list[npt.NDArray[np.bool_]],
                 sm_reads: SmReads | None, stride: int, publisher: Publisher) -> None:
        self.configs = configs
        self._publisher = publisher
        smr = sm_reads if sm_reads is not None else SmReads.empty()
        self._smr = smr
        self._stride = stride
        self.empty = not configs

        def col(attr: str) -> I64:
            return np.array([getattr(c, attr) for c in configs], dtype=np.int64)

        # FMMU-level arrays: a window's FMMUs are found, and its entries expanded,
        # with array operations.
        self.f_lo, self.f_len, self.f_pos, self.f_slave = col("logical"), col("length"), col("pos"), col("slave")
        self.f_sbit, self.f_bits = col("start_bit"), col("bits")
        self.f_phys_bit = 8 * col("physical") + col("physical_bit")
        self.f_read = np.array([c.read for c in configs], dtype=bool)
        self.f_write = np.array([c.write for c in configs], dtype=bool)
        # Per slave of an FMMU: implemented and writable bytes, one table row per
        # distinct mask (the chips of one profile share theirs).
        slaves = sorted({c.slave for c in configs})
        self._impl, self._impl_row = _mask_table(implemented, slaves)
        self._wr, self._wr_row = _mask_table(writable, slaves)
        # Keyed by slave * 64 KiB + byte: refused ranges (merged), the last bytes of
        # buffered ECAT-read SMs (SmReads entry) and of buffered write SMs.
        ranges = sorted((s * _AS + a, s * _AS + b) for s, rs in smr.refused.items() for a, b in rs if b > a)
        merged: list[list[int]] = []
        for a, b in ranges:
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        self._ref_lo = np.array([m[0] for m in merged], np.int64)
        self._ref_hi = np.array([m[1] for m in merged], np.int64)
        last = sorted((s * _AS + byte, k) for s, d in smr.last.items() for byte, k in d.items())
        self._last_key = np.array([k for k, _ in last], np.int64)
        self._last_id = np.array([v for _, v in last], np.int64)
        self._done_key = np.array(sorted(s * _AS + b for s, bs in complete.items() for b in bs), np.int64)
        self._plans: dict[tuple[int, int, bool, bool], DatagramPlan] = {}
        self._plan_entries = 0

    # --- execution --------------------------------------------------------------------

    def plan_keys(self) -> list[tuple[int, int, bool, bool]]:
        """The datagram shapes (address, length, reads, writes) planned so far."""
        return list(self._plans)

    def plan_size(self, address: int, length: int, reads: bool = True, writes: bool = True) -> int | None:
        """Index entries held by the plan of this datagram shape (None: not planned yet)."""
        plan = self._plans.get((address, length, reads, writes))
        return None if plan is None else plan.size

    def span_key(self) -> tuple[int, int, bool, bool] | None:
        """The shape of one LRW over every mapped byte (what most masters send), or None."""
        if self.empty:
            return None
        lo = int(self.f_lo.min())
        return lo, min(int((self.f_lo + self.f_len).max()) - lo, _MAX_DATAGRAM), True, True

    def prepare(self, keys: list[tuple[int, int, bool, bool]]) -> None:
        """Plan these datagram shapes now (those a previous map had seen)."""
        for key in keys[:_PLAN_CACHE]:
            self.plan(*key)

    def plan(self, lo: int, n: int, reads: bool, writes: bool) -> DatagramPlan:
        """The (cached) plan of a logical datagram of ``n`` bytes at ``lo``."""
        key = (lo, n, reads, writes)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plan(lo, n, reads, writes)
            if len(self._plans) >= _PLAN_CACHE or self._plan_entries > _CACHE_ENTRIES:
                self._plans.clear()
                self._plan_entries = 0
            self._plans[key] = plan
            self._plan_entries += plan.size
        return plan

    # --- plans ---------------------------------------------------------------------------

    def _overlapping(self, lo: int, n: int) -> I64:
        """Indices of the FMMUs with a byte in the window (32-bit wrap included)."""
        if self.empty:
            return _EMPTY
        d = (lo - self.f_lo) % _SPACE
        hit = (d < self.f_len) | (d + n > _SPACE)
        return np.nonzero(hit)[0]

    def _pieces(self, lo: int, n: int, fmmus: I64) -> tuple[I64, I64, I64, I64]:
        """The FMMUs' parts inside the window [lo, lo + n) of the 32-bit logical space (an FMMU
        across the end of the space has two): (FMMU, first window bit, end window bit, the
        physical bit of window bit 0), in FMMU order."""
        d = (lo - self.f_lo[fmmus]) % _SPACE  # FMMU offset of the window's first byte
        start = np.concatenate([d, d - _SPACE])
        f = np.concatenate([fmmus, fmmus])
        i0 = np.maximum(start, 0)
        i1 = np.minimum(start + n, self.f_len[f])
        ok = np.nonzero(i1 > i0)[0]
        ok = ok[np.argsort(f[ok], kind="stable")]
        f, start, i0, i1 = f[ok], start[ok], i0[ok], i1[ok]
        sbit = self.f_sbit[f]
        # FMMU bits j (from the first logical byte's bit 0) sit at window bit 8 * start + j.
        j0 = np.maximum(8 * i0, sbit)
        j1 = np.minimum(8 * i1, sbit + self.f_bits[f])
        ok = np.nonzero(j1 > j0)[0]
        f, start, j0, j1, sbit = f[ok], start[ok], j0[ok], j1[ok], sbit[ok]
        # Physical bit = window bit + k for every bit of the FMMU.
        k = self.f_phys_bit[f] - sbit + 8 * start
        return f, j0 - 8 * start, j1 - 8 * start, k

    def _reads(self, f: I64, w0: I64, w1: I64, k: I64) -> tuple[_Side, I64]:
        """Read entries, one per window byte of each read part; and the SmReads entries of the
        buffered ECAT-read SMs whose last byte they read."""
        parts: list[_Side] = []
        sms: list[I64] = []
        b0, b1 = w0 >> 3, ((w1 - 1) >> 3) + 1
        for c in _chunks(b1 - b0):
            pi, b = _expand(b0[c], b1[c])
            pi = c[pi]
            kk, slave = k[pi], self.f_slave[f[pi]]
            mask = _bit_mask(w0[pi] - 8 * b, w1[pi] - 8 * b)
            # Window byte b bit i is physical bit 8 * b + k + i: bits 0..7-r of
            # byte b + q, the others of byte b + q + 1.
            r = kk & 7
            plo = b + (kk >> 3)
            phi = plo + 1
            low = (1 << (8 - r)) - 1
            lo_ok = ((mask & low) != 0) & (plo >= 0) & (plo < _AS)
            lo_ok[lo_ok] = self._impl[self._impl_row[slave[lo_ok]], plo[lo_ok]]
            hi_ok = ((mask & ~low) != 0) & (phi < _AS)
            hi_ok[hi_ok] = self._impl[self._impl_row[slave[hi_ok]], phi[hi_ok]]
            bits = (np.where(lo_ok, mask & low, 0) | np.where(hi_ok, mask & ~low & 0xFF, 0)).astype(np.uint8)
            if len(self._last_key):
                sms.append(_lookup(self._last_key, self._last_id, slave[lo_ok] * _AS + plo[lo_ok]))
                sms.append(_lookup(self._last_key, self._last_id, slave[hi_ok] * _AS + phi[hi_ok]))
            keep = np.nonzero(bits)[0]
            base = slave[keep] * self._stride
            lo_ok, hi_ok, plo, phi = lo_ok[keep], hi_ok[keep], plo[keep], phi[keep]
            parts.append(_Side(b[keep], np.where(lo_ok, plo, phi) + base, np.where(hi_ok, phi, plo) + base,
                               r[keep].astype(np.uint8), bits[keep],
                               self.f_pos[f[pi[keep]]].astype(np.int32)))
        sm = np.concatenate(sms) if sms else _EMPTY
        return _Side.join(parts), sm[sm >= 0]

    def _writes(self, f: I64, w0: I64, w1: I64, k: I64, n: int) -> tuple[_Side, I64, I64]:
        """Write entries, one per physical byte of each write part; the route positions that
        count a write (a byte an ECAT-read SM refuses does not); the slaves whose write SM
        a write completes."""
        parts: list[_Side] = []
        counted: list[I64] = []
        dones: list[I64] = []
        p0, p1 = w0 + k, w1 + k
        q0, q1 = p0 >> 3, ((p1 - 1) >> 3) + 1
        for c in _chunks(q1 - q0):
            pi, p = _expand(q0[c], q1[c])
            pi = c[pi]
            kk, slave, pos = k[pi], self.f_slave[f[pi]], self.f_pos[f[pi]]
            mask = _bit_mask(p0[pi] - 8 * p, p1[pi] - 8 * p)
            key = slave * _AS + p
            inside = p < _AS
            refused = inside & _in_intervals(self._ref_lo, self._ref_hi, key)
            counted.append(np.unique(pos[~refused]))
            ok = inside & ~refused
            ok[ok] = self._wr[self._wr_row[slave[ok]], p[ok]]
            keep = np.nonzero(ok)[0]
            # Physical byte p bit i is window bit 8 * p - k + i: bits of window bytes a, a + 1.
            src = 8 * p[keep] - kk[keep]
            a = src >> 3
            parts.append(_Side(p[keep] + slave[keep] * self._stride, np.minimum(np.maximum(a, 0), n - 1),
                               np.minimum(a + 1, n - 1), (src & 7).astype(np.uint8),
                               mask[keep].astype(np.uint8), pos[keep].astype(np.int32)))
            if len(self._done_key):
                dones.append(slave[keep][np.isin(key[keep], self._done_key)])
        return (_Side.join(parts), np.unique(np.concatenate(counted)) if counted else _EMPTY,
                np.concatenate(dones) if dones else _EMPTY)

    def _plan(self, lo: int, n: int, reads: bool, writes: bool) -> DatagramPlan:
        fmmus = self._overlapping(lo, n)
        if not len(fmmus) or n == 0:
            return DatagramPlan(0)
        f, w0, w1, k = self._pieces(lo, n, fmmus)
        rd = self.f_read[f] if reads else np.zeros(len(f), bool)
        wr = self.f_write[f] if writes else np.zeros(len(f), bool)
        wkc = len(np.unique(self.f_pos[f[rd]]))
        rs, sm = self._reads(f[rd], w0[rd], w1[rd], k[rd])
        ws, counted, done = self._writes(f[wr], w0[wr], w1[wr], k[wr], n)
        # Per slave: at least one byte it may write (bytes an ECAT-read SM
        # refuses do not count, as for FPWR).
        wkc += 2 * len(counted) if reads else len(counted)
        plan = DatagramPlan(wkc)
        if not wkc:
            return plan
        # Last reader on the route wins (within a slave: its last FMMU).
        r_idx = np.lexsort((rs.pos, rs.dst))
        w_idx = np.argsort(ws.dst, kind="stable")
        plan.size = len(rs) + len(ws)
        cuts = _stage_starts(rs.dst[r_idx], rs.pos[r_idx], ws)
        if not cuts:
            plan.stages = [_Stage(rs, r_idx, ws, w_idx)]
        else:
            plan.stages = [_Stage(rs, r, ws, w) for r, w in zip(_split(rs.pos, r_idx, cuts),
                                                                  _split(ws.pos, w_idx, cuts), strict=True)]
        if len(done):
            plan.done = np.unique(done)
        if len(sm):
            self._plan_sm_reads(plan, np.unique(sm))
        plan.fused = fuse(plan, self._publisher)
        return plan

    def _plan_sm_reads(self, plan: DatagramPlan, ids: I64) -> None:
        """The buffered ECAT-read SMs whose last byte this datagram reads, as status updates."""
        smr = self._smr
        al = smr.al_bit[ids] != 0
        or_idx = np.concatenate([smr.status[ids], smr.al_byte[ids][al]])
        or_val = np.concatenate([np.full(len(ids), R.SM_STATUS_READ_EVENT, np.uint8), smr.al_bit[ids][al]])
        plan.or_idx, plan.or_val = _combine(or_idx, or_val, np.bitwise_or)
        ev = smr.ev_bit[ids] != 0
        if ev.any():
            and_idx, hit = _combine(smr.ev_byte[ids][ev], smr.ev_bit[ids][ev], np.bitwise_or)
            plan.and_idx, plan.and_hit = and_idx, hit
            plan.and_val = (~hit).astype(np.uint8)


#: Stacked mask tables by the masks they stack (the masks are kept alive with them, so an
#: id stays theirs); chips of one profile share their masks, so a segment needs few.
_TABLES: dict[tuple[int, ...], tuple[tuple[npt.NDArray[np.bool_], ...], npt.NDArray[np.bool_]]] = {}


def _mask_table(masks: list[npt.NDArray[np.bool_]], slaves: list[int]) -> tuple[npt.NDArray[np.bool_], I64]:
    """The distinct masks of ``slaves`` stacked, and per slave index its row (0 elsewhere)."""
    rows: dict[int, int] = {}
    stack: list[npt.NDArray[np.bool_]] = []
    row = np.zeros(max(slaves, default=0) + 1, np.int64)
    for s in slaves:
        m = masks[s]
        r = rows.get(id(m))
        if r is None:
            r = rows[id(m)] = len(stack)
            stack.append(m)
        row[s] = r
    if not stack:
        return np.zeros((1, _AS), bool), row
    key = tuple(id(m) for m in stack)
    hit = _TABLES.get(key)
    if hit is None:
        if len(_TABLES) >= 64:
            _TABLES.clear()
        hit = _TABLES[key] = (tuple(stack), np.stack(stack))
    return hit[1], row


def _split(pos: I32, idx: I64, cuts: list[int]) -> list[I64]:
    """``idx`` cut into stages (stages start at the route positions ``cuts``), each in order."""
    stage = np.searchsorted(np.array(cuts, np.int64), pos[idx], side="right")
    order = np.argsort(stage, kind="stable")
    bounds = np.searchsorted(stage[order], np.arange(len(cuts) + 2)).tolist()
    idx = idx[order]
    return [idx[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _stage_starts(r_dst: I64, r_pos: I32, ws: _Side) -> list[int]:
    """Route positions where a new stage must start: a slave writes a window byte that an
    earlier slave of the same stage read into the frame (it must see that value). The
    read entries come sorted by (window byte, position)."""
    if not len(r_dst) or not len(ws):
        return []
    # Window bytes each write entry takes bits from: bits 0..7-s of the first, the
    # others of the second.
    s, m = ws.shift.astype(np.int64), ws.mask.astype(np.int64)
    one = (m & ((1 << (8 - s)) - 1)) != 0
    two = (m >> (8 - s)) != 0
    src = np.concatenate([ws.lo[one], ws.hi[two]])
    wpos = np.concatenate([ws.pos[one], ws.pos[two]])
    # Latest reader before the writer, per (byte, writer): read entries are sorted by
    # (window byte, position).
    rkey = r_dst * _POS_SPAN + r_pos
    i = np.searchsorted(rkey, src * _POS_SPAN + wpos) - 1
    ic = np.maximum(i, 0)
    prev = np.where((i >= 0) & (r_dst[ic] == src), r_pos[ic], -1)
    hit = prev >= 0
    if not hit.any():
        return []
    # Per writer position, the latest such reader; a stage starting after it holds both apart.
    wpos, prev = wpos[hit], prev[hit]
    order = np.lexsort((prev, wpos))
    wpos, prev = wpos[order], prev[order]
    last = np.ones(len(wpos), bool)
    last[:-1] = wpos[1:] != wpos[:-1]
    cuts: list[int] = []
    start = -1
    for q, p in zip(wpos[last].tolist(), prev[last].tolist(), strict=True):
        if p >= start:
            start = q
            cuts.append(q)
    return cuts


def _run(rel: I64) -> I64 | slice:
    """``rel`` as a slice when it is consecutive offsets, else itself."""
    first = int(rel[0])
    if int(rel[-1]) - first == len(rel) - 1 and bool((rel[1:] - rel[:-1] == 1).all()):
        return slice(first, first + len(rel))
    return rel
