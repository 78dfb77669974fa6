"""FMMU mapping: the seed 004 example, bit ops, overlap rules, registers, WKC."""

from __future__ import annotations

from simhelp import IN_SM, OUT_SM, address_all, fmmu_bytes, fpwr, line, one, sm_bytes, spec

from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram

READ, WRITE = int(R.FmmuType.READ), int(R.FmmuType.WRITE)


def test_seed004_example_bitwise_write() -> None:
    seg = line(1)
    address_all(seg)
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x00014711, 2, 3, 0, 0x0F01, 1, WRITE))
    seg.slaves[0].write(0x0F01, b"\x81")  # bits 0 and 7 are not mapped: they must stay
    d = one(seg, Datagram.logical(Command.LWR, 0x00014711, bytes([0b1010_1000, 0x01])))
    assert d.wkc == 1
    # logical bits 3..7 of byte 0x14711 and bit 0 of 0x14712 -> physical 0x0F01 bits 1..6
    assert seg.slaves[0].read(0x0F01, 1) == bytes([0x81 | 0b0110_1010])
    # a datagram touching only the first logical byte maps only those 5 bits
    seg.slaves[0].write(0x0F01, b"\x00")
    d = one(seg, Datagram.logical(Command.LWR, 0x00014711, b"\xf8"))
    assert d.wkc == 1 and seg.slaves[0].read(0x0F01, 1) == bytes([0b0011_1110])
    # outside the FMMU's logical range: nothing happens, WKC 0, data unchanged
    d = one(seg, Datagram.logical(Command.LWR, 0x00014713, b"\xff"))
    assert d.wkc == 0 and d.data == b"\xff"


def test_bit_reads_leave_unmapped_bits_untouched() -> None:
    seg = line(2)
    address_all(seg)
    # each slave maps 2 input bits from 0x1180 bits 0-1 to logical 0x100 bits 2-3 / 4-5
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x100, 1, 2, 3, 0x1180, 0, READ))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(0x100, 1, 4, 5, 0x1180, 0, READ))
    seg.slaves[0].write(0x1180, b"\x02")
    seg.slaves[1].write(0x1180, b"\x03")
    d = one(seg, Datagram.logical(Command.LRD, 0x100, b"\x81"))
    assert d.wkc == 2
    assert d.data == bytes([0x81 | (0b10 << 2) | (0b11 << 4)])


def test_unconfigured_logical_bytes_pass_unchanged() -> None:
    seg = line(1)
    address_all(seg)
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x1001, 1, 0, 7, 0x1180, 0, READ))
    seg.slaves[0].write(0x1180, b"\x5a")
    d = one(seg, Datagram.logical(Command.LRD, 0x1000, b"\x11\x22\x33"))
    assert d.data == b"\x11\x5a\x33" and d.wkc == 1


def test_lrw_wkc_three_and_mapping_onto_registers() -> None:
    seg = line(1)
    address_all(seg)
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0, 1, 0, 7, R.USER_RAM, 0, WRITE))
    fpwr(seg, 0x1000, R.fmmu_address(1), fmmu_bytes(1, 1, 0, 7, R.sm_address(1) + R.SM_STATUS, 0, READ))
    seg.slaves[0].write(R.sm_address(1) + R.SM_STATUS, b"\x08")
    d = one(seg, Datagram.logical(Command.LRW, 0, b"\x77\x00"))
    assert d.wkc == 3
    assert d.data == b"\x77\x08"
    assert seg.slaves[0].read(R.USER_RAM, 1) == b"\x77"
    assert one(seg, Datagram.logical(Command.LRD, 0, 2)).wkc == 1
    assert one(seg, Datagram.logical(Command.LWR, 0, 2)).wkc == 1


def test_read_by_one_fmmu_written_by_another_cross_traffic() -> None:
    seg = line(3)
    address_all(seg)
    # slave 0 reads its input into logical 0x10; slave 2 writes logical 0x10 to its RAM;
    # slave 1 (before nothing) also writes logical 0x10 but it comes *after* slave 0 too.
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x10, 1, 0, 7, 0x1180, 0, READ))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(0x10, 1, 0, 7, 0x1100, 0, WRITE))
    fpwr(seg, 0x1002, R.fmmu_address(0), fmmu_bytes(0x10, 1, 0, 7, 0x1100, 0, WRITE))
    seg.slaves[0].write(0x1180, b"\xc3")
    d = one(seg, Datagram.logical(Command.LRW, 0x10, b"\x01"))
    assert d.data == b"\xc3"
    assert d.wkc == 1 + 2 + 2
    assert seg.slaves[1].read(0x1100, 1) == b"\xc3"
    assert seg.slaves[2].read(0x1100, 1) == b"\xc3"


def test_writer_before_reader_gets_the_masters_data() -> None:
    seg = line(2)
    address_all(seg)
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x10, 1, 0, 7, 0x1100, 0, WRITE))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(0x10, 1, 0, 7, 0x1180, 0, READ))
    seg.slaves[1].write(0x1180, b"\x3c")
    d = one(seg, Datagram.logical(Command.LRW, 0x10, b"\x01"))
    assert d.data == b"\x3c" and d.wkc == 3
    assert seg.slaves[0].read(0x1100, 1) == b"\x01"


def test_same_slave_in_and_out_overlap_reads_old_memory() -> None:
    seg = line(1)
    address_all(seg)
    # SOEM's overlapped mapping: write and read FMMU of one slave on the same logical byte
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0x20, 1, 0, 7, 0x1100, 0, WRITE))
    fpwr(seg, 0x1000, R.fmmu_address(1), fmmu_bytes(0x20, 1, 0, 7, 0x1100, 0, READ))
    seg.slaves[0].write(0x1100, b"\x0f")
    d = one(seg, Datagram.logical(Command.LRW, 0x20, b"\xf0"))
    assert d.data == b"\x0f" and d.wkc == 3
    assert seg.slaves[0].read(0x1100, 1) == b"\xf0"


def test_last_reader_on_the_route_wins() -> None:
    seg = line(3)
    address_all(seg)
    for st in (0x1000, 0x1002):
        fpwr(seg, st, R.fmmu_address(0), fmmu_bytes(0x30, 1, 0, 7, 0x1180, 0, READ))
    seg.slaves[0].write(0x1180, b"\x01")
    seg.slaves[2].write(0x1180, b"\x02")
    d = one(seg, Datagram.logical(Command.LRD, 0x30, 1))
    assert d.data == b"\x02" and d.wkc == 2


def test_process_data_through_sms_and_fmmus_publishes_outputs() -> None:
    seg = Segment()
    seg.add_slave(spec("do", out_bits=16))
    seg.add_slave(spec("di", in_bits=8))
    address_all(seg)
    fpwr(seg, 0x1000, R.sm_address(2), sm_bytes(OUT_SM, 2, R.SM_CONTROL_OUTPUTS))
    fpwr(seg, 0x1001, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0, 2, 0, 7, OUT_SM, 0, WRITE))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(2, 1, 0, 7, IN_SM, 0, READ))
    seg.slaves[1].esc.pdi.set_inputs(b"\x99")
    d = one(seg, Datagram.logical(Command.LRW, 0, b"\x34\x12\x00"))
    assert d.wkc == 3 and d.data[2] == 0x99
    assert seg.slaves[0].esc.pdi.outputs() == b"\x34\x12"
    # a datagram that misses the SM's last byte does not publish a new buffer
    d = one(seg, Datagram.logical(Command.LWR, 0, b"\xff"))
    assert d.wkc == 1
    assert seg.slaves[0].esc.pdi.outputs() == b"\x34\x12"
    one(seg, Datagram.logical(Command.LWR, 1, b"\xee"))
    assert seg.slaves[0].esc.pdi.outputs() == b"\xff\xee"


def test_wiring_outputs_to_inputs() -> None:
    seg = Segment()
    seg.add_slave(spec("do", out_bits=8))
    seg.add_slave(spec("di", in_bits=8))
    seg.wire(0, 0, 1, 4, 4)  # output bits 0-3 drive input bits 4-7
    address_all(seg)
    fpwr(seg, 0x1000, R.sm_address(2), sm_bytes(OUT_SM, 1, R.SM_CONTROL_OUTPUTS))
    fpwr(seg, 0x1001, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    fpwr(seg, 0x1000, R.fmmu_address(0), fmmu_bytes(0, 1, 0, 7, OUT_SM, 0, WRITE))
    fpwr(seg, 0x1001, R.fmmu_address(0), fmmu_bytes(1, 1, 0, 7, IN_SM, 0, READ))
    one(seg, Datagram.logical(Command.LRW, 0, b"\x0a\x00"))
    d = one(seg, Datagram.logical(Command.LRW, 0, b"\x0a\x00"))
    assert d.data[1] == 0xA0
