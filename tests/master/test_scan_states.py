"""Scan, SII access, topology, expected configuration and states against the fake segment."""

from __future__ import annotations

import struct

import pytest
from fake_esc_segment import FakeSegment, FakeSlave
from master_sii_helpers import BOOL, io_sii

from pyethercat.clock import VirtualClock
from pyethercat.errors import AlStatusError, SiiError, StateTimeoutError, TopologyMismatchError
from pyethercat.link.pair import PairLink
from pyethercat.master import Identity, Master
from pyethercat.master.scan import ExpectedSlave, build_topology
from pyethercat.master.slave import Slave
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.sii import build_sii, parse_sii


def _image(name: str, product: int, alias: int = 0) -> bytes:
    info = io_sii(name, outputs=[("Out 1", 1, BOOL)], inputs=[("In 1", 1, BOOL)],
                  product=product)
    info.vendor_id = 0x2
    info.revision = 0x00110000
    info.serial = product + 7
    info.station_alias = alias
    return build_sii(info)


class Counting:
    def __init__(self, seg: FakeSegment) -> None:
        self.seg = seg
        self.frames = 0

    def __call__(self, frame: bytes) -> object:
        self.frames += 1
        return self.seg.process(frame)


def _master(slaves: list[FakeSlave]) -> tuple[Master, FakeSegment, Counting]:
    seg = FakeSegment(slaves)
    counter = Counting(seg)
    return Master(PairLink.responder_link(counter), clock=VirtualClock()), seg, counter


def _tree() -> list[FakeSlave]:
    """coupler (ports 0,1,3) -> [port 3: branch-io] ; port 1: io-a -> io-b (end)."""
    return [
        FakeSlave(_image("EK1100", 0x044C2C52), linked_ports=(0, 1, 3), port_descriptor=0xFF),
        FakeSlave(_image("EL2004", 0x07D43052), linked_ports=(0,)),  # on coupler port 3
        FakeSlave(_image("EL1004", 0x03EC3052, alias=7), linked_ports=(0, 1), read_8=False),
        FakeSlave(_image("EL1008", 0x03F03052), linked_ports=(0,), busy_polls=2),
    ]


def test_scan_finds_identities_names_and_topology() -> None:
    m, seg, _ = _master(_tree())
    progress: list[tuple[str, int, int]] = []
    slaves = m.scan(progress=lambda *a: progress.append(a))
    assert [s.name for s in slaves] == ["EK1100", "EL2004", "EL1004", "EL1008"]
    assert [s.station_address for s in slaves] == [0x1001, 0x1002, 0x1003, 0x1004]
    assert [fs.station for fs in seg.slaves] == [0x1001, 0x1002, 0x1003, 0x1004]
    assert slaves[2].identity == Identity(2, 0x03EC3052, 0x00110000, 0x03EC3052 + 7)
    assert slaves[2].alias == 7
    assert m.slave_by_alias(7) is slaves[2]
    # Topology: the branch on the coupler's port 3 comes first in frame order.
    assert slaves[0].parent is None
    assert (slaves[1].parent, slaves[1].parent_port) == (slaves[0], 3)
    assert (slaves[2].parent, slaves[2].parent_port) == (slaves[0], 1)
    assert (slaves[3].parent, slaves[3].parent_port) == (slaves[2], 1)
    assert slaves[0].children == {3: slaves[1], 1: slaves[2]}
    assert slaves[0].topology_kind == "fork"
    assert m.topology_consistent
    # Reset to INIT, SII parsed whole.
    assert all(s.al_state == AlState.INIT for s in slaves)
    for s, fs in zip(slaves, seg.slaves, strict=True):
        assert s.sii == parse_sii(bytes(fs.sii))
        assert s.sii_image == bytes(fs.sii[:len(s.sii_image)])
    assert slaves[3].sii is not None and [p.entries[0].bit_length
                                          for p in slaves[3].sii.tx_pdos] == [1]
    assert slaves[0].dc_supported
    stages = {p[0] for p in progress}
    assert {"count", "registers", "sii"} <= stages
    last_sii = [p for p in progress if p[0] == "sii"][-1]
    assert last_sii[1] == last_sii[2] > 0


def test_sii_reads_of_all_slaves_share_frames() -> None:
    n = 20
    fakes = [FakeSlave(_image(f"IO{i}", 0x100 + i)) for i in range(n)]
    m, _, counter = _master(fakes)
    m.scan()
    one, _, counter1 = _master([FakeSlave(_image("IO0", 0x100))])
    one.scan()
    # Twenty slaves take barely more frames than one (commands + read-back per step;
    # the reads chained per frame fill frames faster with twenty slaves).
    assert counter.frames <= counter1.frames * 2
    assert counter.frames < 20 * counter1.frames / 5


def test_8_byte_and_4_byte_sii_reads() -> None:
    m, seg, _ = _master([FakeSlave(_image("A", 1), read_8=True),
                         FakeSlave(_image("B", 2), read_8=False)])
    slaves = m.scan()
    assert slaves[0].sii_read_8 and not slaves[1].sii_read_8
    assert slaves[1].sii == parse_sii(bytes(seg.slaves[1].sii))


def test_expected_configuration_mismatch_names_position() -> None:
    m, _, _ = _master(_tree())
    good = [Identity(2, 0x044C2C52), Identity(2, 0x07D43052), Identity(2, 0x03EC3052),
            Identity(2, 0x03F03052)]
    m.scan(expected=good)
    bad = list(good)
    bad[2] = Identity(2, 0x0BBB0000)
    with pytest.raises(TopologyMismatchError, match="position 2: expected vendor 0x00000002 "
                       "product 0x0BBB0000, found .*product 0x03EC3052.*EL1004"):
        m.scan(expected=bad)
    with pytest.raises(TopologyMismatchError, match="position 4: expected .* found no slave"):
        m.scan(expected=[*good, Identity(2, 5)])
    with pytest.raises(TopologyMismatchError, match="position 3: expected no slave"):
        m.scan(expected=good[:3])
    with pytest.raises(TopologyMismatchError, match="alias"):
        m.scan(expected=[*good[:2], ExpectedSlave(good[2], alias=8), good[3]])


def test_states_up_and_down_with_batched_polling() -> None:
    m, seg, counter = _master([FakeSlave(_image(f"IO{i}", i)) for i in range(5)])
    m.scan()
    before = counter.frames
    m.set_state("SAFEOP")
    assert all(fs.al_status == AlState.SAFEOP for fs in seg.slaves)
    assert all(s.al_state == AlState.SAFEOP for s in m.slaves)
    # ack check, status read, 2 steps x (request + poll): a handful of frames for 5 slaves.
    assert counter.frames - before <= 8
    m.set_state(AlState.OP)
    m.set_state("INIT")
    assert all(fs.al_status == AlState.INIT for fs in seg.slaves)
    m.set_state("BOOT", [1])
    assert seg.slaves[1].al_status == AlState.BOOT


def test_refused_transition_reports_the_al_code() -> None:
    fakes = [FakeSlave(_image("A", 1)), FakeSlave(_image("B", 2), refuse={4: 0x001D})]
    m, _, _ = _master(fakes)
    m.scan()
    with pytest.raises(AlStatusError, match=r"slave 1 \(0x1002, B\) refused SAFEOP, stays in "
                       r"PREOP\+ERR") as err:
        m.set_state("SAFEOP")
    assert err.value.code == 0x001D
    assert err.value.code_name == "Invalid output configuration"
    assert m.slaves[1].al_error and m.slaves[1].al_status_code == 0x001D
    assert m.slaves[1].al_status_text == "0x001D Invalid output configuration"
    # Acknowledge clears the flag; the slave stays in PREOP.
    assert m.acknowledge_errors() == [m.slaves[1]]
    m.read_states()
    assert m.slaves[1].al_state_name == "PREOP"


def test_stuck_slave_times_out_naming_it() -> None:
    fakes = [FakeSlave(_image("A", 1)), FakeSlave(_image("B", 2), stuck={2})]
    m, _, _ = _master(fakes)
    m.scan()
    with pytest.raises(StateTimeoutError, match=r"1 slave did not reach PREOP within 0.05 s: "
                       r"slave 1 \(0x1002, B\) in INIT"):
        m.set_state("PREOP", timeout=0.05)


def test_register_access_by_slave_and_position() -> None:
    m, seg, _ = _master([FakeSlave(_image("A", 1)), FakeSlave(_image("B", 2))])
    # Before a scan positions use auto-increment addressing.
    m.write(1, 0x0F80, b"\xAA\xBB")
    assert bytes(seg.slaves[1].mem[0x0F80:0x0F82]) == b"\xAA\xBB"
    assert m.read(1, 0x0F80, 2) == b"\xAA\xBB"
    m.scan()
    assert m.read(m.slaves[1], reg.STATION_ADDRESS, 2) == struct.pack("<H", 0x1002)
    results = m.read_many(reg.AL_STATUS, 2)
    assert [r.ok for r in results] == [True, True]
    data, wkc = m.broadcast_read(reg.TYPE, 1)
    assert wkc == 2 and data == b"\x11"


def test_error_counters_report() -> None:
    m, seg, counter = _master([FakeSlave(_image(f"IO{i}", i)) for i in range(3)])
    m.scan()
    seg.slaves[2].mem[reg.RX_ERROR_COUNTER + 2] = 5  # port 1 invalid frames
    seg.slaves[2].mem[reg.LOST_LINK_COUNTER + 1] = 1
    before = counter.frames
    report = m.error_counters()
    assert counter.frames - before == 1
    assert report.slaves[2].ports[1].invalid_frames == 5
    assert report.slaves[2].ports[1].lost_links == 1
    assert [s.position for s in report.with_errors] == [2]
    assert "5/0/0/1" in report.format()
    m.clear_error_counters()
    assert m.error_counters().total == 0


def test_sii_write_changes_only_differing_words_and_reloads() -> None:
    m, seg, _ = _master([FakeSlave(_image("A", 1, alias=3))])
    m.scan()
    new = bytearray(_image("A", 1, alias=9))
    report = m.sii_write(0, bytes(new))
    assert report.written == [4, 7]  # alias word and checksum word
    assert bytes(seg.slaves[0].sii[:len(new)]) == bytes(new)
    assert m.read(0, reg.STATION_ALIAS, 2) == struct.pack("<H", 9)
    assert m.sii_read(0) == bytes(new[:len(m.sii_read(0))])


def test_sii_read_errors_are_typed() -> None:
    m, seg, _ = _master([FakeSlave(_image("A", 1))])
    m.scan()
    seg.slaves[0].busy_polls = 10**9
    with pytest.raises(SiiError, match="stays busy"):
        m.sii_read(0)


def test_staggered_busy_slaves_are_read_whatever_the_frame_count() -> None:
    """The busy limit counts per slave: slaves whose EEPROMs run staggered
    (one busy in every frame) are read however long the whole read takes."""
    from pyethercat.master.scan import SiiAccess, read_sii_batch

    slaves = [FakeSlave(_image("A", 1), busy_polls=3), FakeSlave(_image("B", 2), busy_polls=5)]
    m, _, _ = _master(slaves)
    m.scan()
    images = read_sii_batch(m.scheduler, [SiiAccess.of(s) for s in m.slaves], max_polls=5)
    assert [parse_sii(i).product_code for i in images] == [1, 2]


def test_topology_from_line_and_fallback() -> None:
    line = []
    for n in range(3):
        s = Slave(n, 0x1001 + n)
        s.ports[0].communication, s.ports[0].loop_closed = True, False
        if n < 2:
            s.ports[1].communication, s.ports[1].loop_closed = True, False
        line.append(s)
    assert build_topology(line)
    assert [s.parent_port for s in line] == [None, 1, 1]
    # Ports say "end" too early: the rest hangs on the previous slave.
    line[0].ports[1].communication = False
    assert not build_topology(line)
    assert line[1].parent is line[0] and line[2].parent is line[1]


def test_scan_frames_are_all_standard_datagrams() -> None:
    sent: list[bytes] = []
    seg = FakeSegment([FakeSlave(_image("A", 1))])

    def rec(frame: bytes) -> object:
        sent.append(frame)
        return seg.process(frame)

    m = Master(PairLink.responder_link(rec), clock=VirtualClock())
    m.scan()
    cmds = {Command(d.command) for raw in sent for d in decode_frame(raw).datagrams}
    assert cmds <= {Command.BRD, Command.BWR, Command.APWR, Command.FPRD, Command.FPWR}
    first = decode_frame(sent[0]).datagrams[0]
    assert first == Datagram(Command.BRD, first.index, 0, b"\0\0")
