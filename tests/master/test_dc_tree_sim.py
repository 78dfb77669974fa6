"""Distributed clocks end to end on virtual time: our master on a simulated 50-slave tree.

The tree (examples/dc-tree-50.toml) has a cross (coupler A uses all four
ports) and forks on ports 1, 2 and 3; every oscillator is off by up to
+-100 ppm. Master and simulator share one virtual clock, so 60 s of 1 kHz
cycles are exact and repeatable.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.dc import DcSettings
from pyethercat.master.master import Master
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import load_topology

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
EPOCH = 800_000_000_000_000_000  # the master's "now" at virtual time 0 (ns since 2000)


def bring_up(n: int) -> tuple[Segment, Master, VirtualClock]:
    clock = VirtualClock(1_000_000_000)
    seg = load_topology(EXAMPLES / f"dc-tree-{n}.toml").build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + EPOCH
    m.scan()
    return seg, m, clock


def true_delays(seg: Segment, reference: int) -> list[int]:
    """The simulator's delay of each slave (ring order) behind the reference's processing unit."""
    route = seg.route
    passes = route.passes.tolist()
    epu = route.epu_ns
    return [int(epu[s] - epu[passes[reference]]) for s in passes]


def sync0_spread(seg: Segment) -> tuple[float, int]:
    """Largest spread (ns) of the recorded SYNC0 pulses that every pulsing slave fired; pulses seen."""
    sys_, true = seg.dc.sync.recorded_pulses()
    pulsing = np.nonzero(seg.dc.sync.pulses[: len(seg.slaves)] > 0)[0]
    if not len(pulsing):
        return 0.0, 0
    rows_sys, rows_true = sys_[pulsing], true[pulsing]
    worst, seen = 0.0, 0
    for value in np.unique(rows_sys[0]):
        hit = rows_sys == value
        if value == 0 or not hit.any(axis=1).all():
            continue  # not (yet) recorded by every slave
        times = rows_true[hit]
        worst = max(worst, float(times.max() - times.min()))
        seen += 1
    return worst, seen


def test_delays_match_the_simulator_within_10ns() -> None:
    seg, m, _ = bring_up(50)
    report = m.dc.setup(DcSettings(static_sync=600))
    want = true_delays(seg, report.reference or 0)
    got = [s.delay_ns for s in report.slaves]
    assert report.reference == 0
    errors = [g - w for g, w in zip(got, want, strict=True) if g is not None]
    assert len(errors) == 50
    assert max(abs(e) for e in errors) <= 10, errors


@pytest.mark.slow
def test_fifty_slaves_stay_within_50ns_for_60s_and_after_a_20ppm_step() -> None:
    seg, m, clock = bring_up(50)
    report = m.dc.setup(DcSettings(trace_every=1000))
    # static compensation: 15000 FRMW in 203 frames, well under a second of (virtual) time
    assert report.static_frames <= 210 and report.duration_s < 0.5
    m.configure()
    assert len(m.dc.configure_sync(1_000_000)) == 46  # every terminal; couplers have no DC mode
    m.pd.bring_up(m.slaves, 5.0)
    plan = m.dc.cycle(1_000_000, "master", clock)
    runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                          clock=clock, check_interval=0, dc=plan)
    worst_before = worst_after = 0.0
    pulses = 0
    stepped = False
    start = clock.now_ns()
    while clock.now_ns() - start < 60_000_000_000:
        runner.run(seconds=0.05)
        spread, seen = sync0_spread(seg)
        pulses += seen
        if stepped:
            worst_after = max(worst_after, spread)
        else:
            worst_before = max(worst_before, spread)
        if not stepped and clock.now_ns() - start >= 30_000_000_000:
            drift = seg.dc_report()[7]["drift_ppm"]
            assert isinstance(drift, float)
            seg.set_drift(7, drift + 20.0)
            stepped = True
    assert pulses > 50_000  # (nearly) every cycle's pulse compared across all slaves
    assert worst_before < 50, worst_before
    assert worst_after < 50, worst_after
    assert runner.stats.wkc_errors == 0 and runner.stats.lost_frames == 0
    assert plan.lock is not None and plan.lock.locked
    assert plan.monitor.worst_ns < 100


def test_reference_follows_the_master() -> None:
    seg, m, clock = bring_up(20)
    m.dc.setup(DcSettings(static_sync=3000))
    m.configure()
    m.dc.configure_sync(1_000_000)
    m.pd.bring_up(m.slaves, 5.0)
    plan = m.dc.cycle(1_000_000, "reference", clock)
    runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                          clock=clock, check_interval=0, dc=plan)
    runner.run(seconds=3.0)
    # the reference's time has been pulled onto the master's and the others follow it
    assert plan.master_difference_ns is not None and abs(plan.master_difference_ns) < 2_000
    runner.run(seconds=0.1)
    spread, seen = sync0_spread(seg)
    assert seen > 50 and spread < 50
    assert not plan.monitor.unstable


def test_a_real_deviation_raises_a_sync_event_and_clears_it_again() -> None:
    """A slave's quartz steps by 900 ppm: the loop reports "sync unstable", then stable."""
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock(1_000_000_000)
    seg = parse_topology('[[slave]]\nname = "a"\ndevice = "builtin:coupler"\n'
                         '[[slave]]\nname = "b"\ndevice = "builtin:do8"\n'
                         '[[slave]]\nname = "c"\ndevice = "builtin:di8"\n').build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + EPOCH
    m.scan()
    m.dc.setup(DcSettings(static_sync=1000))
    m.configure()
    m.dc.configure_sync(1_000_000)
    runner = m.start(0.001, dc="master", clock=clock, dc_monitor=0.01, dc_limit=1e-6,
                     check_interval=0)
    try:
        runner.wait_exchanges("main", 300, 20.0)
        assert list(runner.dc_events) == []  # in sync: nothing to report
        drift = seg.dc_report()[2]["drift_ppm"]
        assert isinstance(drift, float)
        seg.set_drift(2, drift + 900.0)  # beyond what 0x0930 = 0x1000 lets the loop follow
        runner.wait_exchanges("main", 600, 30.0)
        events = list(runner.dc_events)
        assert len(events) == 1 and events[0].unstable, [e.text for e in events]
        assert events[0].limit_ns == 1000 and events[0].deviation_ns > 1000
        assert events[0].text.startswith("sync unstable: system time difference up to")
        assert runner.dc is not None and runner.dc.monitor.unstable
        seg.set_drift(2, drift)  # the quartz recovers: the loop pulls the clock back
        runner.wait_exchanges("main", 1500, 60.0)
        events = list(runner.dc_events)
        assert [e.unstable for e in events] == [True, False], [e.text for e in events]
        assert events[1].deviation_ns < 500 and events[1].time_ns > events[0].time_ns
        assert not runner.dc.monitor.unstable
    finally:
        runner.stop()
