"""What an ESC model asks of the segment it sits in: the host protocol.

An :class:`~pyethercat.sim.esc.Esc` models one chip. Everything it does that
concerns more than its own registers goes through these calls, so the ESC
model never imports the segment and never touches its members:

- compiled state it invalidates (:class:`Dirty` bits: addressing, FMMU and
  SM plans, the IRQ field, watchdog limits, the frame walk);
- events the segment acts on (AL state changes, a completed output buffer,
  an ESC reset, a loop-control write, DC register writes);
- what only the segment knows (time, whether outputs arrived).

:class:`~pyethercat.sim.segment.SegmentHost` implements it for
``sim.segment.Segment`` (in that module, so this one never imports the
segment); a test can implement it with a few lines to drive one ESC alone.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from typing import Protocol

from pyethercat.wire.al import AlState

__all__ = ["Dirty", "EscHost"]


class Dirty(enum.IntFlag):
    """Compiled segment state an ESC-level change makes stale."""

    #: Station addresses or aliases (configured addressing).
    ADDRESSING = 0x01
    #: FMMU registers (logical addressing plan).
    FMMU = 0x02
    #: SM registers (SM areas, buffer completion, logical plan).
    SM = 0x04
    #: ECAT event request or mask (the datagram IRQ field).
    IRQ = 0x08
    #: Watchdog divider, times or SM watchdog enables.
    WATCHDOG = 0x10
    #: Ports, links or loop control (the frame walk).
    TOPOLOGY = 0x20


class EscHost(Protocol):
    """The segment as one ESC sees it (see the module docstring)."""

    @property
    def sii_busy_ns(self) -> int:
        """Override of the EEPROM busy time for every slave (0: the profile's timing)."""
        ...

    def now_ns(self) -> int:
        """Current segment time."""
        ...

    def invalidate(self, what: Dirty) -> None:
        """Compiled state ``what`` must be rebuilt before the next use."""
        ...

    def ecat_event_raised(self, bits: int) -> None:
        """ECAT event request bits changed on this slave (``bits``: those newly set)."""
        ...

    def al_state_changed(self, index: int, old: AlState, new: AlState) -> None:
        """The slave's AL state changed."""
        ...

    def has_outputs(self, index: int) -> bool:
        """Whether a complete output buffer arrived since the slave left SAFEOP's way up."""
        ...

    def wait_for_outputs(self, index: int, waiting: bool) -> None:
        """A SAFEOP -> OP request waits (or no longer waits) for the first outputs."""
        ...

    def output_buffer_completed(self, index: int) -> None:
        """The master wrote the last byte of a buffered write SM of the slave."""
        ...

    def reset_requested(self, index: int) -> None:
        """The ESC reset sequence completed: power-on reset of the slave."""
        ...

    def loop_control_written(self, index: int, old: int, new: int) -> None:
        """DL control loop byte written (``old``, ``new`` values)."""
        ...

    def dc_written(self, index: int, lo: int, data: bytes) -> None:
        """DC registers in [lo, lo + len(data)) written by EtherCAT (latch, system time, cyclic unit)."""
        ...

    def dc_refresh(self, index: int) -> None:
        """Bring the slave's system time register (0x0910) up to date before a read."""
        ...

    def dc_sync_status(self, index: int, lo: int, hi: int, pdi: bool) -> None:
        """Bring SYNC0/SYNC1 status (0x098E/0x098F) up to date before a read of [lo, hi)
        (``pdi``: a PDI read, which acknowledges the pulses in acknowledge mode)."""
        ...

    def dc_latch_input(self, index: int, unit: int, rising: bool, t_ns: int | None) -> None:
        """An edge on the slave's latch input ``unit`` at segment time ``t_ns`` (None: now)."""
        ...

    def after_frame(self, work: Callable[[], None]) -> None:
        """Run ``work``, the firmware's reaction to an access, once the frame has passed
        (at once outside a frame)."""
        ...
