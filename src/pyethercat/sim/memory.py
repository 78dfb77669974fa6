"""All slaves' ESC memories in one numpy array.

Row ``i`` is the 64 KiB address space of slave ``i`` as the EtherCAT side
sees it. ``shadow`` has the same shape and holds, for each buffered write
sync manager (process-data outputs), the newest *complete* buffer: the copy
the PDI (device application) sees. Logical and broadcast datagrams work on
``flat``/``shadow_flat`` (1-D views) with precomputed index arrays, so their
cost does not grow with a Python loop over slaves.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.wire.registers import ADDRESS_SPACE

__all__ = ["EscMemory"]

U8Array = npt.NDArray[np.uint8]


class EscMemory:
    """Growable (slaves x 65536) uint8 array plus the complete-buffer shadow."""

    def __init__(self, capacity: int = 4) -> None:
        self.count = 0
        #: Bytes per slave row (index of byte ``a`` of slave ``s`` in ``flat``: ``s * stride + a``).
        self.stride = ADDRESS_SPACE
        self._alloc(max(1, capacity))

    def _alloc(self, capacity: int) -> None:
        mem = np.zeros((capacity, ADDRESS_SPACE), dtype=np.uint8)
        shadow = np.zeros((capacity, ADDRESS_SPACE), dtype=np.uint8)
        if self.count:
            mem[: self.count] = self.mem[: self.count]
            shadow[: self.count] = self.shadow[: self.count]
        self.mem: U8Array = mem
        self.shadow: U8Array = shadow
        self.flat: U8Array = mem.reshape(-1)
        self.shadow_flat: U8Array = shadow.reshape(-1)

    @property
    def capacity(self) -> int:
        return int(self.mem.shape[0])

    def add(self) -> int:
        """Add a zeroed slave row; return its index."""
        if self.count == self.capacity:
            self._alloc(self.capacity * 2)
        index = self.count
        self.count += 1
        self.mem[index] = 0
        self.shadow[index] = 0
        return index

    def clear(self, index: int) -> None:
        """Zero one slave's memory and shadow (power-off)."""
        self.mem[index] = 0
        self.shadow[index] = 0
