"""Process-data wiring: output bits of one slave drive input bits of another.

A wire copies bits of a slave's newest complete output buffer (the shadow
the PDI sees) into the input buffer of another slave, as a cable between a
digital output and a digital input terminal would. All wires are compiled
into flat index arrays over the memory, so applying them is a fixed number
of array operations whatever their number: destination bytes that take all
eight bits of one source byte in place (the usual byte-aligned wire) are a
plain gather and scatter; the other bits are looked up in a table of
(source bit, destination bit, source byte) and OR-ed per destination byte.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError
from pyethercat.sim.esc import Esc
from pyethercat.sim.memory import EscMemory

__all__ = ["Wiring"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
_EMPTY = np.zeros(0, np.int64)


def _bit_table() -> U8:
    """``_BITS[256 * (8 * ss + ds) + v]``: bit ``ss`` of byte value ``v`` placed at bit ``ds``."""
    v = np.arange(256, dtype=np.int64)
    rows = [((v >> ss) & 1) << ds for ss in range(8) for ds in range(8)]
    return np.concatenate(rows).astype(np.uint8)


_BITS = _bit_table()


class _Compiled:
    """The wires as index arrays (see the module docstring)."""

    __slots__ = ("copy_src", "copy_dst", "bit_src", "bit_code", "bit_dst", "starts", "keep")

    def __init__(self, sb: I64, ss: I64, db: I64, ds: I64) -> None:
        # Per destination byte, in order: its entries (stable, so wire order within a byte).
        order = np.argsort(db, kind="stable")
        sb, ss, db, ds = sb[order], ss[order], db[order], ds[order]
        starts = np.nonzero(np.append(True, db[1:] != db[:-1]))[0] if len(db) else _EMPTY
        # All eight bits, each once, from one source byte at the same bit positions.
        count = np.append(starts[1:], len(db)) - starts
        run = np.repeat(np.arange(len(starts)), count)
        same = (sb == sb[starts][run]) & (ss == ds)
        whole = ((count == 8) & np.logical_and.reduceat(same, starts)
                 & (np.bitwise_or.reduceat(np.left_shift(1, ds), starts) == 0xFF)) if len(db) else same
        self.copy_src: I64 = sb[starts[whole]]
        self.copy_dst: I64 = db[starts[whole]]
        rest = np.nonzero(~whole[run])[0]
        self.bit_src: I64 = sb[rest]
        self.bit_code: I64 = 256 * (8 * ss[rest] + ds[rest])
        rdb = db[rest]
        rstarts = np.nonzero(np.append(True, rdb[1:] != rdb[:-1]))[0] if len(rdb) else _EMPTY
        self.bit_dst: I64 = rdb[rstarts]
        #: Entries of each destination byte (None: one entry per byte, nothing to combine).
        self.starts: I64 | None = rstarts if len(rstarts) != len(rdb) else None
        # Bits any wire drives are cleared first (a byte may also hold undriven bits).
        clear = (np.left_shift(1, ds[rest]) & 0xFF).astype(np.uint8)
        self.keep: U8 = (~np.bitwise_or.reduceat(clear, rstarts)).astype(np.uint8) if len(rdb) else np.zeros(
            0, np.uint8)


class Wiring:
    """The wires of a segment (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc]) -> None:
        self.memory = memory
        self.escs = escs
        #: (source slave, source bit, destination slave, destination bit, bits)
        self.wires: list[tuple[int, int, int, int, int]] = []
        self._idx: _Compiled | None = None

    def add(self, src_slave: int, src_bit: int, dst_slave: int, dst_bit: int, bits: int,
            slaves: int) -> None:
        if not (0 <= src_slave < slaves and 0 <= dst_slave < slaves) or bits <= 0 or src_bit < 0 or dst_bit < 0:
            raise ConfigError(f"bad wire {src_slave}.{src_bit} -> {dst_slave}.{dst_bit} ({bits} bits)")
        self.wires.append((src_slave, src_bit, dst_slave, dst_bit, bits))
        self._idx = None

    def invalidate(self) -> None:
        """SM configuration changed: compile again before the next use."""
        self._idx = None

    def _sm_start(self, slave: int, n: int) -> int | None:
        """Start of SM ``n`` of ``slave`` (enabled, else as its SII describes it)."""
        esc = self.escs[slave]
        if n < esc.profile.sm_count:
            s = esc.sm(n)
            if s.enabled:
                return int(s.start)
        if esc.sii_info is not None:
            sms = esc.sii_info.sync_managers
            if n < len(sms):
                return int(sms[n].start)
        return None

    def _compile(self) -> _Compiled:
        stride = self.memory.stride
        sb, ss, db, ds = [], [], [], []
        for src, sbit, dst, dbit, bits in self.wires:
            s0 = self._sm_start(src, self.escs[src].output_sm)
            d0 = self._sm_start(dst, self.escs[dst].input_sm)
            if s0 is None or d0 is None:
                continue
            k = np.arange(bits, dtype=np.int64)
            sbits = s0 * 8 + sbit + k
            dbits = d0 * 8 + dbit + k
            sb.append(src * stride + (sbits >> 3))
            ss.append(sbits & 7)
            db.append(dst * stride + (dbits >> 3))
            ds.append(dbits & 7)

        def cat(x: list[I64]) -> I64:
            return np.concatenate(x) if x else _EMPTY

        return _Compiled(cat(sb), cat(ss), cat(db), cat(ds))

    def apply(self) -> None:
        """Copy wired output bits (complete buffers) into the inputs they drive."""
        if not self.wires:
            return
        if self._idx is None:
            self._idx = self._compile()
        c = self._idx
        shadow = self.memory.shadow_flat
        flat = self.memory.flat
        if len(c.copy_dst):
            flat[c.copy_dst] = shadow[c.copy_src]
        if len(c.bit_dst):
            vals = _BITS[c.bit_code + shadow[c.bit_src]]
            if c.starts is not None:
                vals = np.bitwise_or.reduceat(vals, c.starts)
            dst = c.bit_dst
            flat[dst] = (flat[dst] & c.keep) | vals
