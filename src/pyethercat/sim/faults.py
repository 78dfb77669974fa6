"""Frame faults of a segment: CRC errors on a port, frames lost on the wire, malformed frames.

A frame with a CRC error on a link (ESC datasheet section II, error
counters 0x0300-0x0313; gatorcat ``esc.zig`` ``RXErrorCounter``):

- the port that receives it counts an invalid frame (RX error counter,
  0x0300 + 2 * port), every later port on the walk counts a forwarded error
  (0x0308 + port): only the first detecting port counts the error itself;
- the slaves passed before the bad link took the frame (their FCS check was
  good); the receiving slave and all after it discard its content, and the
  master's NIC drops it for its bad FCS.

A malformed EtherCAT frame (datagrams running past the frame) is not
processed at all and counted by the first slave's processing-unit error
counter 0x030C.

A bad cable (``rates``) corrupts each frame arriving over it with a given
probability, in both directions.

Dropped frames (``drop_probability``) are lost before any slave sees them.
"""

from __future__ import annotations

import random

from pyethercat.errors import ConfigError
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.ports import Route
from pyethercat.wire import registers as R

__all__ = ["NEVER", "Faults"]

#: "No arrival": later than any arrival index.
NEVER = 1 << 62


class Faults:
    """Pending CRC faults per port and the drop probability (see the module docstring)."""

    def __init__(self, memory: EscMemory) -> None:
        self.memory = memory
        #: Frames still to corrupt, by (slave, port) of arrival.
        self.corrupt: dict[tuple[int, int], int] = {}
        #: Probability that a frame arriving at (slave, port) carries a CRC error.
        self.rates: dict[tuple[int, int], float] = {}
        self.drop_p = 0.0
        #: The frame being processed: passes before its CRC-corrupted arrival (-1: none),
        #: and that arrival's index into Route.arrivals (what :meth:`apply_corruption` found).
        self.crc_cut = -1
        self.crc_at = NEVER
        self._rng = random.Random()
        self._crc_rng = random.Random()

    def corrupt_frames(self, slave: int, port: int, count: int) -> None:
        self.corrupt[(slave, port)] = self.corrupt.get((slave, port), 0) + count

    def set_crc_rate(self, slave: int, port: int, rate: float, seed: int | None = None) -> None:
        """Frames arriving at ``slave``'s ``port`` get a CRC error with probability ``rate`` (0: none)."""
        if not 0.0 <= rate <= 1.0:
            raise ConfigError(f"CRC error rate {rate} is not within 0..1")
        if rate:
            self.rates[(slave, port)] = rate
        else:
            self.rates.pop((slave, port), None)
        if seed is not None:
            self._crc_rng.seed(seed)

    def set_drop_probability(self, p: float, seed: int | None = None) -> None:
        if not 0.0 <= p <= 1.0:
            raise ConfigError(f"drop probability {p} is not within 0..1")
        self.drop_p = p
        if seed is not None:
            self._rng.seed(seed)

    def drops(self) -> bool:
        """Whether this frame is lost on the wire (one draw per frame)."""
        return self._rng.random() < self.drop_p

    def apply_corruption(self, route: Route) -> tuple[int, int]:
        """Count CRC errors along the walk.

        Returns the number of processing-unit passes made before the corrupted
        arrival (those slaves execute the frame) and that arrival's index in
        ``route.arrivals``, or (-1, :data:`NEVER`) if no pending fault hit this frame."""
        mem = self.memory.mem
        corrupted = False
        cut, at = -1, NEVER
        rates = self.rates
        for i, (s, p, _t, before) in enumerate(route.arrivals):
            if not corrupted:
                left = self.corrupt.get((s, p), 0)
                if left:
                    if left == 1:
                        del self.corrupt[(s, p)]
                    else:
                        self.corrupt[(s, p)] = left - 1
                elif not (rates and (s, p) in rates and self._crc_rng.random() < rates[(s, p)]):
                    continue
                corrupted = True
                cut, at = before, i
                a = R.RX_ERROR_COUNTER + 2 * p
                mem[s, a] = min(255, int(mem[s, a]) + 1)
            else:
                a = R.FORWARDED_RX_ERROR_COUNTER + p
                mem[s, a] = min(255, int(mem[s, a]) + 1)
        return cut, at

    def processing_error(self, route: Route) -> None:
        """A malformed EtherCAT frame: counted by the first slave's processing unit."""
        if len(route.passes):
            s = int(route.passes[0])
            mem = self.memory.mem
            c = int(mem[s, R.ECAT_PROCESSING_ERROR_COUNTER])
            mem[s, R.ECAT_PROCESSING_ERROR_COUNTER] = min(255, c + 1)
