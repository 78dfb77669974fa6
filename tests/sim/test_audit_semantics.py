"""Audit of issue 3 semantics against the facts sheet (sections 2, 3, 4, 5, 12).

Each test pins one rule that the earlier core tests left open or asserted too
weakly: RW working counters on read-only registers, ARMW/FRMW edges, LRW with
read-only and write-only slaves, bit-granular FMMUs across byte boundaries
and overlapping slaves in ring order, three-buffer and mailbox gating, AL
transitions of facts 4.3, SII edge cases, loop control, forwarding order in
trees, power cycling, CRC counters and seeded drops.
"""

from __future__ import annotations

import struct

import pytest
from simhelp import (
    IN_SM,
    MBX_IN,
    MBX_OUT,
    OUT_SM,
    address_all,
    fmmu_bytes,
    fprd,
    fpwr,
    line,
    one,
    sm_bytes,
    spec,
    u16,
)

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame

READ, WRITE = int(R.FmmuType.READ), int(R.FmmuType.WRITE)
ST = 0x1000


def seg_n(n: int, profile: str = "ET1100") -> Segment:
    seg = line(n, profile=profile)
    address_all(seg)
    return seg


# --- commands and working counters (facts 2.2) ------------------------------------------------


def test_fprw_aprw_on_read_only_register_count_only_the_read() -> None:
    seg = seg_n(2)
    d = one(seg, Datagram.device(Command.FPRW, 0x1001, R.TYPE, b"\x99"))
    assert d.wkc == 1 and d.data == b"\x11"
    assert seg.slaves[1].read(R.TYPE, 1) == b"\x11"
    d = one(seg, Datagram.positional(Command.APRW, 0, R.TYPE, b"\x99"))
    assert d.wkc == 1 and d.data == b"\x11"


def test_fprw_write_counts_two_when_nothing_is_readable() -> None:
    # 0x0040 (ESC reset) is write-only on real chips; here it stores the byte:
    # a read-write on a writable register gives 1 + 2
    seg = seg_n(1)
    d = one(seg, Datagram.device(Command.FPRW, ST, R.USER_RAM, b"\x01\x02"))
    assert d.wkc == 3 and d.data == b"\x00\x00"
    assert seg.slaves[0].read(R.USER_RAM, 2) == b"\x01\x02"


def test_brw_mixed_read_only_and_writable_per_slave() -> None:
    seg = seg_n(3)
    # BRW on the read-only type register: +1 per slave, nothing written
    d = one(seg, Datagram.device(Command.BRW, 0, R.TYPE, b"\x00"))
    assert d.wkc == 3 and d.data == b"\x11" and d.adp == 3
    assert all(s.read(R.TYPE, 1) == b"\x11" for s in seg.slaves)


def test_brw_frame_or_and_memory_gets_data_as_received_in_ring_order() -> None:
    seg = seg_n(3)
    for i, s in enumerate(seg.slaves):
        s.write(R.USER_RAM, bytes([1 << i]))
    d = one(seg, Datagram.device(Command.BRW, 0, R.USER_RAM, b"\x80"))
    assert d.wkc == 9 and d.data == b"\x87"
    assert [s.read(R.USER_RAM, 1) for s in seg.slaves] == [b"\x80", b"\x81", b"\x83"]


def test_brd_counts_only_slaves_that_read_and_ors_multibyte() -> None:
    seg = seg_n(3)
    seg.slaves[0].write(R.USER_RAM, b"\x01\x00\x10")
    seg.slaves[1].write(R.USER_RAM, b"\x00\x02\x20")
    seg.slaves[2].write(R.USER_RAM, b"\x04\x00\x40")
    # master data is ORed too (masters should send zeros)
    d = one(seg, Datagram.device(Command.BRD, 0, R.USER_RAM, b"\x00\x80\x00"))
    assert d.data == b"\x05\x82\x70" and d.wkc == 3 and d.adp == 3


def test_armw_reader_missing_every_slave_writes() -> None:
    seg = seg_n(3)
    d = one(seg, Datagram.positional(Command.ARMW, 7, R.USER_RAM, b"\x5a"))
    assert d.wkc == 3 and d.data == b"\x5a"
    assert all(s.read(R.USER_RAM, 1) == b"\x5a" for s in seg.slaves)
    assert d.adp == (-7 + 3) & 0xFFFF


def test_frmw_on_system_time_from_reference_distributes_its_time() -> None:
    seg = Segment(VirtualClock(5_000_000))
    for i in range(3):
        seg.add_slave(spec(f"s{i}", "ET1100"))
    address_all(seg)
    d = one(seg, Datagram.device(Command.FRMW, 0x1001, R.DC_SYSTEM_TIME, 8))
    # the reader counts 1, the two writers 1 each
    assert d.wkc == 3 and d.adp == 0x1001
    ref = struct.unpack("<q", d.data)[0]
    assert ref > 0
    # slave 0 (before the reader) got the master's zeros: its difference is its whole
    # system time (positive: bit 31); slave 2 got the reference's time: a small difference
    own0 = struct.unpack("<q", fprd(seg, 0x1000, R.DC_SYSTEM_TIME, 8).data)[0]
    diff0 = struct.unpack("<I", fprd(seg, 0x1000, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0]
    diff2 = struct.unpack("<I", fprd(seg, 0x1002, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0]
    assert diff0 & 0x80000000 and 0 < own0 - (diff0 & 0x7FFFFFFF) < 100_000
    assert (diff0 & 0x7FFFFFFF) > 10 * (diff2 & 0x7FFFFFFF)
    assert diff2 & 0x7FFFFFFF < 5_000


def test_lrw_read_only_and_write_only_slaves() -> None:
    seg = seg_n(3)
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0, 1, 0, 7, 0x1180, 0, READ))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(1, 1, 0, 7, 0x1100, 0, WRITE))
    seg.slaves[0].write(0x1180, b"\x42")
    # LRW: reader +1, writer +2; LRD: reader only; LWR: writer only (+1)
    d = one(seg, Datagram.logical(Command.LRW, 0, b"\x00\x77"))
    assert d.wkc == 3 and d.data == b"\x42\x77"
    assert seg.slaves[1].read(0x1100, 1) == b"\x77"
    assert one(seg, Datagram.logical(Command.LRD, 0, 2)).wkc == 1
    d = one(seg, Datagram.logical(Command.LWR, 0, b"\x11\x22"))
    assert d.wkc == 1 and d.data == b"\x11\x22"  # LWR leaves the frame unchanged
    assert seg.slaves[1].read(0x1100, 1) == b"\x22"
    # a datagram that only touches the writer's byte: LRW counts 2
    assert one(seg, Datagram.logical(Command.LRW, 1, b"\x33")).wkc == 2
    # ADP/ADO (the logical address) are not changed by logical commands
    d = one(seg, Datagram.logical(Command.LRW, 0x00010000, b"\x00"))
    assert d.wkc == 0 and d.address == 0x00010000


def test_lrw_two_fmmus_of_one_slave_count_once_per_direction() -> None:
    seg = seg_n(1)
    fpwr(seg, ST, R.fmmu_address(0), fmmu_bytes(0, 1, 0, 7, 0x1100, 0, WRITE))
    fpwr(seg, ST, R.fmmu_address(1), fmmu_bytes(1, 1, 0, 7, 0x1101, 0, WRITE))
    fpwr(seg, ST, R.fmmu_address(2), fmmu_bytes(2, 1, 0, 7, 0x1180, 0, READ))
    fpwr(seg, ST, R.fmmu_address(3), fmmu_bytes(3, 1, 0, 7, 0x1181, 0, READ))
    assert one(seg, Datagram.logical(Command.LRW, 0, 4)).wkc == 3
    assert one(seg, Datagram.logical(Command.LWR, 0, 4)).wkc == 1
    assert one(seg, Datagram.logical(Command.LRD, 0, 4)).wkc == 1


# --- FMMU bit granularity ----------------------------------------------------------------------


def test_bit_fmmu_with_physical_start_bit_across_byte_boundaries() -> None:
    seg = seg_n(1)
    # 12 bits: logical 0x40 bit 5 .. 0x42 bit 0 -> physical 0x1180 bit 6 .. 0x1182 bit 1
    fpwr(seg, ST, R.fmmu_address(0), fmmu_bytes(0x40, 3, 5, 0, 0x1180, 6, READ))
    seg.slaves[0].write(0x1180, bytes([0b1100_0000, 0b1010_1010, 0b0000_0011]))
    d = one(seg, Datagram.logical(Command.LRD, 0x40, b"\x00\x00\x00"))
    # physical bits 6..17: 1,1, 0,1,0,1,0,1,0,1, 1,1
    bits = [1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 1, 1]
    value = sum(b << (5 + k) for k, b in enumerate(bits))
    assert d.data == value.to_bytes(3, "little")
    assert d.wkc == 1
    # unmapped logical bits keep the master's value
    d = one(seg, Datagram.logical(Command.LRD, 0x40, b"\x1f\x00\xfe"))
    assert d.data == (value | 0x1F | (0xFE << 16)).to_bytes(3, "little")


def test_bit_fmmu_write_across_bytes_leaves_neighbours() -> None:
    seg = seg_n(1)
    fpwr(seg, ST, R.fmmu_address(0), fmmu_bytes(0x40, 2, 6, 1, 0x1100, 7, WRITE))
    seg.slaves[0].write(0x1100, b"\x55\x55")
    # logical bits 0x40.6, 0x40.7, 0x41.0, 0x41.1 -> physical 0x1100.7, 0x1101.0..2
    one(seg, Datagram.logical(Command.LWR, 0x40, bytes([0b1100_0000, 0b0000_0011])))
    assert seg.slaves[0].read(0x1100, 2) == bytes([0x55 | 0x80, 0x55 | 0x07])
    one(seg, Datagram.logical(Command.LWR, 0x40, bytes([0, 0])))
    assert seg.slaves[0].read(0x1100, 2) == bytes([0x55, 0x50])


def test_bitwise_cross_traffic_on_one_logical_byte_in_ring_order() -> None:
    seg = seg_n(3)
    # slave 0 reads 2 input bits into logical 0x50 bits 0-1; slave 1 writes bits 0-1
    # of the same byte to its outputs (it sees slave 0's inputs); slave 2 reads bits
    # 2-3 of the same byte (its own inputs), which the others leave alone.
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x50, 1, 0, 1, 0x1180, 0, READ))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(0x50, 1, 0, 1, 0x1100, 4, WRITE))
    fpwr(seg, 0x1002, R.fmmu_address(0), fmmu_bytes(0x50, 1, 2, 3, 0x1180, 0, READ))
    seg.slaves[0].write(0x1180, b"\x02")
    seg.slaves[2].write(0x1180, b"\x03")
    d = one(seg, Datagram.logical(Command.LRW, 0x50, b"\xf0"))
    assert d.data == bytes([0xF0 | 0x02 | (0x03 << 2)])
    assert seg.slaves[1].read(0x1100, 1) == bytes([0x02 << 4])
    assert d.wkc == 1 + 2 + 1


def test_writer_after_bit_reader_sees_updated_bits_only() -> None:
    seg = seg_n(2)
    # slave 0 reads its bit into logical 0x60 bit 7; slave 1 writes the whole byte
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x60, 1, 7, 7, 0x1180, 0, READ))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(0x60, 1, 0, 7, 0x1100, 0, WRITE))
    seg.slaves[0].write(0x1180, b"\x01")
    d = one(seg, Datagram.logical(Command.LRW, 0x60, b"\x05"))
    assert d.data == b"\x85"
    assert seg.slaves[1].read(0x1100, 1) == b"\x85"


# --- sync managers ------------------------------------------------------------------------------


def _pd_segment() -> Segment:
    seg = Segment()
    seg.add_slave(spec("io", out_bits=16, in_bits=16))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(OUT_SM, 2, R.SM_CONTROL_OUTPUTS))
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 2, R.SM_CONTROL_INPUTS))
    return seg


def test_input_buffer_partial_pdi_write_is_not_visible() -> None:
    seg = _pd_segment()
    pdi = seg.slaves[0].esc.pdi
    pdi.set_inputs(b"\x11\x22")
    assert fprd(seg, ST, IN_SM, 2).data == b"\x11\x22"
    pdi.write(IN_SM, b"\x33")  # the firmware began a new buffer
    assert fprd(seg, ST, IN_SM, 2).data == b"\x11\x22"  # newest complete buffer
    pdi.write(IN_SM + 1, b"\x44")  # last byte: the buffer is published
    assert fprd(seg, ST, IN_SM, 2).data == b"\x33\x44"


def test_input_buffer_status_and_read_event() -> None:
    seg = _pd_segment()
    status = fprd(seg, ST, R.sm_address(3) + R.SM_STATUS, 1).data[0]
    assert (status & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT == 3
    seg.slaves[0].esc.pdi.set_inputs(b"\x01\x02")
    status = fprd(seg, ST, R.sm_address(3) + R.SM_STATUS, 1).data[0]
    assert status & R.SM_STATUS_WRITE_EVENT
    assert (status & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT == 0
    fprd(seg, ST, IN_SM, 2)
    status = fprd(seg, ST, R.sm_address(3) + R.SM_STATUS, 1).data[0]
    assert status & R.SM_STATUS_READ_EVENT


def test_mailbox_read_of_empty_and_write_to_full_through_logical_and_broadcast() -> None:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("m", mailbox=True))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    assert one(seg, Datagram.device(Command.BRD, 0, MBX_IN, 128)).wkc == 0
    assert one(seg, Datagram.positional(Command.APRD, 0, MBX_IN, 128)).wkc == 0
    # a read of the send mailbox that is refused leaves the frame as the master sent it
    assert one(seg, Datagram.device(Command.FPRD, ST, MBX_IN, b"\xab" * 4)).data == b"\xab" * 4


def test_mailbox_partial_read_does_not_empty() -> None:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("m", mailbox=True))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    assert seg.slaves[0].esc.pdi.post_mailbox(b"hello")
    assert fprd(seg, ST, MBX_IN, 64).wkc == 1
    status = fprd(seg, ST, R.sm_address(1) + R.SM_STATUS, 1).data[0]
    assert status & R.SM_STATUS_MAILBOX_FULL
    assert fprd(seg, ST, MBX_IN + 64, 64).wkc == 1  # includes the last byte
    status = fprd(seg, ST, R.sm_address(1) + R.SM_STATUS, 1).data[0]
    assert not status & R.SM_STATUS_MAILBOX_FULL
    assert fprd(seg, ST, MBX_IN, 128).wkc == 0


# --- AL state machine (facts 4.2, 4.3) ------------------------------------------------------------


def _mbx_al_segment(**kw: object) -> Segment:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("m", mailbox=True, **kw))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    return seg


def request(seg: Segment, value: int) -> tuple[int, int]:
    fpwr(seg, ST, R.AL_CONTROL, struct.pack("<H", value))
    return u16(fprd(seg, ST, R.AL_STATUS, 2)), u16(fprd(seg, ST, R.AL_STATUS_CODE, 2))


ACK = int(R.AL_ERROR_FLAG)


def test_boot_transitions() -> None:
    seg = _mbx_al_segment(boot=True)
    assert request(seg, AlState.BOOT) == (AlState.BOOT, 0)
    for target in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        status, code = request(seg, target | ACK)
        assert code == AlStatusCode.INVALID_STATE_CHANGE, target
        assert status & R.AL_ERROR_FLAG and status & R.AL_STATE_MASK in (AlState.BOOT, AlState.PREOP)
    assert request(seg, AlState.INIT | ACK) == (AlState.INIT, 0)
    assert request(seg, AlState.PREOP) == (AlState.PREOP, 0)
    # PRE-OP -> BOOT is refused, the slave stays in PRE-OP
    assert request(seg, AlState.BOOT) == (AlState.PREOP | ACK, AlStatusCode.INVALID_STATE_CHANGE)


def test_boot_with_bad_bootstrap_mailbox_is_0x0015() -> None:
    seg = _mbx_al_segment(boot=True)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 64, R.SM_CONTROL_MAILBOX_OUT))
    assert request(seg, AlState.BOOT) == (AlState.INIT | ACK, AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT)


@pytest.mark.parametrize("code", [0x00, 0x05, 0x06, 0x07, 0x09, 0x0F])
def test_unknown_state_codes_0x0012_state_stays(code: int) -> None:
    seg = _mbx_al_segment()
    assert request(seg, AlState.PREOP) == (AlState.PREOP, 0)
    assert request(seg, code) == (AlState.PREOP | ACK, AlStatusCode.UNKNOWN_STATE)


def test_unknown_state_from_op_falls_back_to_safeop() -> None:
    seg = Segment()
    seg.add_slave(spec("di", in_bits=8))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    for s in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        assert request(seg, s) == (s, 0)
    assert request(seg, 0x0E) == (AlState.SAFEOP | ACK, AlStatusCode.UNKNOWN_STATE)


@pytest.mark.parametrize("code", [AlState.INIT, AlState.PREOP, 0x05])
def test_al_status_poked_to_no_state_is_taken_as_init(code: int) -> None:
    # A raw write of AL status (as the PDI could) naming no state: the next
    # request starts from INIT instead of failing inside the state machine.
    seg = _mbx_al_segment()
    seg.slaves[0].write(R.AL_STATUS, b"\x05\x00")
    expected = AlState.PREOP if code == AlState.PREOP else AlState.INIT
    assert request(seg, code)[0] & ~ACK == expected


def test_error_not_acknowledged_ignores_requests_then_ack_with_current_state() -> None:
    seg = _mbx_al_segment()
    assert request(seg, AlState.OP) == (AlState.INIT | ACK, AlStatusCode.INVALID_STATE_CHANGE)
    assert request(seg, AlState.PREOP) == (AlState.INIT | ACK, AlStatusCode.INVALID_STATE_CHANGE)
    # IgH acknowledges by writing back the AL status it read (state + 0x10)
    assert request(seg, AlState.INIT | ACK) == (AlState.INIT, 0)
    assert request(seg, AlState.PREOP) == (AlState.PREOP, 0)


def test_downward_transitions_and_same_state() -> None:
    seg = Segment()
    seg.add_slave(spec("di", in_bits=8, mailbox=True))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    for s in (AlState.PREOP, AlState.PREOP, AlState.SAFEOP, AlState.OP, AlState.OP):
        assert request(seg, s) == (s, 0)
    assert request(seg, AlState.SAFEOP) == (AlState.SAFEOP, 0)
    assert request(seg, AlState.OP) == (AlState.OP, 0)
    assert request(seg, AlState.INIT) == (AlState.INIT, 0)


def test_safeop_or_op_to_boot_is_refused_to_safeop() -> None:
    seg = Segment()
    seg.add_slave(spec("di", in_bits=8, mailbox=True, boot=True))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    for s in (AlState.PREOP, AlState.SAFEOP, AlState.OP):
        assert request(seg, s) == (s, 0)
    assert request(seg, AlState.BOOT) == (AlState.SAFEOP | ACK, AlStatusCode.INVALID_STATE_CHANGE)


# --- SII interface (facts 3.10) -----------------------------------------------------------------


def sii_cmd(seg: Segment, command: int, word: int) -> int:
    """Start an SII command and read the status once the EEPROM is done with it
    (7 ms of segment time cover any profile's read, write and write cycle)."""
    fpwr(seg, ST, R.SII_CONTROL, struct.pack("<HI", command, word))
    seg.clock.advance(7_000_000)  # type: ignore[attr-defined]
    return u16(fprd(seg, ST, R.SII_CONTROL, 2))


def test_sii_read_straddling_the_end_pads_with_ff() -> None:
    seg = seg_n(1)
    image = bytes(seg.slaves[0].esc.sii)
    last_word = len(image) // 2 - 2
    sii_cmd(seg, R.SiiControl.CMD_READ, last_word)
    assert fprd(seg, ST, R.SII_DATA, 8).data == image[-4:] + b"\xff" * 4


def test_sii_write_without_enable_changes_nothing() -> None:
    seg = seg_n(1)
    before = bytes(seg.slaves[0].esc.sii)
    fpwr(seg, ST, R.SII_DATA, b"\xee\xee")
    status = sii_cmd(seg, R.SiiControl.CMD_WRITE, 0x10)
    assert status & R.SiiControl.WRITE_ENABLE_ERROR
    assert bytes(seg.slaves[0].esc.sii) == before


# --- ports, loop control, DL status (facts 3.4, 3.5, 12) ------------------------------------------


def test_forwarding_order_with_branches_on_ports_3_1_2_and_nested() -> None:
    seg = Segment()
    seg.add_slave(spec("c", "IPCORE"))                          # 0: 4 ports
    seg.add_slave(spec("p1", "IPCORE"), parent=0, port=1)       # 1
    seg.add_slave(spec("p2", "IPCORE"), parent=0, port=2)       # 2
    seg.add_slave(spec("p3", "IPCORE"), parent=0, port=3)       # 3
    seg.add_slave(spec("p3-3", "ET1200"), parent=3, port=3)     # 4 nested branch on p3's port 3
    seg.add_slave(spec("p3-1", "ET1200"), parent=3, port=1)     # 5
    seg.add_slave(spec("p2-1", "ET1200"), parent=2, port=1)     # 6
    seg.add_slave(spec("p1-2", "ET1200"), parent=1, port=2)     # 7
    seg.add_slave(spec("p1-1", "ET1200"), parent=1, port=1)     # 8
    assert seg.route.passes.tolist() == [0, 3, 4, 5, 1, 8, 7, 2, 6]
    # positional addressing follows that order
    for pos, s in enumerate(seg.route.passes.tolist()):
        seg.slaves[s].write(R.USER_RAM, bytes([s]))
        assert one(seg, Datagram.positional(Command.APRD, pos, R.USER_RAM, 1)).data == bytes([s])
    d = one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1))
    assert d.wkc == 9 and d.adp == 9
    # the coupler: all four ports link + communication, loops open
    dl = seg.slaves[0].u16(R.DL_STATUS)
    for p in range(4):
        assert dl & R.dl_status_link(p) and dl & R.dl_status_com(p) and not dl & R.dl_status_loop(p)


def test_branch_on_port_2_of_ek1100_profile_and_break_inside_it() -> None:
    seg = Segment()
    seg.add_slave(spec("ek", "EK1100"))                       # ports 0 MII, 1 E-Bus, 2 MII
    seg.add_slave(spec("a", "ET1200"))                        # on port 1
    seg.add_slave(spec("b", "ET1200"), parent=0, port=2)      # on port 2
    seg.add_slave(spec("c", "ET1200"))                        # behind b
    assert seg.route.passes.tolist() == [0, 1, 2, 3]
    seg.break_link(2, 1)
    assert seg.route.passes.tolist() == [0, 1, 2]
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 3
    seg.restore_link(3, 0)  # restoring from the other end of the cable works too
    assert seg.route.passes.tolist() == [0, 1, 2, 3]


def test_dl_status_two_bit_fields_for_each_loop_setting() -> None:
    seg = seg_n(2, profile="ET1200")
    s0 = seg.slaves[0]
    # auto: linked port 1 open with communication (2), port 0 likewise
    dl = s0.u16(R.DL_STATUS)
    assert (dl >> 8) & 3 == 2 and (dl >> 10) & 3 == 2
    # always closed on a linked port: loop closed + communication (3), the frame turns there
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, bytes([R.LoopControl.CLOSED << 2])))
    dl = s0.u16(R.DL_STATUS)
    assert (dl >> 10) & 3 == 3
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 1
    # always open on a linked port: open + communication (2)
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, bytes([R.LoopControl.OPEN << 2])))
    assert (s0.u16(R.DL_STATUS) >> 10) & 3 == 2
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 2
    # last slave, auto, no link on port 1: loop closed, no communication (1)
    assert (seg.slaves[1].u16(R.DL_STATUS) >> 10) & 3 == 1
    # back to auto, then a link break: PL bit goes, loop closes
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, b"\x00"))
    seg.break_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 1
    dl = s0.u16(R.DL_STATUS)
    assert not dl & R.dl_status_link(1) and (dl >> 10) & 3 == 1


def test_auto_close_written_while_link_down_does_not_reopen_later() -> None:
    seg = seg_n(2, profile="ET1200")
    auto_close = bytes([R.LoopControl.AUTO_CLOSE << 2])
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, auto_close))
    seg.break_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    # writing 1 while the link is still down re-opens nothing
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, auto_close))
    seg.restore_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    # only writing 1 after the link came back opens the port
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, auto_close))
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 2


def test_lost_link_counted_on_both_sides_of_the_cable() -> None:
    seg = seg_n(3, profile="ET1200")
    seg.break_link(1, 1)
    one(seg, Datagram.device(Command.BRD, 0, 0, 1))
    assert seg.slaves[1].read(R.LOST_LINK_COUNTER + 1, 1) == b"\x01"
    assert seg.slaves[2].read(R.LOST_LINK_COUNTER, 1) == b"\x01"
    assert seg.slaves[0].read(R.LOST_LINK_COUNTER, 4) == bytes(4)


def test_circulating_bit_set_when_passing_a_closed_port0_once() -> None:
    # slave 1's port 0 is forced closed: the frame coming from slave 0 still reaches
    # slave 1's processing unit; on the way back port 0 is closed, so it passes the
    # processing unit a second time and is destroyed (facts 2.3)
    seg = seg_n(2, profile="ET1200")
    one(seg, Datagram.positional(Command.APWR, 1, R.DL_CONTROL_LOOP, bytes([R.LoopControl.CLOSED])))
    assert seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None


# --- faults --------------------------------------------------------------------------------------


def test_power_cycle_restores_alias_and_clears_memory() -> None:
    seg = Segment()
    seg.add_slave(spec("a", "ET1200"))
    seg.add_slave(spec("b", "ET1200", alias_sii=0x0321))
    address_all(seg)
    seg.slaves[1].write(R.USER_RAM, b"\x77")
    fpwr(seg, 0x1001, R.STATION_ALIAS, b"\x99\x00")
    seg.power_off(1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    assert seg.slaves[0].u16(R.DL_STATUS) & R.dl_status_loop(1)
    seg.power_on(1)
    s = seg.slaves[1]
    assert s.u16(R.STATION_ADDRESS) == 0 and s.u16(R.STATION_ALIAS) == 0x0321
    assert s.read(R.USER_RAM, 1) == b"\x00"
    assert s.u16(R.AL_STATUS) == AlState.INIT
    # FPRD to its old address goes nowhere; position 1 still answers
    assert fprd(seg, 0x1001, R.TYPE, 1).wkc == 0
    assert one(seg, Datagram.positional(Command.APRD, 1, R.TYPE, 1)).wkc == 1


def test_crc_error_on_the_return_path_counts_upstream_only() -> None:
    seg = seg_n(3, profile="ET1200")
    # the frame comes back into slave 0 on port 1: error there, forwarded on the way home
    seg.corrupt_frames(0, 1, count=1)
    assert seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
    c = [s.read(R.RX_ERROR_COUNTER, 12) for s in seg.slaves]
    assert c[0][2] == 1  # invalid frame counter port 1 of slave 0
    assert all(x == 0 for x in c[1] + c[2])
    assert sum(c[0]) == 1


def test_seeded_drops_are_deterministic() -> None:
    def pattern(seed: int) -> list[bool]:
        seg = line(2, profile="ET1200")
        seg.drop_probability(0.3, seed=seed)
        return [seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
                for _ in range(64)]

    a, b, c = pattern(7), pattern(7), pattern(8)
    assert a == b
    assert a != c
    assert 5 < sum(a) < 40


def test_seeded_drops_from_the_topology_file_are_deterministic() -> None:
    body = "[[slave]]\nname = 'a'\ndevice = 'builtin:di8'\n"

    def pattern(segment: str) -> list[bool]:
        seg = parse_topology(segment + body).build()
        return [seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
                for _ in range(64)]

    def direct(p: float, seed: int) -> list[bool]:
        seg = parse_topology(body).build()
        seg.drop_probability(p, seed=seed)
        return [seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
                for _ in range(64)]

    a = pattern("[segment]\ndrop_probability = 0.3\nseed = 11\n")
    # The file's probability and seed are applied: the same losses as set directly,
    # some frames lost and most not; without the key nothing is lost.
    assert a == pattern("[segment]\ndrop_probability = 0.3\nseed = 11\n") == direct(0.3, 11)
    assert 5 < sum(a) < 40
    assert a != pattern("[segment]\ndrop_probability = 0.3\nseed = 12\n")
    assert not any(pattern(""))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'coupler'\nport = 1", "slave 'x'"),
        ("[[slave]]\nname = 'x'\ndevice = 'builtin:di8'\nparent = 'in'\nport = 3", "slave 'x'"),
        ("[[fault]]\nkind = 'break_link'\nslave = 'nope'\nport = 1", "nope"),
        ("[[fault]]\nkind = 'corrupt'\nslave = 'in'\nport = 3", "slave 'in' has no port 3"),
        ("[[fault]]\nkind = 'break_link'\nslave = 'coupler'\nport = 2", "port 2 of slave 'coupler' has no cable"),
        ("[[fault]]\nkind = 'break_link'\nslave = 'out'\nport = 1", "port 1 of slave 'out' has no cable"),
        ("[[wire]]\nfrom = 'out:9'\nto = 'in:0'", "wire #1"),
    ],
)
def test_topology_errors_start_with_the_file_name(extra: str, message: str) -> None:
    text = ("[[slave]]\nname = 'coupler'\ndevice = 'builtin:coupler'\n"
            "[[slave]]\nname = 'in'\ndevice = 'builtin:di8'\n"
            "[[slave]]\nname = 'out'\ndevice = 'builtin:do8'\n")
    with pytest.raises(ConfigError, match=message) as info:
        parse_topology(text + extra, source="f.toml")
    assert str(info.value).startswith("f.toml"), str(info.value)


# --- topology file contract (design.md "Topology file", docs/simulator.md) -------------------------


def _route_names(seg: Segment) -> list[str]:
    return [seg.slaves[i].name for i in seg.route.passes.tolist()]


def test_demo_topology_processing_order_and_wiring() -> None:
    from pathlib import Path

    from pyethercat.sim.topology import load_topology

    demo = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
    seg = load_topology(demo).build(clock=VirtualClock())
    # the branch on the coupler's port 3 is processed before the line on port 1
    assert _route_names(seg) == ["coupler", "branch-do8", "di8", "do8", "di2", "ai2"]
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 6


def test_every_documented_slave_key_takes_effect_on_the_wire() -> None:
    text = """
[segment]
drift_ppm = 0.0     # slaves without drift_ppm: exact oscillators
[[slave]]
name = "c"
device = "builtin:coupler"
forwarding_delay_ns = 700
[[slave]]
name = "a"
device = "builtin:di8"
cable_delay_ns = 40
forwarding_delay_ns = 150
alias = 0x0BEE
serial = 4711
profile = "IPCORE"
drift_ppm = 50.0
inputs = "5a"
[[slave]]
name = "b"
device = "builtin:do8"
"""
    clock = VirtualClock(0)
    seg = parse_topology(text).build(clock=clock)
    seg.advance_clock = False
    assert _route_names(seg) == ["c", "a", "b"]
    # profile: the IP core's type register
    assert one(seg, Datagram.positional(Command.APRD, 1, R.TYPE, 1)).data == b"\x04"
    # alias in 0x0012 and serial number in SII words 0x0E/0x0F
    assert one(seg, Datagram.positional(Command.APRD, 1, R.STATION_ALIAS, 2)).data == b"\xee\x0b"
    image = bytes(seg.slaves[1].esc.sii)
    assert struct.unpack_from("<I", image, 2 * 0x0E)[0] == 4711
    # forwarding and cable delays: receive-time latch at every port
    one(seg, Datagram.device(Command.BWR, 0, R.DC_RECEIVE_TIME_PORT0, bytes(4)))
    t = [struct.unpack("<II", one(seg, Datagram.positional(
        Command.APRD, i, R.DC_RECEIVE_TIME_PORT0, 8)).data) for i in range(3)]
    # coupler port 1 sees the frame come back from 'a' and 'b':
    # 700 (c) + 40 (cable c-a) + 150 (a) + 5 (a-b) + b + 5 + 150 (a) + 40
    b_delay = seg.slaves[2].spec.profile.default_forwarding_delay_ns
    assert t[0][1] - t[0][0] == 700 + 40 + 150 + 5 + b_delay + 5 + 150 + 40
    assert t[1][1] - t[1][0] == 150 + 5 + b_delay + 5
    # drift: 'a' runs 50 ppm fast against the coupler
    clock.advance(1_000_000_000)
    st = [struct.unpack("<q", one(seg, Datagram.positional(Command.APRD, i, R.DC_SYSTEM_TIME, 8)).data)[0]
          for i in range(2)]
    assert 49_000 < st[1] - st[0] < 51_000
    # inputs: in the input SM once the master enables it
    sm = seg.slaves[1].esc.sii_info.sync_managers[seg.slaves[1].esc.input_sm]  # type: ignore[union-attr]
    one(seg, Datagram.positional(Command.APWR, 1, R.sm_address(seg.slaves[1].esc.input_sm),
                                 sm_bytes(sm.start, sm.length, sm.control)))
    assert one(seg, Datagram.positional(Command.APRD, 1, sm.start, 1)).data == b"\x5a"


# --- ESC reset, SM events in the IRQ field (facts 3.3, 3.8) ---------------------------------------


def test_esc_reset_sequence_in_three_writes() -> None:
    seg = seg_n(2)
    fpwr(seg, 0x1001, R.AL_CONTROL, struct.pack("<H", AlState.PREOP))
    seg.slaves[1].write(R.USER_RAM, b"\x42")
    # a wrong byte in between restarts the sequence: no reset
    for b in (b"R", b"E", b"X", b"S"):
        assert fpwr(seg, 0x1001, R.ESC_RESET_ECAT, b).wkc == 1
    assert seg.slaves[1].u16(R.STATION_ADDRESS) == 0x1001
    for b in (b"R", b"E", b"S"):
        assert fpwr(seg, 0x1001, R.ESC_RESET_ECAT, b).wkc == 1
    s = seg.slaves[1]
    assert s.u16(R.STATION_ADDRESS) == 0 and s.al_state == AlState.INIT
    assert s.read(R.USER_RAM, 1) == b"\x00"
    assert seg.slaves[0].u16(R.STATION_ADDRESS) == 0x1000  # the other slave is untouched
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 2


def test_mailbox_sm_event_in_the_irq_field() -> None:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("m", mailbox=True))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    # SM1 with 'interrupt in ECAT event request' (control bit 4)
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN | R.SM_CONTROL_ECAT_EVENT))
    fpwr(seg, ST, R.ECAT_EVENT_MASK, struct.pack("<H", 1 << (4 + 1)))
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0
    assert seg.slaves[0].esc.pdi.post_mailbox(b"reply")
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 1 << 5
    fprd(seg, ST, MBX_IN, 128)  # reading the mailbox clears the event
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0


def test_crc_error_slaves_before_the_fault_still_process_the_frame() -> None:
    # An ESC commits a frame's writes when the frame's FCS checks out as it passes
    # (seed 000, 'Sicherungsmassnahmen'): slaves the frame passed before it was
    # corrupted take the write, the slave that receives it corrupted and every
    # slave after it do not. The frame is lost for the master either way.
    seg = seg_n(4, profile="ET1200")
    seg.corrupt_frames(2, 0, count=1)
    frame = encode_frame([Datagram.device(Command.BWR, 0, R.USER_RAM, b"\x77")])
    assert seg.process(frame) is None
    assert [s.read(R.USER_RAM, 1) for s in seg.slaves] == [b"\x77", b"\x77", b"\x00", b"\x00"]


def test_crc_error_on_the_return_path_after_every_pass_keeps_all_writes() -> None:
    # corrupted on its way back into slave 0 (port 1): every slave has processed the
    # frame with a good FCS; the master's NIC drops it (bad FCS), the counters say where
    seg = seg_n(3, profile="ET1200")
    seg.corrupt_frames(0, 1, count=1)
    frame = encode_frame([Datagram.device(Command.BWR, 0, R.USER_RAM, b"\x55"),
                          Datagram.device(Command.BRD, 0, R.TYPE, 1)])
    assert seg.process(frame) is None
    assert [s.read(R.USER_RAM, 1) for s in seg.slaves] == [b"\x55"] * 3
    assert seg.slaves[0].read(R.RX_ERROR_COUNTER + 2, 1) == b"\x01"
    assert seg.process(frame) is not None  # the fault hit one frame only


def test_crc_error_receiving_slave_and_downstream_keep_their_memory_and_count() -> None:
    seg = seg_n(4, profile="ET1200")
    seg.corrupt_frames(1, 0, count=1)
    frame = encode_frame([Datagram.positional(Command.APWR, 0, R.USER_RAM, b"\x11"),
                          Datagram.positional(Command.APWR, -1 & 0xFFFF, R.USER_RAM, b"\x22"),
                          Datagram.positional(Command.APWR, -3 & 0xFFFF, R.USER_RAM, b"\x33")])
    assert seg.process(frame) is None
    assert [s.read(R.USER_RAM, 1) for s in seg.slaves] == [b"\x11", b"\x00", b"\x00", b"\x00"]
    c = [s.read(R.RX_ERROR_COUNTER, 12) for s in seg.slaves]
    assert c[1][0] == 1 and c[1][8] == 0  # detected on port 0: not also a forwarded error there
    assert c[2][8] == 1 and c[3][8] == 1  # downstream: forwarded errors on port 0
    assert c[0][8] == 0 and c[0][9] == 1  # slave 0 only sees it come back on port 1
