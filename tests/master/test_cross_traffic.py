"""Cross traffic: a slave's inputs reach a later slave's outputs in the same frame.

The consumer's output FMMU is laid over the producer's input bits in the
logical image; the simulator (like an ESC) processes the frame slave after
slave, so what the producer writes into the frame is what the consumer
takes out of it a few hundred nanoseconds later, with no master in between.
Also from an ENI (outputs laid over another slave's inputs), and on a ring
whose cable between producer and consumer is pulled: the frame then goes
out on port A and on through port B, so the two still meet in one frame.
"""

from __future__ import annotations

import numpy as np
import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError
from pyethercat.esi.eni import build_eni, parse_eni
from pyethercat.link.pair import PairLink
from pyethercat.master.config import CrossLink
from pyethercat.master.cross import cross_links_from_eni
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.esi_config import eni_from_master, start_from_eni
from pyethercat.master.master import Master
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.al import AlState

TOPO = {"slave": [{"name": "coupler", "device": "builtin:coupler"},
                  {"name": "src", "device": "builtin:di8"},
                  {"name": "mid", "device": "builtin:do8"},
                  {"name": "dst", "device": "builtin:do8"},
                  {"name": "tail", "device": "builtin:di8"}]}


def start(ring: bool = False, cross: list[CrossLink] | None = None):
    clock = VirtualClock()
    doc = dict(TOPO)
    if ring:
        doc["segment"] = {"ring": True}
    seg = parse_topology(doc).build(clock=clock)
    m = Master(ring_link(seg) if ring else PairLink.responder_link(seg.process), clock=clock)
    m.scan()
    cfg = m.configure(cross=cross if cross is not None else [CrossLink(producer=1, consumer=3)])
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0)
    r.run(cycles=3)
    m.set_state(AlState.OP)
    return seg, m, r


def set_src(seg, value: int) -> None:
    seg.pdio.set_inputs(np.array([1], np.int64), np.array([[value]], np.uint8))


def dst_outputs(seg) -> int:
    return int(seg.pdio.outputs(np.array([3], np.int64), 1)[0, 0])


def test_inputs_of_one_slave_are_outputs_of_a_later_one_in_the_same_frame() -> None:
    seg, m, r = start()
    for value in (0x5A, 0xA5, 0x01, 0xFF):
        set_src(seg, value)
        r.run(cycles=1)  # one frame: src writes it, dst takes it
        assert dst_outputs(seg) == value
        # the master sees it as the consumer's outputs view (the producer's input bits)
        assert sum(int(m.slaves[3].outputs[f"Output {i + 1}"]) << i for i in range(8)) == value
    assert r.stats.wkc_errors == 0
    # the master's own outputs still reach the slave without cross traffic
    for i in range(8):
        m.slaves[2].outputs[f"Output {i + 1}"] = (0x3C >> i) & 1
    r.run(cycles=1)
    assert int(seg.pdio.outputs(np.array([2], np.int64), 1)[0, 0]) == 0x3C


def test_the_consumer_counts_in_the_working_counter_of_the_inputs() -> None:
    _, m, r = start()
    cfg = m.pd.config
    assert cfg is not None
    (d,) = cfg.groups[0].datagrams
    # do8 x2 (outputs, +2 each), di8 x2 (inputs, +1 each): the same total, the consumer
    # now counted where the producer's inputs are
    assert d.expected_wkc == 6 and set(d.positions) == {1, 2, 3, 4}
    assert r.groups[0].wkc_ok


def test_a_consumer_before_its_producer_is_refused() -> None:
    with pytest.raises(ConfigError, match="producer must come before the consumer"):
        start(cross=[CrossLink(producer=4, consumer=3)])


def test_cross_traffic_over_a_broken_ring_in_one_frame() -> None:
    seg, m, r = start(ring=True)
    seg.break_link(2, 1)  # between mid (2) and dst (3): src on A's side, dst on B's
    for value in (0x11, 0x22, 0x33):
        set_src(seg, value)
        r.run(cycles=1)
        assert dst_outputs(seg) == value
    red = m.scheduler.core.redundancy
    assert red is not None and red.forwards >= 3  # out on A, on through B
    assert r.stats.wkc_errors == 0


def test_cross_traffic_from_an_eni() -> None:
    _, m, _ = start()
    eni = parse_eni(build_eni(eni_from_master(m)))
    assert cross_links_from_eni(eni.slaves) == [CrossLink(1, 3, 8, 0)]


def test_cross_traffic_configured_from_an_eni_flows_slave_to_slave() -> None:
    """A master started from the ENI of another (its cross links among the slaves' Send
    and Recv areas) passes the producer's inputs to the consumer's outputs in one frame."""
    _, m, _ = start()
    xml = build_eni(eni_from_master(m))
    m.close()
    clock = VirtualClock()
    seg = parse_topology(dict(TOPO)).build(clock=clock)
    m2 = Master(PairLink.responder_link(seg.process), clock=clock)
    start_from_eni(m2, parse_eni(xml))
    cfg = m2.configure()
    m2.pd.bring_up(m2.slaves, 2.0)
    r = CyclicRunner(m2.scheduler, cfg, m2.images, m2.slaves, clock=clock, check_interval=0)
    r.run(cycles=3)
    m2.set_state(AlState.OP)
    for value in (0x5A, 0xA5, 0x3C):
        set_src(seg, value)
        r.run(cycles=1)
        assert dst_outputs(seg) == value
    assert r.stats.wkc_errors == 0 and r.groups[0].wkc_ok
