"""Clocks for the simulator.

Everything in ``sim/`` that needs time asks a :class:`Clock`. Tests use the
deterministic :class:`VirtualClock` (time moves only when someone advances
it); serving on a real interface uses :class:`WallClock`.
"""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable

__all__ = [
    "Clock",
    "VirtualClock",
    "WallClock",
]


@runtime_checkable
class Clock(Protocol):
    """A source of nanoseconds (monotonic, arbitrary epoch)."""

    def now_ns(self) -> int:
        """Current time in nanoseconds."""
        ...


class VirtualClock:
    """Deterministic clock: starts at ``start_ns`` and moves only by :meth:`advance`."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now = int(start_ns)

    def now_ns(self) -> int:
        """Current virtual time."""
        return self._now

    def advance(self, ns: int) -> int:
        """Move time forward by ``ns`` (>= 0) and return the new time."""
        if ns < 0:
            raise ValueError(f"a virtual clock cannot go back ({ns} ns)")
        self._now += int(ns)
        return self._now

    def set(self, ns: int) -> None:
        """Jump to ``ns`` (must not be earlier than now)."""
        if ns < self._now:
            raise ValueError(f"a virtual clock cannot go back (from {self._now} to {ns} ns)")
        self._now = int(ns)


class WallClock:
    """Real time from :func:`time.monotonic_ns`."""

    def now_ns(self) -> int:
        """Current monotonic time."""
        return time.monotonic_ns()
