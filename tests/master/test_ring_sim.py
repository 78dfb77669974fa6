"""Our master on a simulated ring (in-process, both ports): scan and process data through faults.

The demo topology closed into a ring at its last slave (ai2, port 1); the
do8's outputs are wired to the di8's inputs, so an output pattern comes back
as inputs only if both halves of a split ring did their part in the same
cycle.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cycleplan import plan_frames
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import load_topology

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def open_ring():
    seg = load_topology(DEMO).build()
    m = Master(ring_link(seg), clock=VirtualClock())
    return seg, m


def names_and_stations(m: Master) -> list[tuple[str, int]]:
    return [(s.name, s.station_address) for s in m.slaves]


def test_ring_closes_at_the_last_slave_in_bus_order() -> None:
    seg, m = open_ring()
    # file order puts the coupler's port-3 branch last; on the wire ai2 is last
    assert seg.ring == (4, 1)
    m.close()


@pytest.mark.parametrize("fault", ["none", "link", "port A", "port B"])
def test_scan_finds_every_slave_in_bus_order_whatever_single_fault(fault: str) -> None:
    seg, m = open_ring()
    m.scan()
    want = names_and_stations(m)
    if fault == "link":
        seg.break_link(1, 1)  # between di8 (bus position 2) and do8
    elif fault == "port A":
        seg.master_port_fault(0)
    elif fault == "port B":
        seg.master_port_fault(1)
    m.scan()
    assert names_and_stations(m) == want
    assert m.scheduler.stats.timeouts == 0
    m.close()


def test_scan_without_the_failed_node_keeps_bus_order() -> None:
    seg, m = open_ring()
    m.scan()
    before = [s.name for s in m.slaves]
    seg.power_off(2)  # the do8 on the coupler's E-bus (bus position 3)
    m.scan()
    assert [s.name for s in m.slaves] == before[:3] + before[4:]
    m.close()


def start(seg, m):
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=VirtualClock(), check_interval=0)
    r.run(cycles=2)
    m.set_state("OP")
    return r


def loops_back(m: Master, r: CyclicRunner, pattern: int) -> bool:
    s = m.slaves
    for i in range(8):
        s[3].outputs[f"Output {i + 1}"] = (pattern >> i) & 1
    r.run(cycles=2)
    return sum(int(s[2].inputs[f"Input {i + 1}"]) << i for i in range(8)) == pattern


FAULTS = {
    "link between di8 and do8": (lambda seg: seg.break_link(1, 1), lambda seg: seg.restore_link(1, 1)),
    "link at the coupler": (lambda seg: seg.break_link(0, 1), lambda seg: seg.restore_link(0, 1)),
    "port A": (lambda seg: seg.master_port_fault(0), lambda seg: seg.master_port_fault(0, False)),
    "port B": (lambda seg: seg.master_port_fault(1), lambda seg: seg.master_port_fault(1, False)),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_process_data_complete_and_correct_through_a_fault(fault: str) -> None:
    seg, m = open_ring()
    r = start(seg, m)
    cause, mend = FAULTS[fault]
    for step in (cause, mend, cause, mend):
        step(seg)
        for pattern in (0x5A, 0xA5, 0x0F):
            assert loops_back(m, r, pattern)
        assert m.slaves[5].inputs["Value 1"] == 0x1234
    assert r.stats.wkc_errors == 0 and r.stats.lost_frames == 0
    red = m.scheduler.core.redundancy
    assert red is not None and red.state() == "redundant"
    m.close()


def test_split_ring_halves_come_back_on_their_own_ports() -> None:
    seg, m = open_ring()
    r = start(seg, m)
    seg.break_link(1, 1)
    ticket = m.scheduler.send_prepared(plan_frames(m.scheduler, list(r.groups))[0][0].template)
    assert ticket.wait_raw() is not None
    assert ticket.copies is not None and set(ticket.copies) == {0, 1}
    m.close()


def test_a_one_port_master_on_a_ring_topology_still_works() -> None:
    seg = load_topology(DEMO).build()
    seg.close_ring()  # cabled, but the master has one port: the last slave loops back
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    assert len(m.scan()) == 6
    m.close()
