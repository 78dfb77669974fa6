"""All slaves' ESC memories in one numpy array.

Row ``i`` is the address space of slave ``i`` as the EtherCAT side sees it,
from 0x0000 up to ``stride``: the registers (0x0000-0x0FFF) and the process
RAM of the largest chip in the segment (``EscProfile.ram_end``: 0x1400 for an
ET1200's 1 KiB, 0x3000 for an ET1100's 8 KiB). Addresses at or above a chip's
RAM end are not implemented: reads give zeros, writes are dropped, and no
compiled index reaches past a row. ``shadow`` has the same shape and holds,
for each buffered write sync manager (process-data outputs), the newest
*complete* buffer: the copy the PDI (device application) sees. Logical and
broadcast datagrams work on ``flat``/``shadow_flat`` (1-D views) with
precomputed index arrays, so their cost does not grow with a Python loop over
slaves. Adding a chip with more RAM than the stride widens every row (the
segment then recompiles everything that holds flat indices).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.wire.registers import ADDRESS_SPACE, RAM_START

__all__ = ["EscMemory"]

U8Array = npt.NDArray[np.uint8]


class EscMemory:
    """Growable (slaves x stride) uint8 array plus the complete-buffer shadow."""

    def __init__(self, capacity: int = 4, stride: int = RAM_START) -> None:
        self.count = 0
        #: Bytes per slave row (index of byte ``a`` of slave ``s`` in ``flat``:
        #: ``s * stride + a``); a multiple of 8, at most 64 KiB.
        self.stride = self._round(stride)
        self._alloc(max(1, capacity), self.stride)

    @staticmethod
    def _round(size: int) -> int:
        return min(-(-max(size, RAM_START) // 8) * 8, ADDRESS_SPACE)

    def _alloc(self, capacity: int, stride: int) -> None:
        mem = np.zeros((capacity, stride), dtype=np.uint8)
        shadow = np.zeros((capacity, stride), dtype=np.uint8)
        if self.count:
            old = self.stride
            mem[: self.count, :old] = self.mem[: self.count]
            shadow[: self.count, :old] = self.shadow[: self.count]
        self.stride = stride
        self.mem: U8Array = mem
        self.shadow: U8Array = shadow
        self.flat: U8Array = mem.reshape(-1)
        self.shadow_flat: U8Array = shadow.reshape(-1)

    @property
    def capacity(self) -> int:
        return int(self.mem.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes held by the memory and shadow arrays (their capacity)."""
        return int(self.mem.nbytes + self.shadow.nbytes)

    def fit(self, ram_end: int) -> bool:
        """Widen the rows to hold ``ram_end`` bytes; True when the stride changed."""
        stride = self._round(ram_end)
        if stride <= self.stride:
            return False
        self._alloc(self.capacity, stride)
        return True

    def add(self, ram_end: int = RAM_START) -> int:
        """Add a zeroed slave row (wide enough for ``ram_end``); return its index."""
        self.fit(ram_end)
        if self.count == self.capacity:
            self._alloc(self.capacity * 2, self.stride)
        index = self.count
        self.count += 1
        self.mem[index] = 0
        self.shadow[index] = 0
        return index

    def clear(self, index: int) -> None:
        """Zero one slave's memory and shadow (power-off)."""
        self.mem[index] = 0
        self.shadow[index] = 0
