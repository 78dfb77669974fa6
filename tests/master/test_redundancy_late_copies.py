"""Late copies of ring frames: a busy host is no dead port, and a late copy costs its cycle only.

A host that stalls hands the master one copy of a frame after the frame's
deadline (or not at all): that is not a dead port. Virtual time, the demo
segment closed into a ring in process, the ring watch riding in the loop;
a gate on one master port's receive loses copies (a copy later than its
frame's deadline is as good as lost) or lets the other port's copy of a
frame be read first, as the order of two sockets' readiness may.

- a closed ring whose port A copies come late, once or twice, while the
  watch reads the ring: no port fault, both ports still counted on;
- a split ring whose port B copy comes late once: that one cycle has a
  wrong working counter, the next is whole (not a second one that waited
  for A only), and no slave behind the break is taken for gone;
- a port that is really dead is still named: its carrier says so, or its
  copies miss several frames in a row (a NIC that stopped receiving), or
  the DL status at the cable's far end shows no link.
"""

from __future__ import annotations

from pathlib import Path

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.locate import MASTER, Cable, SlaveReading, locate
from pyethercat.master.master import Master
from pyethercat.master.redundancy import GIVE_UP_AFTER
from pyethercat.master.ringwatch import RingWatch
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import load_topology
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
#: The cable pulled in the split ring: di8 (bus position 2) port 1 to do8 (bus 3) port 0.
LINK = "between slave 2 port 1 and slave 3 port 0"
PORT_A_FAULT = "master port A (its cable to slave 0 port 0)"


class Gate:
    """Wraps the receive of one master port of an in-process ring.

    ``drop``: the next copies that arrive are lost (late past their frame's
    deadline); ``after_other``: a copy waits while the other port has one
    queued (the other port's copy of a frame is read first)."""

    def __init__(self, port: PairLink, other: PairLink) -> None:
        self.port, self.other = port, other
        self._recv = port.recv
        self.drop = 0
        self.dropped = 0
        self.after_other = False
        port.recv = self.recv  # type: ignore[method-assign]

    def recv(self, timeout: float | None = None) -> bytes | None:
        if self.after_other and self.other.pending():
            return None
        frame = self._recv(timeout)
        if frame is not None and self.drop > 0:
            self.drop -= 1
            self.dropped += 1
            return None
        return frame


def start():
    clock = VirtualClock()
    seg = load_topology(DEMO).build(clock=clock)
    link = ring_link(seg)
    m = Master(link, clock=clock)
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0,
                     recover=m.pd.recover)
    # A long interval: every reading below was asked for by what the loop noticed.
    w = RingWatch(m.ring, interval=10.0, log=r.log)
    r.riders.append(w)
    r.run(cycles=3)
    m.set_state(AlState.OP)
    w.refresh()
    r.run(cycles=5)
    a, b = link.ports
    return seg, m, r, w, Gate(a, b), Gate(b, a)


def found(m: Master) -> list[str]:
    return [e.fault.where for e in m.ring.events if not e.cleared]


def test_late_port_a_copies_of_a_closed_ring_are_no_port_fault() -> None:
    seg, m, r, w, gate_a, _ = start()
    readings = w.diagnoses
    for late in range(1, GIVE_UP_AFTER):
        w.refresh()  # a reading rides in the very frame whose A copy is late
        gate_a.drop = late
        r.run(cycles=10)
        assert gate_a.dropped == sum(range(1, late + 1))
        assert m.ring.state() == "redundant"
        assert [p.returning for p in m.ring.ports()] == [True, True]
    assert w.diagnoses > readings  # the watch did read the ring after each
    red = m.scheduler.core.redundancy
    assert red is not None and red.marks  # (each copy tells the port it was sent on)
    assert found(m) == []
    assert m.ring.last is not None and m.ring.last.ok and m.ring.last.ring_state == "closed"
    # a closed ring's copy back on B went round every slave: no cycle was short
    assert r.stats.wkc_errors == 0 and r.stats.lost_frames == 0


def test_a_late_port_b_copy_in_a_split_ring_costs_only_its_cycle() -> None:
    seg, m, r, w, _, gate_b = start()
    seg.break_link(1, 1)  # sim index 1 is the di8
    r.run(cycles=5)
    assert found(m) == [LINK]
    errors = r.stats.wkc_errors
    events = len(m.ring.events)
    gate_b.after_other = True  # A's half is read first from now on
    gate_b.drop = 1
    w.refresh()  # a reading rides in the frame whose B half comes late
    absent = set()
    for _ in range(10):
        r.run(cycles=1)
        absent |= r.absent
    assert gate_b.dropped == 1
    assert r.stats.wkc_errors == errors + 1  # the cycle whose B half came late, no other
    assert absent == set()  # nobody behind the break was taken for gone, not even briefly
    assert [e.text for e in list(m.ring.events)[events:]] == []
    assert m.ring.state() == "redundant"
    # the halves still meet in one cycle: the do8 before the break drives the di8 ...
    s = m.slaves
    for value in (0x5A, 0xA5):
        for i in range(8):
            s[3].outputs[f"Output {i + 1}"] = (value >> i) & 1
        r.run(cycles=2)
        assert sum(int(s[2].inputs[f"Input {i + 1}"]) << i for i in range(8)) == value


def test_port_a_that_stopped_receiving_is_named_after_copies_missing_in_a_row() -> None:
    seg, m, r, w, gate_a, _ = start()
    gate_a.drop = 10**9  # the NIC of port A receives nothing; its cable is fine
    r.run(cycles=GIVE_UP_AFTER + 5)
    assert m.ring.state() == "port B only"
    assert found(m) == [PORT_A_FAULT]
    (f,) = m.ring.faults
    assert f.detail == (f"slave 0 port 0: link up; no copy back on port A in "
                        f"{m.ring.ports()[0].misses} frames in a row")
    assert r.stats.wkc_errors == 0  # what port A sends still goes round the ring


def test_port_a_cable_fault_without_carrier_is_named() -> None:
    seg, m, r, w, _, _ = start()
    m.scheduler.link.ports[0].carrier_fn = None  # a medium that cannot tell
    seg.master_port_fault(0)
    r.run(cycles=GIVE_UP_AFTER + 5)
    assert found(m) == [PORT_A_FAULT]
    assert m.ring.faults[0].detail.startswith("slave 0 port 0: no link")
    assert r.stats.wkc_errors == 0
    seg.master_port_fault(0, broken=False)
    r.run(cycles=5)
    assert m.ring.faults == () and m.ring.state() == "redundant"


# -- locate: a master port named only when something confirms it ----------------------------

CABLES = [Cable((MASTER, 0), (0, 0)), Cable((0, 1), (1, 0)), Cable((1, 1), (MASTER, 1))]


def reading(pos: int, side: str, *down: int) -> SlaveReading:
    links = sum(reg.dl_status_link(p) for p in (0, 1) if p not in down)
    return SlaveReading(pos, side, links)


def test_every_slave_reached_from_b_alone_is_no_port_a_fault_without_confirmation() -> None:
    readings = [reading(0, "B"), reading(1, "B")]
    assert locate(CABLES, readings, ring=True, returned=("B",)) == []
    (f,) = locate(CABLES, readings, ring=True, returned=("B",),
                  port_evidence={"A": "port A: no carrier"})
    assert (f.kind, f.where) == ("port", PORT_A_FAULT)
    assert f.detail == "slave 0 port 0: link up; port A: no carrier"
    (f,) = locate(CABLES, [reading(0, "B", 0), reading(1, "B")], ring=True, returned=("B",))
    assert (f.kind, f.detail) == ("port", "slave 0 port 0: no link")


def test_port_b_named_from_its_far_end() -> None:
    readings = [reading(0, "A"), reading(1, "A", 1)]
    (f,) = locate(CABLES, readings, ring=True, returned=("A",))
    assert f.where == "master port B (its cable to slave 1 port 1)"
    assert locate(CABLES, [reading(0, "A"), reading(1, "A")], ring=True, returned=("A",)) == []
