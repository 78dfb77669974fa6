"""The cyclic side of distributed clocks: pure, picklable objects fed with measurements.

Nothing here sends or waits. The cyclic engine puts :meth:`DcCycle.datagrams`
into every cycle's frame, gives back what the reference clock answered, and
moves its deadlines by what :meth:`DcCycle.on_reply` returns. Two modes:

* :attr:`DcMode.MASTER` (the master follows the reference): every frame
  carries an FRMW of the reference's 0x0910; the value that comes back is
  the reference time at the moment the frame passed it. :class:`PhaseLock`,
  a PI loop, moves the master's cycle so that this happens at a fixed phase
  of the SYNC0 grid (``lead_ns`` before SYNC0), and learns the rate of the
  master's clock against the reference's (the integral term). SOEM's sample
  ``ec_sync`` and KickCAT's ``SoftPll`` do the same; KickCAT notes that
  writing master time into the reference injects the master's jitter.
* :attr:`DcMode.REFERENCE` (the reference follows the master): each frame
  first writes the master's time into the reference's 0x0910 (IgH
  ``ecrt_master_sync_reference_clock``, a 4-byte FPWR before the FRMW); the
  reference's own time-control loop steers it, and the other slaves follow
  the reference through the FRMW as above.

:class:`SyncMonitor` turns periodic broadcast reads of 0x092C into the worst
deviation and typed events when it goes above a limit ("sync unstable").
"""

from __future__ import annotations

import enum
import struct
from collections import deque
from dataclasses import dataclass, field

from pyethercat.errors import ConfigError
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.dc import difference_bound

__all__ = [
    "DEFAULT_MONITOR_PERIOD_NS",
    "DEFAULT_UNSTABLE_NS",
    "DcCycle",
    "DcMode",
    "PhaseLock",
    "SyncEvent",
    "SyncMonitor",
]

#: How often the sync monitor reads 0x092C by default (IgH's sync monitor
#: runs at the application's pace; 10 reads a second cost one 16-byte datagram).
DEFAULT_MONITOR_PERIOD_NS = 100_000_000
#: Above this worst deviation the segment counts as "sync unstable" (a
#: tenth of IgH's 10 us set-up bound: the figure a running segment should beat).
DEFAULT_UNSTABLE_NS = 1_000


class DcMode(enum.Enum):
    """Who follows whom in the cyclic operation."""

    MASTER = "master"
    """The master's cycle follows the reference clock (the default)."""
    REFERENCE = "reference"
    """The reference clock follows the master's time."""

    @classmethod
    def parse(cls, text: str) -> DcMode:
        try:
            return cls(text.strip().lower())
        except ValueError:
            raise ConfigError(f"unknown DC mode {text!r}: use master or reference") from None


def _wrap(value: int, cycle: int) -> int:
    """``value`` modulo ``cycle`` into (-cycle/2, cycle/2]."""
    v = value % cycle
    return v - cycle if v > cycle // 2 else v


@dataclass
class PhaseLock:
    """PI phase lock of the master's cycle onto the reference clock's cycle grid.

    ``update(reference_time)`` takes the reference's system time read by the
    cycle's FRMW and returns how many ns to move the next deadlines (negative:
    earlier). The target is that the frame passes the reference at system
    time ``target_ns`` modulo the cycle. The first sample jumps straight to
    the target (``acquire``); then the loop corrects ``kp`` of the phase error
    per cycle and integrates it (``ki``) to learn the clock-rate difference,
    each step bounded by ``max_step_ns``. ``kp`` = 0.1 with ``ki`` =
    ``kp**2 / 4`` is critically damped: about 20 cycles to settle.
    """

    cycle_ns: int
    target_ns: int = 0
    kp: float = 0.1
    ki: float = 0.0025
    max_step_ns: int = 0
    acquire: bool = True
    #: State: integrated error, last error, samples taken, the learned per-cycle rate term.
    integral: float = 0.0
    error_ns: int = 0
    samples: int = 0
    rate_ns: float = 0.0
    #: Recent phase errors (ns), for statistics and plots.
    history: deque[int] = field(default_factory=lambda: deque(maxlen=4096))

    def __post_init__(self) -> None:
        if self.cycle_ns <= 0:
            raise ConfigError("phase lock: the cycle time must be positive")
        if self.max_step_ns <= 0:
            self.max_step_ns = max(1, self.cycle_ns // 20)

    def update(self, reference_time: int) -> int:
        e = _wrap(reference_time - self.target_ns, self.cycle_ns)
        self.error_ns = e
        self.history.append(e)
        self.samples += 1
        if self.samples == 1 and self.acquire:
            return -e
        u = self.kp * e + self.ki * (self.integral + e)
        if abs(u) <= self.max_step_ns:
            self.integral += e  # (no wind-up while the step is at its bound)
        self.rate_ns = self.ki * self.integral
        step = int(round(max(-self.max_step_ns, min(self.max_step_ns, u))))
        return -step

    @property
    def locked(self) -> bool:
        """The last errors stay within 1 % of the cycle (and at least 20 samples were taken)."""
        if self.samples < 20:
            return False
        recent = list(self.history)[-20:]
        return max(abs(x) for x in recent) <= max(1_000, self.cycle_ns // 100)


@dataclass(frozen=True)
class SyncEvent:
    """The segment's synchronisation changed: ``unstable`` above ``limit_ns``, or stable again."""

    time_ns: int
    unstable: bool
    deviation_ns: int
    limit_ns: int

    @property
    def text(self) -> str:
        if self.unstable:
            return (f"sync unstable: system time difference up to {self.deviation_ns} ns "
                    f"(limit {self.limit_ns} ns)")
        return f"sync stable again: system time difference up to {self.deviation_ns} ns"


@dataclass
class SyncMonitor:
    """Worst system-time deviation from periodic BRD of 0x092C.

    A broadcast read ORs every slave's 0x092C: the magnitude bits give an
    upper bound of the largest deviation (less than twice it). The monitor
    keeps the last and the worst bound, a bounded history, and reports a
    :class:`SyncEvent` when the bound rises above ``limit_ns`` and when it
    falls back below half of it (hysteresis, so a value near the limit does
    not chatter).
    """

    period_ns: int = DEFAULT_MONITOR_PERIOD_NS
    limit_ns: int = DEFAULT_UNSTABLE_NS
    last_ns: int | None = None
    worst_ns: int = 0
    unstable: bool = False
    readings: int = 0
    #: (time, bound) of recent readings.
    history: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=4096))
    _next_ns: int | None = None

    @staticmethod
    def datagram() -> Datagram:
        return Datagram.device(Command.BRD, 0, R.DC_SYSTEM_TIME_DIFFERENCE, 4)

    def due(self, now_ns: int) -> bool:
        """Time for the next reading (call :meth:`on_reading` with its result)."""
        if self.period_ns <= 0:
            return False
        if self._next_ns is None or now_ns >= self._next_ns:
            self._next_ns = now_ns + self.period_ns
            return True
        return False

    def on_reading(self, now_ns: int, data: bytes, wkc: int) -> SyncEvent | None:
        """A BRD 0x092C reply (``wkc`` 0: nobody answered, ignored)."""
        if wkc == 0 or len(data) < 4:
            return None
        bound = difference_bound(struct.unpack_from("<I", data)[0])
        self.readings += 1
        self.last_ns = bound
        self.worst_ns = max(self.worst_ns, bound)
        self.history.append((now_ns, bound))
        if not self.unstable and bound > self.limit_ns:
            self.unstable = True
            return SyncEvent(now_ns, True, bound, self.limit_ns)
        if self.unstable and bound <= self.limit_ns // 2:
            self.unstable = False
            return SyncEvent(now_ns, False, bound, self.limit_ns)
        return None

    def reset_worst(self) -> None:
        self.worst_ns = 0


@dataclass
class DcCycle:
    """Everything DC a cyclic engine does per cycle (picklable: plain data and floats).

    ``reference_station``: the reference clock's station address; ``wide``:
    it has a 64-bit clock (8-byte FRMW). ``clock_offset_ns``: EtherCAT
    system time (ns since 2000) minus the engine's clock, for the reference
    mode and for plots. :meth:`datagrams` are placed first in the cycle's
    first frame; :meth:`on_reply` takes the frame's reply and the engine's
    send time of the frame and returns the deadline adjustment.
    """

    mode: DcMode
    reference_station: int
    cycle_ns: int
    wide: bool = True
    shift_ns: int = 0
    lead_ns: int | None = None
    clock_offset_ns: int = 0
    lock: PhaseLock | None = None
    monitor: SyncMonitor = field(default_factory=SyncMonitor)
    #: The reference time of the last cycle (None before the first reply, or lost).
    reference_time: int | None = None
    #: Reference time minus master time of the last cycle (the reference mode's
    #: tracking error, the master mode's clock difference), ns.
    master_difference_ns: int | None = None
    frames: int = 0
    lost: int = 0
    _aligned: bool = False

    def __post_init__(self) -> None:
        if self.cycle_ns <= 0:
            raise ConfigError("DC cycle: the cycle time must be positive")
        if self.lead_ns is None:
            # The frame passes the reference half a cycle before SYNC0: outputs
            # reach every slave well before the pulse, inputs taken at the
            # pulse leave with the next frame (SOEM's sample aims at 50 %).
            self.lead_ns = self.cycle_ns // 2
        if self.mode is DcMode.MASTER and self.lock is None:
            self.lock = PhaseLock(self.cycle_ns, target_ns=self.target_ns)

    @property
    def target_ns(self) -> int:
        """System-time phase (modulo the cycle) at which frames should pass the reference."""
        assert self.lead_ns is not None
        return (self.shift_ns - self.lead_ns) % self.cycle_ns

    @property
    def size(self) -> int:
        return 8 if self.wide else 4

    def datagrams(self) -> list[Datagram]:
        """The DC datagrams of every cycle's frame (their data is filled by :meth:`fill`)."""
        dgs = []
        if self.mode is DcMode.REFERENCE:
            dgs.append(Datagram.device(Command.FPWR, self.reference_station, R.DC_SYSTEM_TIME,
                                       bytes(self.size)))
        dgs.append(Datagram.device(Command.FRMW, self.reference_station, R.DC_SYSTEM_TIME,
                                   bytes(self.size)))
        return dgs

    def fill(self, send_ns: int) -> bytes | None:
        """Data of the first datagram for a frame sent at ``send_ns`` (engine clock), if any."""
        if self.mode is not DcMode.REFERENCE:
            return None
        value = (send_ns + self.clock_offset_ns) & ((1 << 64) - 1)
        return struct.pack("<Q", value)[: self.size]

    def on_reply(self, frmw_data: bytes | None, send_ns: int) -> int:
        """The FRMW's data as it came back (``None``: frame lost); returns the deadline shift."""
        self.frames += 1
        shift = 0
        if self.mode is DcMode.REFERENCE and not self._aligned:
            # System time follows the master's clock: put the master's cycle on
            # the SYNC grid once; nothing to track afterwards.
            self._aligned = True
            shift = -_wrap(send_ns + self.clock_offset_ns - self.target_ns, self.cycle_ns)
        if frmw_data is None or len(frmw_data) < self.size:
            self.lost += 1
            self.reference_time = None
            return shift
        ref = int.from_bytes(frmw_data[: self.size], "little")
        master = send_ns + self.clock_offset_ns
        if not self.wide:
            # A 32-bit reference: extend it with the master's upper bits.
            ref = _extend32(ref, master)
        self.reference_time = ref
        self.master_difference_ns = ref - master
        if self.lock is None:
            return shift
        return self.lock.update(ref)


def _extend32(low: int, near: int) -> int:
    """The 64-bit time whose low 32 bits are ``low`` closest to ``near``."""
    base = near - (near & 0xFFFF_FFFF) + low
    if base - near > 1 << 31:
        base -= 1 << 32
    elif near - base > 1 << 31:
        base += 1 << 32
    return base
