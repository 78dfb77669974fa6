"""The simulated ring: frames entering at master port A or B, faults, hot swap.

What a real ring does (ETG.1000.4 section 5.4, ET1100 datasheet section I
"Frame processing"): the copy sent on A is processed by every slave and
leaves at B; the copy sent on B travels backwards through ports that only
forward and comes back at A untouched. A broken cable closes the loops on
both sides of the break, so each copy is processed by the slaves on its
side only, and returns to the port it was sent from.
"""

from __future__ import annotations

import struct

import pytest
from simhelp import line, spec

from pyethercat.errors import ConfigError
from pyethercat.sim.host import Dirty
from pyethercat.sim.ports import PORT_A, PORT_B
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import CIRCULATING_BIT, Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame


def ring(n: int = 6):
    seg = line(n)
    seg.close_ring()
    seg.attach_port_b()
    return seg


def send(seg, port: int, *dgrams: Datagram):
    got = seg.process_from(encode_frame(list(dgrams)), port)
    if got is None:
        return None, []
    exit_port, raw = got
    return exit_port, decode_frame(raw).datagrams


def brd() -> Datagram:
    return Datagram.device(Command.BRD, 0, R.TYPE, 1)


def positions_answering(seg, port: int) -> list[int]:
    """Which slaves (by index) answer an FPRD of their station address in a copy sent on ``port``."""
    dgs = [Datagram.device(Command.FPRD, 0x1000 + i, R.STATION_ADDRESS, 2) for i in range(len(seg.slaves))]
    _, got = send(seg, port, *dgs)
    return [i for i, d in enumerate(got) if d.wkc == 1]


def address(seg) -> None:
    for i in range(len(seg.slaves)):
        seg.slaves[i].write(R.STATION_ADDRESS, struct.pack("<H", 0x1000 + i))
    seg.state.topology_dirty = True


def test_intact_ring_a_copy_is_processed_and_leaves_at_b() -> None:
    seg = ring()
    exit_port, (d,) = send(seg, PORT_A, brd())
    assert exit_port == PORT_B and d.wkc == 6


def test_intact_ring_b_copy_passes_untouched_and_leaves_at_a() -> None:
    seg = ring()
    exit_port, (d,) = send(seg, PORT_B, brd())
    assert exit_port == PORT_A and d.wkc == 0 and d.adp == 0


def test_without_a_nic_at_b_the_last_slave_closes_the_loop() -> None:
    seg = line(6)
    seg.close_ring()  # cabled, but nothing listens at the master's port B
    exit_port, (d,) = send(seg, PORT_A, brd())
    assert exit_port == PORT_A and d.wkc == 6
    # and a frame sent into the unconnected port B reaches nothing
    assert seg.process_from(encode_frame([brd()]), PORT_B) is None
    with pytest.raises(ConfigError):
        line(2).process_from(encode_frame([brd()]), PORT_B)  # no ring at all


@pytest.mark.parametrize("cut", [0, 2, 4])
def test_broken_link_splits_the_ring_into_two_halves(cut: int) -> None:
    seg = ring()
    address(seg)
    seg.break_link(cut, 1)  # between slave cut (port 1) and cut + 1 (port 0)
    exit_a, (da,) = send(seg, PORT_A, brd())
    exit_b, (db,) = send(seg, PORT_B, brd())
    assert (exit_a, exit_b) == (PORT_A, PORT_B)
    assert (da.wkc, db.wkc) == (cut + 1, 6 - cut - 1)
    assert positions_answering(seg, PORT_A) == list(range(cut + 1))
    assert positions_answering(seg, PORT_B) == list(range(cut + 1, 6))


def test_b_half_is_processed_in_bus_order_with_the_circulating_bit() -> None:
    seg = ring()
    seg.break_link(2, 1)
    # auto-increment from the B side counts from the first slave behind the break
    _, (d,) = send(seg, PORT_B, Datagram.positional(Command.APRD, 0, R.TYPE, 1))
    assert d.wkc == 1 and d.adp == 3
    _, (d,) = send(seg, PORT_B, Datagram.positional(Command.APRD, 2, R.TYPE, 1))
    assert d.wkc == 1
    # the first slave behind the break loops the frame in through its closed port 0
    got = seg.process_from(encode_frame([brd()]), PORT_B)
    assert got is not None
    word = struct.unpack_from("<H", got[1], 14 + 2 + 6)[0]
    assert word & CIRCULATING_BIT


def test_powered_off_node_is_missing_from_both_halves() -> None:
    seg = ring()
    address(seg)
    seg.power_off(3)
    assert positions_answering(seg, PORT_A) == [0, 1, 2]
    assert positions_answering(seg, PORT_B) == [4, 5]
    seg.power_on(3)
    seg.slaves[3].write(R.STATION_ADDRESS, struct.pack("<H", 0x1003))
    exit_port, (d,) = send(seg, PORT_A, brd())
    assert exit_port == PORT_B and d.wkc == 6


def test_port_a_fault_b_copy_goes_round_and_comes_back_at_b() -> None:
    seg = ring()
    seg.master_port_fault(PORT_A)
    assert seg.process_from(encode_frame([brd()]), PORT_A) is None
    exit_port, (d,) = send(seg, PORT_B, brd())
    assert exit_port == PORT_B and d.wkc == 6
    seg.master_port_fault(PORT_A, broken=False)
    assert send(seg, PORT_A, brd())[0] == PORT_B


def test_port_b_fault_a_copy_loops_at_the_last_slave() -> None:
    seg = ring()
    seg.master_port_fault(PORT_B)
    exit_port, (d,) = send(seg, PORT_A, brd())
    assert exit_port == PORT_A and d.wkc == 6
    assert seg.process_from(encode_frame([brd()]), PORT_B) is None


def test_dl_status_and_lost_link_counters_name_the_break() -> None:
    seg = ring()
    send(seg, PORT_A, brd())  # links seen up
    seg.break_link(1, 1)
    send(seg, PORT_A, brd())
    before = seg.slaves[1].u16(R.DL_STATUS)
    after = seg.slaves[2].u16(R.DL_STATUS)
    assert not before & R.dl_status_link(1) and not after & R.dl_status_link(0)
    assert seg.slaves[1].read(R.LOST_LINK_COUNTER + 1, 1) == b"\x01"
    assert seg.slaves[2].read(R.LOST_LINK_COUNTER, 1) == b"\x01"


def test_hot_swap_with_another_device() -> None:
    seg = ring()
    address(seg)
    seg.remove_slave(2)
    assert seg.removed(2)
    assert positions_answering(seg, PORT_A) == [0, 1]
    seg.insert_slave(2, spec("other", product=0x4242, in_bits=8))
    assert not seg.removed(2)
    # the new device starts at station address 0 with its own identity
    assert seg.slaves[2].u16(R.STATION_ADDRESS) == 0
    assert seg.slaves[2].name == "other"
    assert seg.slaves[2].esc.sii_info.product_code == 0x4242
    exit_port, (d,) = send(seg, PORT_A, brd())
    assert exit_port == PORT_B and d.wkc == 6


def test_alternating_ports_keep_separate_compiled_state() -> None:
    seg = ring()
    address(seg)
    seg.break_link(2, 1)
    for _ in range(3):
        assert positions_answering(seg, PORT_A) == [0, 1, 2]
        assert positions_answering(seg, PORT_B) == [3, 4, 5]
    # a change made while frames enter at B reaches the A side's compiled state too
    seg.slaves[0].write(R.STATION_ADDRESS, struct.pack("<H", 0x2000))
    seg.invalidate(Dirty.ADDRESSING)
    send(seg, PORT_B, brd())
    _, (d,) = send(seg, PORT_A, Datagram.device(Command.FPRD, 0x2000, R.TYPE, 1))
    assert d.wkc == 1


def test_topology_ring_key_closes_the_ring_where_it_says() -> None:
    from pyethercat.sim.topology import parse_topology

    text = '''
[segment]
ring = "%s"
[[slave]]
name = "a"
device = "builtin:coupler"
[[slave]]
name = "b"
device = "builtin:di8"
'''
    assert parse_topology(text % "b:1").build().ring == (1, 1)
    assert parse_topology(text.replace('"%s"', "true")).build().ring == (1, 1)
    with pytest.raises(ConfigError, match="no slave named 'x'"):
        parse_topology(text % "x:1")
    with pytest.raises(ConfigError, match="port"):
        parse_topology(text % "b:7")
