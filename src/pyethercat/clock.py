"""Time sources shared by the master and the simulator.

Everything in pyethercat that needs time asks one of these objects instead of
calling :mod:`time` itself, so a test can swap real time for a
:class:`VirtualClock` that moves only when told to:

- :class:`TimeSource`: ``now_ns()``, monotonic nanoseconds from an arbitrary
  epoch (all the simulator needs);
- :class:`Clock`: a time source that can also wait, ``sleep_until(deadline_ns)``
  (the master's cyclic loop and its scheduler);
- :class:`WallClock`: real time from :func:`time.monotonic_ns`, sleeping with
  :func:`time.sleep`;
- :class:`PerfClock`: :func:`time.perf_counter_ns`, sleeping and then
  busy-waiting the last slice before a deadline (the cyclic loop's default);
- :class:`VirtualClock`: deterministic; ``sleep_until`` jumps, ``advance``
  models time spent working.

``wire/`` keeps no clock: codecs take times as arguments. This module is the
only place below ``master/`` and ``sim/`` that reads the system's clocks.
"""

from __future__ import annotations

import time
from typing import Protocol, runtime_checkable

__all__ = [
    "Clock",
    "PerfClock",
    "TimeSource",
    "VirtualClock",
    "WallClock",
    "is_virtual",
    "sleep_for",
]


@runtime_checkable
class TimeSource(Protocol):
    """A source of nanoseconds (monotonic, arbitrary epoch)."""

    def now_ns(self) -> int:
        """Current time in nanoseconds."""
        ...


@runtime_checkable
class Clock(TimeSource, Protocol):
    """A time source that can wait for a deadline."""

    def sleep_until(self, deadline_ns: int) -> None:
        """Return once ``now_ns() >= deadline_ns`` (at once if it already is)."""
        ...


class WallClock:
    """Real time from :func:`time.monotonic_ns`; ``sleep_until`` sleeps."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until(self, deadline_ns: int) -> None:
        left = deadline_ns - time.monotonic_ns()
        if left > 0:
            time.sleep(left / 1e9)

    def __repr__(self) -> str:
        return "WallClock()"


class PerfClock:
    """:func:`time.perf_counter_ns` with sleep-then-spin waiting.

    ``spin_ns`` is the slice before a deadline spent busy-waiting instead of
    sleeping (the OS timer may wake a sleeper late by tens of microseconds).
    """

    def __init__(self, spin_ns: int = 100_000) -> None:
        self.spin_ns = spin_ns

    def now_ns(self) -> int:
        return time.perf_counter_ns()

    def sleep_until(self, deadline_ns: int) -> None:
        left = deadline_ns - time.perf_counter_ns()
        if left > self.spin_ns:
            time.sleep((left - self.spin_ns) / 1e9)
        while time.perf_counter_ns() < deadline_ns:
            pass

    def __repr__(self) -> str:
        return f"PerfClock(spin_ns={self.spin_ns})"


class VirtualClock:
    """Deterministic time: starts at ``start_ns``, moves only forward and only when told.

    ``sleep_until`` jumps to the deadline; ``advance`` models time spent
    working. ``ns`` is the current time as a public attribute: the
    simulator's frame path reads it and adds each frame's wire time to it
    directly (two method calls would cost about 7 % of a small frame).
    Everybody else moves time with ``advance``, ``set`` or ``sleep_until``,
    which refuse to go back.
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

    def sleep_until(self, deadline_ns: int) -> None:
        """Jump to ``deadline_ns`` if it is ahead (nothing waits in virtual time)."""
        if deadline_ns > self.ns:
            self.ns = int(deadline_ns)

    def __repr__(self) -> str:
        return f"VirtualClock({self.ns})"


def is_virtual(clock: TimeSource) -> bool:
    """Whether ``clock`` is virtual: time passes only when somebody advances it."""
    return isinstance(clock, VirtualClock)


def sleep_for(clock: Clock, seconds: float) -> None:
    """Wait ``seconds`` on ``clock`` (a virtual clock just moves on)."""
    if seconds > 0:
        clock.sleep_until(clock.now_ns() + int(seconds * 1e9))
