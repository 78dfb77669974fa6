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

__all__ = ["AfterFrame"]

Work = Callable[[], None]


class AfterFrame:
    """Work queued during a frame (see the module docstring)."""

    __slots__ = ("_work", "in_frame", "hold", "_wall_ns", "_charge")

    def __init__(self, wall_ns: Callable[[], int | None], charge: Callable[[int], None]) -> None:
        self._work: list[Work] = []
        #: A frame is being processed: work waits for its end.
        self.in_frame = False
        #: The caller runs the work (:meth:`run`) instead of the frame's end.
        self.hold = False
        # The segment's real time (None on virtual time), and its rule for time spent
        # serving since then (a long spell pauses the watchdogs, as a long frame does).
        self._wall_ns = wall_ns
        self._charge = charge

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
        t0 = self._wall_ns()
        while queue:
            queue.pop(0)()
        if t0 is not None:
            self._charge(t0)  # (the firmware's work delays the next frame as the frame's did)
