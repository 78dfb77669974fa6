"""The cyclic frame answered first, its effects in the slaves applied after.

An ESC forwards a frame while it processes it: the master has its reply
after the wire's delay, and the writes land in the memory meanwhile. A
simulator that applies every effect of a cyclic LRW (outputs into the
memory, buffers published, SM and AL events, watchdogs, the applications)
before it sends the reply makes the master wait for work whose result the
reply does not contain.

What the reply contains of a logical datagram is known before its writes:
the data the slaves read (from their memory as it was: an ESC reads before
it writes), the working counter (the plan's) and the IRQ field (the events
as they were before the slaves executed it). :func:`serve_reply_first`
builds that reply, hands it to the link, then applies the writes and the
rest, before the next frame is taken. Only frames whose result cannot
differ qualify: one logical datagram, a plan in one stage (no slave reads
what another wrote in the same datagram), the walk and the compiled state
clean, no faults, no ring, no time-driven work due. Every other frame goes
through :meth:`Segment.process <pyethercat.sim.segment.Segment.process>`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from pyethercat.wire.datagram import HEADER_SIZE, HEADER_TAIL, LOGICAL_COMMANDS, WKC
from pyethercat.wire.frame import LOCALLY_ADMINISTERED_BIT

if TYPE_CHECKING:
    from pyethercat.sim.segment import Segment

__all__ = ["serve_reply_first"]


def serve_reply_first(seg: Segment, frame: bytes | bytearray | memoryview,
                      send: Callable[[bytes], None]) -> bool:
    """Answer ``frame`` through ``send`` before applying its effects, if it qualifies
    (see the module docstring); False (nothing done) if it does not."""
    vclock = seg._vclock
    now = vclock.ns if vclock is not None else seg._clock.now_ns()
    state = seg.state
    route = state.route
    if (state.watchdog_dirty or state.sm_dirty or state.topology_dirty or state.irq_stale
            or state.fmmu_stale or route is None or now > seg.watchdogs.deadline or seg._sync
            or seg._corrupt or seg._rates):
        return False
    faults = seg.faults
    if faults.drop_p or faults.crc_cut >= 0 or route.closed_idx or route.reopen or not route.live \
            or not route.returned:
        return False
    hit = seg._parsed.get(frame[12:26] if type(frame) is bytes else bytes(frame[12:26]))
    if hit is None or hit[0] > len(frame) or len(hit[1]) != 1:
        return False
    off, cmd, address, lw, irq, n = hit[1][0]
    if cmd not in LOGICAL_COMMANDS:
        return False
    plan = seg.logical_plan(cmd, address, n)  # (compiles nothing: the state is clean)
    if plan is None or plan.fused is None or len(plan.stages) != 1:
        return False
    fused = plan.fused
    stages = plan.stages
    seg.frames += 1
    seg.dc.frame_t0 = now
    stage = stages[0]
    memory = seg.memory
    flat = memory.flat
    doff = off + HEADER_SIZE
    buf = bytearray(frame)
    stage.place(np.frombuffer(buf, np.uint8, n, doff), stage.gather(flat))
    HEADER_TAIL.pack_into(buf, off + 2, address, lw, irq | state.irq)
    wkc_off = doff + n
    WKC.pack_into(buf, wkc_off, (WKC.unpack_from(buf, wkc_off)[0] + plan.wkc) & 0xFFFF)
    buf[6] |= LOCALLY_ADMINISTERED_BIT
    try:
        send(bytes(buf))
    finally:
        # The frame passed the slaves whatever became of its reply: its writes hold.
        stage.write(flat, np.frombuffer(frame, np.uint8, n, doff))
        seg.registers_done(fused, flat)
        seg.frame_done(now, len(buf))
    return True
