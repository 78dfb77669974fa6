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
    """Deterministic clock: starts at ``start_ns`` and moves only by :meth:`advance`.

    ``ns`` is the current time as a public attribute: the simulator's frame
    path reads it and adds each frame's wire time to it directly (two method
    calls would cost about 7 % of a small frame). Anyone else moves time with
    :meth:`advance` or :meth:`set`, which refuse to go back.
    """

    __slots__ = ("ns",)

    def __init__(self, start_ns: int = 0) -> None:
        self.ns = int(start_ns)

    def now_ns(self) -> int:
        """Current virtual time."""
        return self.ns

    def advance(self, ns: int) -> int:
        """Move time forward by ``ns`` (>= 0) and return the new time."""
        if ns < 0:
            raise ValueError(f"a virtual clock cannot go back ({ns} ns)")
        self.ns += int(ns)
        return self.ns

    def set(self, ns: int) -> None:
        """Jump to ``ns`` (must not be earlier than now)."""
        if ns < self.ns:
            raise ValueError(f"a virtual clock cannot go back (from {self.ns} to {ns} ns)")
        self.ns = int(ns)


class WallClock:
    """Real time from :func:`time.monotonic_ns`."""

    def now_ns(self) -> int:
        """Current monotonic time."""
        return time.monotonic_ns()
