"""ECAT event registers of a segment and the IRQ field of datagrams.

Each ESC keeps ECAT event request bits (0x0210) and the master's mask
(0x0200). Every slave a datagram passes ORs (request AND mask) into the
datagram's IRQ field (gatorcat ``esc.zig`` ``ExternalEvent``, IEC 61158-4-12
6.1.6; KickCAT ``protocol.h`` ``EcatEvent``; ESC datasheet section II,
registers 0x0200 and 0x0210), so the
field the master sees is the OR over the route.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.sim.memory import EscMemory
from pyethercat.wire import registers as R

__all__ = ["irq_field"]


def irq_field(memory: EscMemory, passes: npt.NDArray[np.int64]) -> int:
    """OR over the slaves of ``passes`` of (ECAT event request AND ECAT event mask)."""
    if not len(passes):
        return 0
    mem = memory.mem
    req = mem[passes, R.ECAT_EVENT_REQUEST: R.ECAT_EVENT_REQUEST + 2]
    mask = mem[passes, R.ECAT_EVENT_MASK: R.ECAT_EVENT_MASK + 2]
    v = np.bitwise_or.reduce(req & mask, axis=0)
    return int(v[0]) | (int(v[1]) << 8)
