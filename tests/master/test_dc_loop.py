"""The cyclic DC objects (master.dc_loop), fed with a modelled reference clock."""

from __future__ import annotations

import pickle
import struct

import pytest

from pyethercat.errors import ConfigError
from pyethercat.master.dc_loop import DcCycle, DcMode, PhaseLock, SyncMonitor
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command
from pyethercat.wire.dc import encode_time_difference

CYCLE = 1_000_000


def run_lock(dc: DcCycle, ppm: float, cycles: int, latency: int = 20_000,
             ref0: int = 123_456_789_012) -> list[int]:
    """A master whose cycle follows ``dc``; the reference runs ``ppm`` fast. Returns phases."""
    deadline = 0
    phases = []
    for _ in range(cycles):
        t_ref_pass = deadline + latency
        ref = int(ref0 + t_ref_pass * (1 + ppm * 1e-6))
        phases.append(ref % CYCLE)
        deadline += CYCLE + dc.on_reply(struct.pack("<Q", ref), deadline)
    return phases


@pytest.mark.parametrize("ppm", [-100.0, 0.0, 37.5, 100.0])
def test_master_follows_reference_phase(ppm: float) -> None:
    """The frame ends up passing the reference half a cycle before SYNC0, whatever the drift."""
    dc = DcCycle(DcMode.MASTER, 0x1001, CYCLE, shift_ns=100_000)
    phases = run_lock(dc, ppm, 400)
    target = (100_000 - CYCLE // 2) % CYCLE
    assert dc.lock is not None and dc.lock.target_ns == target
    tail = [abs((p - target + CYCLE // 2) % CYCLE - CYCLE // 2) for p in phases[-100:]]
    assert max(tail) <= 2, tail[-5:]
    # the integral learned the rate difference: ppm of a cycle per cycle
    assert dc.lock.rate_ns == pytest.approx(ppm * 1e-6 * CYCLE, abs=0.5)
    assert dc.lock.locked


def test_phase_lock_steps_are_bounded_after_acquisition() -> None:
    lock = PhaseLock(CYCLE, target_ns=0)
    assert lock.update(300_000) == -300_000      # first sample: jump to the target
    assert lock.update(499_000) == -lock.max_step_ns  # then bounded steps
    assert lock.integral == 0  # no wind-up while the step is at its bound
    assert lock.max_step_ns == CYCLE // 20
    with pytest.raises(ConfigError):
        PhaseLock(0)


def test_reference_mode_writes_master_time_then_reads() -> None:
    dc = DcCycle(DcMode.REFERENCE, 0x1002, CYCLE, clock_offset_ns=5_000_000_000)
    fpwr, frmw = dc.datagrams()
    assert (fpwr.command, fpwr.adp, fpwr.ado, len(fpwr.data)) == (Command.FPWR, 0x1002,
                                                                   R.DC_SYSTEM_TIME, 8)
    assert (frmw.command, frmw.ado) == (Command.FRMW, R.DC_SYSTEM_TIME)
    assert dc.fill(1_000) == struct.pack("<Q", 5_000_001_000)
    # the first reply puts the master's cycle on the grid: frames half a cycle before SYNC0
    assert dc.target_ns == CYCLE // 2
    assert dc.on_reply(struct.pack("<Q", 5_000_001_040), 1_000) == CYCLE // 2 - 1_000
    # the reference answers 40 ns ahead of the master: the tracking error
    assert dc.master_difference_ns == 40
    assert dc.on_reply(struct.pack("<Q", 5_000_002_040), 2_000) == 0
    assert dc.on_reply(None, 3_000) == 0 and dc.lost == 1


def test_32bit_reference_is_extended_with_the_master_time() -> None:
    dc = DcCycle(DcMode.REFERENCE, 1, CYCLE, wide=False, clock_offset_ns=(7 << 32) - 100)
    assert len(dc.datagrams()[1].data) == 4
    # the reference's low word wrapped just after the master's
    dc.on_reply(struct.pack("<I", 50), 0)
    assert dc.reference_time == (7 << 32) + 50
    assert dc.master_difference_ns == 150


def test_sync_monitor_events_with_hysteresis() -> None:
    mon = SyncMonitor(period_ns=1000, limit_ns=1000)
    assert mon.due(0) and not mon.due(500) and mon.due(1000)
    raw = encode_time_difference(-300) | encode_time_difference(200)
    assert mon.on_reading(0, struct.pack("<I", raw), 3) is None
    assert mon.last_ns is not None and 300 <= mon.last_ns < 600
    ev = mon.on_reading(1, struct.pack("<I", encode_time_difference(1500)), 3)
    assert ev is not None and ev.unstable and ev.deviation_ns == 1500
    assert "sync unstable" in ev.text
    # still above half the limit: no event either way
    assert mon.on_reading(2, struct.pack("<I", encode_time_difference(900)), 3) is None
    ev = mon.on_reading(3, struct.pack("<I", encode_time_difference(100)), 3)
    assert ev is not None and not ev.unstable
    assert mon.worst_ns == 1500
    assert mon.on_reading(4, bytes(4), 0) is None  # nobody answered
    d = SyncMonitor.datagram()
    assert (d.command, d.ado, len(d.data)) == (Command.BRD, R.DC_SYSTEM_TIME_DIFFERENCE, 4)


def test_cycle_object_pickles_with_its_state() -> None:
    dc = DcCycle(DcMode.MASTER, 0x1001, CYCLE)
    run_lock(dc, 50.0, 50)
    copy = pickle.loads(pickle.dumps(dc))
    assert copy.lock is not None and dc.lock is not None
    assert copy.lock.integral == dc.lock.integral and copy.frames == 50
    assert DcMode.parse("Reference") is DcMode.REFERENCE
    with pytest.raises(ConfigError):
        DcMode.parse("slave")


def test_start_takes_the_monitor_period_and_limit() -> None:
    from pyethercat.clock import VirtualClock
    from pyethercat.link.pair import PairLink
    from pyethercat.master.dc import DcSettings
    from pyethercat.master.master import Master
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock(1_000_000_000)
    seg = parse_topology('[[slave]]\nname = "a"\ndevice = "builtin:coupler"\n'
                         '[[slave]]\nname = "b"\ndevice = "builtin:do8"\n').build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.scan()
    m.dc.setup(DcSettings(static_sync=500))
    runner = m.start(0.001, dc="master", clock=clock, dc_monitor=0.01, dc_limit=50e-9,
                     check_interval=0)
    try:
        assert runner.wait_exchanges("main", 200, 10.0)
    finally:
        runner.stop()
    assert runner.dc is not None
    mon = runner.dc.monitor
    assert (mon.period_ns, mon.limit_ns) == (10_000_000, 50)
    assert mon.readings >= 10
