"""Process-data wiring: output bits of one slave drive input bits of another.

A wire copies bits of a slave's newest complete output buffer (the shadow
the PDI sees) into the input buffer of another slave, as a cable between a
digital output and a digital input terminal would. All wires are compiled
into flat bit index arrays over the memory, so applying them is four array
operations whatever their number.
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
_EMPTY = np.zeros(0, np.int64)


class Wiring:
    """The wires of a segment (see the module docstring)."""

    def __init__(self, memory: EscMemory, escs: Sequence[Esc]) -> None:
        self.memory = memory
        self.escs = escs
        #: (source slave, source bit, destination slave, destination bit, bits)
        self.wires: list[tuple[int, int, int, int, int]] = []
        self._idx: tuple[I64, I64, I64, I64] | None = None

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

    def _compile(self) -> tuple[I64, I64, I64, I64]:
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

        return cat(sb), cat(ss), cat(db), cat(ds)

    def apply(self) -> None:
        """Copy wired output bits (complete buffers) into the inputs they drive."""
        if not self.wires:
            return
        if self._idx is None:
            self._idx = self._compile()
        sb, ss, db, ds = self._idx
        if not len(sb):
            return
        flat = self.memory.flat
        vals = ((self.memory.shadow_flat[sb] >> ss) & 1).astype(np.uint8)
        np.bitwise_and.at(flat, db, (~np.left_shift(1, ds)).astype(np.uint8))
        np.bitwise_or.at(flat, db, (vals << ds).astype(np.uint8))
