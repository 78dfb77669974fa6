"""The firmware's work a frame sets in motion, run once the frame has passed.

A device application reacts to what a frame did (new outputs, a mailbox
request written, a reply read) through its PDI, after the frame has passed
the ESC: the frame passes in about a microsecond, firmware takes tens of
microseconds to milliseconds. :class:`AfterFrame` holds that work while a
frame is processed and runs it, in order, when the frame is done: at the end
of ``Segment.process``, or, while ``hold`` is set, when the caller says
(``pyethercat sim`` sends the reply first, then runs it, before it takes the
next frame). Outside a frame the work runs at once.
"""

from __future__ import annotations

from collections.abc import Callable

from pyethercat.clock import TimeSource

__all__ = ["AfterFrame"]

Work = Callable[[], None]


class AfterFrame:
    """Work queued during a frame (see the module docstring)."""

    __slots__ = ("_work", "in_frame", "hold", "_clock", "_slow_ns", "_pause")

    def __init__(self, clock: Callable[[], TimeSource | None], slow_ns: int,
                 pause: Callable[[int], None]) -> None:
        self._work: list[Work] = []
        #: A frame is being processed: work waits for its end.
        self.in_frame = False
        #: The caller runs the work (:meth:`run`) instead of the frame's end.
        self.hold = False
        # The real-time clock (None on virtual time), and what to do when the work took
        # longer than ``slow_ns`` (the segment pauses its watchdogs by it).
        self._clock = clock
        self._slow_ns = slow_ns
        self._pause = pause

    def __bool__(self) -> bool:
        return bool(self._work)

    def add(self, work: Work) -> None:
        """Run ``work`` once the frame in progress has passed (at once outside a frame)."""
        if self.in_frame:
            self._work.append(work)
        else:
            work()

    def run(self) -> None:
        """Run the work the last frame left, in order."""
        queue = self._work
        if not queue:
            return
        clock = self._clock()
        t0 = clock.now_ns() if clock is not None else 0
        while queue:
            queue.pop(0)()
        if clock is not None:
            # (the firmware's work delays the next frame as the frame's own did)
            spent = clock.now_ns() - t0
            if spent > self._slow_ns:
                self._pause(spent)
