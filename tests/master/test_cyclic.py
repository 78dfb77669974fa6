"""Cyclic exchange against a register-level fake segment with logical addressing.

Outputs loop back to inputs bit-exactly (packed 2-bit terminals included),
statistics are computed on a virtual clock, and slaves that drop out of OP,
vanish behind a broken link or are power-cycled are found and brought back
without restarting the master.
"""

from __future__ import annotations

import pytest
from conftest import wait_for
from fake_esc_segment import FakeSlave
from fake_logical import LogicalSegment
from master_sii_helpers import coupler, di, do

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import build_sii

IN_RAM, OUT_RAM = 0x1180, 0x1100


def make(layout: str = "packed"):
    siis = [coupler(), do(2), di(2), do(2), di(2), do(8), di(8)]
    seg = LogicalSegment([FakeSlave(build_sii(s)) for s in siis])
    # do2 (1) -> di2 (2), do2 (3) -> di2 (4), do8 (5) -> di8 (6)
    seg.wires = [(1, OUT_RAM, 2, IN_RAM, 2), (3, OUT_RAM, 4, IN_RAM, 2), (5, OUT_RAM, 6, IN_RAM, 8)]
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.configure(layout=layout)
    return seg, m


def runner(m: Master, clock=None, **kw) -> CyclicRunner:
    assert m.process_data is not None
    return CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                        clock=clock or VirtualClock(), **kw)


@pytest.mark.parametrize("layout", ["packed", "byte"])
def test_outputs_loop_back_to_inputs_bit_exactly(layout):
    seg, m = make(layout)
    g = m.process_data.groups[0]
    assert (g.output_bytes, g.input_bytes) == ((2, 2) if layout == "packed" else (3, 3))
    m.pd.bring_up(m.slaves, 1.0)
    r = runner(m, check_interval=0)
    r.run(cycles=2)
    m.set_state("OP")
    s = m.slaves
    for pattern in range(16):
        s[1].outputs["Output 1"] = pattern & 1
        s[1].outputs["Output 2"] = (pattern >> 1) & 1
        s[5].outputs.update({f"Output {i + 1}": (pattern * 37 >> i) & 1 for i in range(8)})
        s[3].outputs["Output 2"] = (pattern >> 2) & 1
        r.run(cycles=2)  # one cycle writes, the wire copies, the next one reads
        assert s[2].inputs["Input 1"] == bool(pattern & 1)
        assert s[2].inputs["Input 2"] == bool(pattern & 2)
        assert [s[6].inputs[f"Input {i + 1}"] for i in range(8)] == [
            bool((pattern * 37 >> i) & 1) for i in range(8)]
        assert s[4].inputs["Input 2"] == bool(pattern & 4) and s[4].inputs["Input 1"] is False
    grp = r.groups[0]
    assert grp.wkc_ok and grp.total_wkc == grp.expected_wkc == 3 * 2 + 3 * 1
    assert r.stats.wkc_errors == 0 and r.stats.lost_frames == 0


def test_statistics_on_a_virtual_clock():
    seg, m = make()
    m.pd.bring_up(m.slaves, 1.0)
    clock = VirtualClock()
    period = 1_000_000

    def work(cycle):
        clock.advance(10_000)  # every cycle: 10 us of exchange + callback
        if cycle.index == 20:
            clock.advance(int(2.5 * period))  # a callback that stalls for 2.5 periods

    r = runner(m, clock, callback=work, check_interval=0)
    stats = r.run(cycles=100)
    assert stats.cycles == 100
    # cycle 20 ends 2.51 ms after its deadline: deadlines 21 and 22 are skipped
    assert stats.overruns == 1 and stats.callback_overruns == 1 and stats.skipped == 2
    p = stats.periods()
    assert p.size == 98  # no period sample across the skipped deadline
    assert set(p.tolist()) == {period}
    lat = stats.latencies()
    assert lat.max() == 0 and stats.late == 0  # the loop resumed at deadline 23, on time
    assert stats.jitter_us()["p100"] == 0.0
    summary = stats.summary()
    assert summary["cycles"] == 100 and summary["histogram"]["<1us"] == 98
    assert stats.frames == 100


def test_a_cycle_that_overruns_a_little_is_followed_at_once_not_skipped():
    """An overrun shorter than the late threshold (a quarter period) delays the next cycle;
    a longer one skips to the next deadline ahead."""
    seg, m = make()
    m.pd.bring_up(m.slaves, 1.0)
    clock = VirtualClock()
    period = 1_000_000

    def work(cycle):
        clock.advance(10_000)
        if cycle.index == 20:
            clock.advance(period + 100_000)  # ends 0.11 ms after the next deadline
        if cycle.index == 50:
            clock.advance(period + 300_000)  # ends 0.31 ms after it: past the threshold

    r = runner(m, clock, callback=work, check_interval=0)
    stats = r.run(cycles=100)
    assert stats.overruns == 2 and stats.skipped == 1  # only the second overrun skips
    lat = stats.latencies()
    assert lat[21] == 110_000 and stats.late == 0  # cycle 21 ran 0.11 ms late, not "late"
    assert lat[22] == 0  # and cycle 22 was back on its deadline
    assert lat[51] == 0  # after the skip: deadline 52, on time
    assert stats.frames == 100


def test_wkc_error_and_lost_frame_are_counted():
    seg, m = make()
    m.pd.bring_up(m.slaves, 1.0)
    r = runner(m, check_interval=0)
    r.run(cycles=3)
    seg.break_after = 2  # slaves 3.. stop answering
    r.run(cycles=2)
    assert r.stats.wkc_errors == 2 and not r.groups[0].wkc_ok
    assert r.groups[0].total_wkc == 2 * 1 + 1 * 1  # only slaves 1 and 2 answer
    seg.break_after = None
    seg.faults[seg.frames] = "drop"
    r.run(cycles=2)
    assert r.stats.lost_frames == 1 and r.groups[0].lost == 1
    assert r.groups[0].wkc_ok


def test_dropped_broken_and_power_cycled_slaves_recover():
    seg, m = make()
    with m.start(cycle=0.001, check_interval=0.01) as r:
        assert all(s.al_state == AlState.OP for s in m.slaves)
        assert wait_for(lambda: r.stats.cycles > 20)

        def seen(text):
            return any(text in e.text for e in r.events)

        def all_ok():
            return all(h.status == "ok" for h in r.health.values()) and r.groups[0].wkc_ok

        # 1) a slave drops to SAFEOP+ERR (watchdog): acknowledged and back in OP
        seg.drop_to(6, AlState.SAFEOP)
        assert wait_for(lambda: seen("slave 6 left OP: now SAFEOP+ERR (AL code 0x001B)"))
        assert wait_for(lambda: seen("slave 6 back in OP") and seg.slaves[6].al_status == 8)
        # (the recovery logs "back in OP" before it counts the recovery in the health record)
        assert wait_for(lambda: r.health[6].recoveries == 1), r.health[6]
        # 2) the link behind slave 2 breaks: slaves 3.. vanish, come back when it heals
        seg.break_after = 2
        assert wait_for(lambda: seen("slave 5 (0x1006) vanished"))
        assert not r.groups[0].wkc_ok
        seg.break_after = None
        assert wait_for(lambda: seen("slave 5 back in OP") and all_ok())
        # 3) slave 5 is power-cycled: station address 0, INIT, no SM/FMMU config
        before = r.health[5].recoveries
        seg.power_cycle(5)
        assert wait_for(lambda: r.health[5].recoveries > before and all_ok())
        assert seg.slaves[5].station == m.slaves[5].station_address
        assert seg.slaves[5].al_status == AlState.OP
        # and process data flows again through the re-configured slave
        m.slaves[5].outputs["Output 5"] = 1
        assert wait_for(lambda: m.slaves[6].inputs["Input 5"] is True)
    assert not r.running
