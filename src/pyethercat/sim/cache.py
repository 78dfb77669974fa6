"""Caches of compiled index arrays keyed by an array of slaves (or instances).

The frame path hands the same index array objects around every cycle (a
cached FMMU plan's completed slaves, a model's instance groups), so a
lookup by object identity finds a compiled plan without hashing the array's
bytes (hashing 1,000 slave indices costs more than the numpy work it
selects). Arrays met for the first time fall back to a lookup by content.
The cache keeps a reference to every key array, so an identity never
stands for another array; key arrays must not be changed in place.
"""

from __future__ import annotations

from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

__all__ = ["ArrayKeyCache"]

V = TypeVar("V")


class ArrayKeyCache(Generic[V]):
    """Values by index array, found by identity first, then by content (see the module docstring)."""

    __slots__ = ("_by_id", "_by_bytes", "limit")

    def __init__(self, limit: int = 1024) -> None:
        self._by_id: dict[int, tuple[npt.NDArray[np.int64], V]] = {}
        self._by_bytes: dict[bytes, V] = {}
        self.limit = limit

    def get(self, key: npt.NDArray[np.int64]) -> V | None:
        hit = self._by_id.get(id(key))
        if hit is not None and hit[0] is key:
            return hit[1]
        value = self._by_bytes.get(key.tobytes())
        if value is not None:
            self._remember(key, value)
        return value

    def put(self, key: npt.NDArray[np.int64], value: V) -> None:
        if len(self._by_bytes) >= self.limit:
            self.clear()
        self._by_bytes[key.tobytes()] = value
        self._remember(key, value)

    def _remember(self, key: npt.NDArray[np.int64], value: V) -> None:
        if len(self._by_id) >= self.limit:
            self._by_id.clear()
        self._by_id[id(key)] = (key, value)

    def clear(self) -> None:
        self._by_id.clear()
        self._by_bytes.clear()
