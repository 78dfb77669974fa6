"""Statistics of the cyclic loop: counters, timing percentiles, jitter histogram, link spells.

Samples are kept in fixed numpy ring buffers, so memory does not grow with
run time; counters are plain integers the loop thread increments (readers in
other threads see them a cycle late at worst).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError

__all__ = ["CycleStats", "JITTER_BINS_US"]

#: Upper edges (µs) of the period-jitter histogram bins; the last bin is open.
JITTER_BINS_US = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)


class CycleStats:
    """Counters and timing samples of a cyclic loop.

    Samples (period, wake-up latency, round trip; nanoseconds) are kept in
    fixed numpy ring buffers of ``capacity`` entries, so memory does not grow
    with run time; percentiles cover the last ``capacity`` cycles.
    """

    def __init__(self, period_ns: int, capacity: int = 1 << 18) -> None:
        self.period_ns = period_ns
        self.capacity = capacity
        self.cycles = 0
        self.late = 0
        self.overruns = 0
        self.callback_overruns = 0
        self.skipped = 0
        self.wkc_errors = 0
        #: Cycles whose working counter was short of even the slaves present
        #: (the ones known to be gone, ``CyclicRunner.set_absent``, not counted).
        self.incomplete = 0
        self.lost_frames = 0
        self.frames = 0
        #: Frames the link refused to send (interface down, no carrier, gone).
        self.send_errors = 0
        #: Whether frames come back (see :class:`~pyethercat.master.cyclic.CyclicRunner`).
        self.link_up = True
        #: Times the link went down, cycles run while it was down, and the
        #: nanoseconds of the down spells that ended (the current one is
        #: ``last_ns - down_since_ns``).
        self.link_downs = 0
        self.down_cycles = 0
        self.down_ns = 0
        self.down_since_ns: int | None = None
        self._periods = np.zeros(capacity, dtype=np.int64)
        self._latency = np.zeros(capacity, dtype=np.int64)
        self._rtt = np.zeros(capacity, dtype=np.int64)
        self._n_period = 0
        self._n_rtt = 0
        self._last_start: int | None = None
        self.histogram = [0] * (len(JITTER_BINS_US) + 1)
        self._edges_ns = [b * 1000 for b in JITTER_BINS_US]
        self.started_ns: int | None = None
        self.last_ns: int | None = None

    def record_start(self, deadline_ns: int, start_ns: int, late_threshold_ns: int) -> None:
        """One cycle began at ``start_ns`` for ``deadline_ns``."""
        self.cycles += 1
        if self.started_ns is None:
            self.started_ns = start_ns
        self.last_ns = start_ns
        latency = start_ns - deadline_ns
        i = (self.cycles - 1) % self.capacity
        self._latency[i] = latency
        if latency > late_threshold_ns:
            self.late += 1
        if self._last_start is not None:
            period = start_ns - self._last_start
            j = self._n_period % self.capacity
            self._periods[j] = period
            self._n_period += 1
            # Bin k: the first edge the deviation stays below.
            self.histogram[bisect.bisect_right(self._edges_ns, abs(period - self.period_ns))] += 1
        self._last_start = start_ns

    def keep_samples_in(self, periods: npt.NDArray[np.int64], latency: npt.NDArray[np.int64],
                        rtt: npt.NDArray[np.int64]) -> None:
        """Keep the sample rings in these arrays (``capacity`` int64 each, e.g. memory that
        other processes read: the isolated engine's); call before the first cycle."""
        for a in (periods, latency, rtt):
            if a.shape != (self.capacity,) or a.dtype != np.int64:
                raise ConfigError(f"sample ring must be {self.capacity} int64, got {a.shape} "
                                  f"{a.dtype}")
        self._periods, self._latency, self._rtt = periods, latency, rtt

    def record_round_trip(self, ns: int) -> None:
        self._rtt[self._n_rtt % self.capacity] = ns
        self._n_rtt += 1

    def link_went_down(self, now_ns: int) -> None:
        self.link_up = False
        self.link_downs += 1
        self.down_since_ns = now_ns

    def link_came_up(self, now_ns: int) -> int:
        """Close the down spell; returns its length in nanoseconds."""
        since = self.down_since_ns if self.down_since_ns is not None else now_ns
        self.link_up = True
        self.down_since_ns = None
        self.down_ns += now_ns - since
        return now_ns - since

    def down_for_ns(self, now_ns: int) -> int:
        """How long the current down spell lasts (0 while the link is up)."""
        return 0 if self.down_since_ns is None else max(0, now_ns - self.down_since_ns)

    def restart_period(self) -> None:
        """Forget the previous start (after skipped deadlines the period is not a sample)."""
        self._last_start = None

    # -- views --------------------------------------------------------------------

    def periods(self) -> npt.NDArray[np.int64]:
        return self._periods[:min(self._n_period, self.capacity)].copy()

    def latencies(self) -> npt.NDArray[np.int64]:
        return self._latency[:min(self.cycles, self.capacity)].copy()

    def round_trips(self) -> npt.NDArray[np.int64]:
        return self._rtt[:min(self._n_rtt, self.capacity)].copy()

    def recent(self, n: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """The last ``n`` (at most) period and round-trip samples in ns, oldest first.

        Costs O(n), whatever the capacity: readers outside the loop (telemetry)
        take a window of the last second instead of copying the whole ring.
        """
        return (_tail(self._periods, self._n_period, n, self.capacity),
                _tail(self._rtt, self._n_rtt, n, self.capacity))

    @staticmethod
    def _pct(samples: npt.NDArray[np.int64], qs: Sequence[float]) -> dict[str, float]:
        if samples.size == 0:
            return {f"p{q:g}": math.nan for q in qs}
        values = np.percentile(samples, qs)
        return {f"p{q:g}": float(v) / 1000.0 for q, v in zip(qs, values, strict=True)}

    def jitter_us(self, qs: Sequence[float] = (50, 90, 99, 99.9, 100)) -> dict[str, float]:
        """Percentiles of |period - nominal| in µs."""
        return self._pct(np.abs(self.periods() - self.period_ns), qs)

    def latency_us(self, qs: Sequence[float] = (50, 90, 99, 99.9, 100)) -> dict[str, float]:
        """Percentiles of wake-up latency (start - deadline) in µs."""
        return self._pct(self.latencies(), qs)

    def round_trip_us(self, qs: Sequence[float] = (50, 90, 99, 100)) -> dict[str, float]:
        """Percentiles of the process-data round trip in µs."""
        return self._pct(self.round_trips(), qs)

    def period_us(self) -> dict[str, float]:
        p = self.periods()
        if p.size == 0:
            return {"mean": math.nan, "min": math.nan, "max": math.nan}
        return {"mean": float(p.mean()) / 1000, "min": float(p.min()) / 1000,
                "max": float(p.max()) / 1000}

    def summary(self) -> dict[str, object]:
        """Everything as plain numbers (for printing and JSON)."""
        return {
            "cycles": self.cycles, "period_us": self.period_ns / 1000,
            "late": self.late, "overruns": self.overruns,
            "callback_overruns": self.callback_overruns, "skipped": self.skipped,
            "wkc_errors": self.wkc_errors, "incomplete": self.incomplete,
            "lost_frames": self.lost_frames,
            "frames": self.frames, "send_errors": self.send_errors,
            "link": {"up": self.link_up, "downs": self.link_downs,
                     "down_cycles": self.down_cycles,
                     "down_s": (self.down_ns + self.down_for_ns(self.last_ns or 0)) / 1e9},
            "period": self.period_us(), "jitter_us": self.jitter_us(),
            "latency_us": self.latency_us(), "round_trip_us": self.round_trip_us(),
            "histogram": dict(zip([f"<{b}us" for b in JITTER_BINS_US] + [f">={JITTER_BINS_US[-1]}us"],
                                  self.histogram, strict=True)),
        }


def _tail(ring: npt.NDArray[np.int64], count: int, n: int, capacity: int
          ) -> npt.NDArray[np.int64]:
    """The last ``n`` of ``count`` samples written round ``ring``, oldest first."""
    n = min(n, count, capacity)
    if n <= 0:
        return ring[:0].copy()
    end = count % capacity
    if end >= n:
        return ring[end - n:end].copy()
    return np.concatenate((ring[capacity - (n - end):], ring[:end]))
