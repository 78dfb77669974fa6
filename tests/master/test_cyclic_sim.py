"""Cyclic exchange against the simulator (in-process, synchronous pair link).

The demo topology: coupler, do8 on a branch (port 3), di8, do8, di2, ai2; the
do8 outputs are wired to the di8 inputs and two branch outputs to the 2-bit
terminal, which the packed layout maps bitwise.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import wait_for

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.config import Layout
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def open_sim():
    from pyethercat.sim.topology import load_topology

    seg = load_topology(DEMO).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    return seg, m


@pytest.mark.parametrize("layout", [Layout.PACKED, Layout.BYTE])
def test_loop_back_through_the_simulator_bit_exactly(layout):
    seg, m = open_sim()
    cfg = m.configure(layout=layout)
    di2 = cfg.slaves[4].fmmus[0]
    if layout is Layout.PACKED:
        # the 2-bit terminal takes 2 bits of a byte, bitwise
        assert (di2.length, di2.logical_start_bit, di2.logical_stop_bit) == (1, 0, 1)
    else:
        assert (di2.logical_start_bit, di2.logical_stop_bit) == (0, 7)
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=VirtualClock(), check_interval=0)
    r.run(cycles=2)
    m.set_state("OP")
    assert all(s.al_state == AlState.OP for s in m.slaves)
    s = m.slaves
    for pattern in list(range(256)) + [0xA5, 0x5A, 0]:
        for i in range(8):
            s[3].outputs[f"Output {i + 1}"] = (pattern >> i) & 1
        s[1].outputs["Output 1"] = pattern & 1
        s[1].outputs["Output 2"] = (pattern >> 1) & 1
        r.run(cycles=2)
        got = sum(int(s[2].inputs[f"Input {i + 1}"]) << i for i in range(8))
        assert got == pattern
        assert (s[4].inputs["Input 1"], s[4].inputs["Input 2"]) == (bool(pattern & 1),
                                                                     bool(pattern & 2))
    assert s[5].inputs["Value 1"] == 0x1234 and s[5].inputs["Value 2"] == -0x5433
    assert r.stats.wkc_errors == 0 and r.groups[0].wkc_ok


def test_link_break_and_power_cycle_recovered_without_restart():
    seg, m = open_sim()
    m.configure()
    with m.start(cycle=0.002, check_interval=0.02) as r:
        def seen(text):
            return any(text in e.text for e in r.events)

        def all_ok():
            return all(h.status == "ok" for h in r.health.values()) and r.groups[0].wkc_ok

        assert wait_for(lambda: r.stats.cycles > 10 and all_ok())
        # the cable between di8 (position 2) and do8 (3) is pulled: 3, 4, 5 vanish
        di8 = seg.slave("di8").index
        seg.break_link(di8, 1)
        assert wait_for(lambda: seen("slave 3 (0x1004) vanished"))
        assert wait_for(lambda: seen("slave 5 (0x1006) vanished"))
        seg.restore_link(di8, 1)
        assert wait_for(lambda: all_ok() and seen("slave 3 back in OP"))
        # the di2 (4) loses power and comes back: address 0, INIT, no configuration
        before = r.health[4].recoveries
        di2 = seg.slave("di2").index
        seg.power_off(di2)
        assert wait_for(lambda: r.health[4].status != "ok")
        seg.power_on(di2)
        assert wait_for(lambda: r.health[4].recoveries > before and all_ok())
        m.slaves[1].outputs["Output 2"] = 1
        assert wait_for(lambda: m.slaves[4].inputs["Input 2"] is True)
