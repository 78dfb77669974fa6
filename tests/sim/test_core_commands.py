"""Every command's addressing, ADP increment and working-counter rule (facts 2.2)."""

from __future__ import annotations

import struct

from simhelp import address_all, fprd, line, one, spec, u16, xfer

from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame


def seg3() -> Segment:
    seg = line(3)
    address_all(seg)
    return seg


def test_brd_counts_slaves_ors_data_and_increments_adp() -> None:
    seg = line(3)
    d = one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 2))
    assert d.wkc == 3
    assert d.adp == 3
    assert d.data == bytes([0x11, 0x00])  # ET1100 type, revision


def test_brd_ors_differing_values() -> None:
    seg = line(3)
    seg.slaves[0].write(R.USER_RAM, b"\x01")
    seg.slaves[2].write(R.USER_RAM, b"\x80")
    d = one(seg, Datagram.device(Command.BRD, 0, R.USER_RAM, 1))
    assert d.data == b"\x81" and d.wkc == 3


def test_bwr_writes_all_and_counts() -> None:
    seg = line(4)
    d = one(seg, Datagram.device(Command.BWR, 0x10, R.USER_RAM, b"\x5a\xa5"))
    assert d.wkc == 4 and d.adp == 0x14
    assert all(s.read(R.USER_RAM, 2) == b"\x5a\xa5" for s in seg.slaves)


def test_brw_wkc_three_per_slave_and_swaps() -> None:
    seg = line(2)
    seg.slaves[0].write(R.USER_RAM, b"\x01")
    seg.slaves[1].write(R.USER_RAM, b"\x02")
    d = one(seg, Datagram.device(Command.BRW, 0, R.USER_RAM, b"\x10"))
    assert d.wkc == 6
    assert d.data == bytes([0x10 | 0x01 | 0x02])
    assert seg.slaves[0].read(R.USER_RAM, 1) == b"\x10"
    # the second slave stores the data as it arrived there (already ORed by the first)
    assert seg.slaves[1].read(R.USER_RAM, 1) == b"\x11"


def test_aprd_addresses_by_position_and_increments_adp() -> None:
    seg = line(3)
    seg.slaves[1].write(R.USER_RAM, b"\x42")
    d = one(seg, Datagram.positional(Command.APRD, 1, R.USER_RAM, 1))
    assert d.wkc == 1 and d.data == b"\x42"
    assert d.adp == (0xFFFF + 3) & 0xFFFF  # -1 + 3 slaves
    missing = one(seg, Datagram.positional(Command.APRD, 5, R.USER_RAM, 1))
    assert missing.wkc == 0 and missing.data == b"\x00"


def test_apwr_aprw() -> None:
    seg = line(3)
    d = one(seg, Datagram.positional(Command.APWR, 2, R.USER_RAM, b"\x07"))
    assert d.wkc == 1 and seg.slaves[2].read(R.USER_RAM, 1) == b"\x07"
    d = one(seg, Datagram.positional(Command.APRW, 2, R.USER_RAM, b"\x09"))
    assert d.wkc == 3 and d.data == b"\x07"
    assert seg.slaves[2].read(R.USER_RAM, 1) == b"\x09"


def test_fprd_fpwr_fprw_by_station_address() -> None:
    seg = seg3()
    assert fprd(seg, 0x1002, R.STATION_ADDRESS, 2).data == struct.pack("<H", 0x1002)
    d = one(seg, Datagram.device(Command.FPWR, 0x1001, R.USER_RAM, b"\x33"))
    assert d.wkc == 1 and d.adp == 0x1001
    assert seg.slaves[1].read(R.USER_RAM, 1) == b"\x33"
    d = one(seg, Datagram.device(Command.FPRW, 0x1001, R.USER_RAM, b"\x44"))
    assert d.wkc == 3 and d.data == b"\x33"
    assert fprd(seg, 0x7777, R.TYPE, 1).wkc == 0


def test_fprd_by_alias_only_when_enabled() -> None:
    seg = Segment()
    seg.add_slave(spec("a", alias_sii=0x0042))
    address_all(seg)
    assert fprd(seg, 0x0042, R.TYPE, 1).wkc == 0
    assert fprd(seg, 0x1000, R.STATION_ALIAS, 2).data == b"\x42\x00"
    one(seg, Datagram.device(Command.FPWR, 0x1000, R.DL_CONTROL_ALIAS, b"\x01"))
    assert fprd(seg, 0x0042, R.TYPE, 1).wkc == 1


def test_armw_frmw_reader_and_writers() -> None:
    seg = seg3()
    for i, s in enumerate(seg.slaves):
        s.write(R.USER_RAM, bytes([0x10 + i]))
    d = one(seg, Datagram.positional(Command.ARMW, 1, R.USER_RAM, b"\xee"))
    assert d.wkc == 3 and d.data == b"\x11"
    assert seg.slaves[0].read(R.USER_RAM, 1) == b"\xee"  # before the reader: master's data
    assert seg.slaves[2].read(R.USER_RAM, 1) == b"\x11"  # after it: the reader's data
    assert d.adp == (0xFFFF + 3) & 0xFFFF
    seg.slaves[0].write(R.USER_RAM, b"\x55")
    d = one(seg, Datagram.device(Command.FRMW, 0x1000, R.USER_RAM, b"\x00"))
    assert d.wkc == 3 and d.data == b"\x55" and d.adp == 0x1000
    assert seg.slaves[2].read(R.USER_RAM, 1) == b"\x55"


def test_nop_does_nothing() -> None:
    seg = line(2)
    d = one(seg, Datagram.device(Command.NOP, 0, R.USER_RAM, b"\x12"))
    assert d.wkc == 0 and d.adp == 0 and d.data == b"\x12"


def test_missing_registers_answer_wkc_zero() -> None:
    seg = line(2, profile="ET1200")  # 3 FMMUs, 4 SMs, 1 KiB RAM
    assert one(seg, Datagram.device(Command.BRD, 0, R.fmmu_address(2), 16)).wkc == 2
    assert one(seg, Datagram.device(Command.BRD, 0, R.fmmu_address(3), 16)).wkc == 0
    assert one(seg, Datagram.device(Command.BWR, 0, R.sm_address(4), bytes(8))).wkc == 0
    assert one(seg, Datagram.device(Command.BRD, 0, 0x1000 + 1024, 4)).wkc == 0
    assert one(seg, Datagram.device(Command.BRD, 0, 0x1000 + 1020, 4)).wkc == 2
    assert one(seg, Datagram.positional(Command.APRD, 0, R.fmmu_address(7), 2)).wkc == 0


def test_read_only_registers_ignore_writes_without_counting() -> None:
    seg = line(2)
    d = one(seg, Datagram.positional(Command.APWR, 0, R.TYPE, b"\x99"))
    assert seg.slaves[0].read(R.TYPE, 1) == b"\x11"
    assert d.wkc == 0  # real ESCs: BWR of read-only 0x092C returns WKC 0
    assert one(seg, Datagram.device(Command.BWR, 0, R.DC_SYSTEM_TIME_DIFFERENCE, bytes(4))).wkc == 0
    # a write that covers some writable byte counts; the read-only bytes keep their value
    d = one(seg, Datagram.positional(Command.APWR, 0, R.STATION_ADDRESS - 2, b"\xaa\xbb\x34\x12"))
    assert d.wkc == 1 and seg.slaves[0].u16(R.STATION_ADDRESS) == 0x1234


def test_mixed_profiles_broadcast_counts_only_implementing_slaves() -> None:
    seg = Segment()
    seg.add_slave(spec("big", "ET1100"))
    seg.add_slave(spec("small", "ET1200"))
    seg.add_slave(spec("big2", "ET1100"))
    d = one(seg, Datagram.device(Command.BWR, 0, R.fmmu_address(5), bytes(16)))
    assert d.wkc == 2


def test_many_datagrams_in_one_frame() -> None:
    seg = seg3()
    ds = xfer(seg,
              Datagram.device(Command.BRD, 0, R.TYPE, 1, index=1),
              Datagram.device(Command.FPWR, 0x1000, R.USER_RAM, b"\x01", index=2),
              Datagram.device(Command.FPRD, 0x1000, R.USER_RAM, 1, index=3),
              Datagram.positional(Command.APRD, 2, R.STATION_ADDRESS, 2, index=4))
    assert [d.index for d in ds] == [1, 2, 3, 4]
    assert [d.wkc for d in ds] == [3, 1, 1, 1]
    assert ds[2].data == b"\x01"
    assert u16(ds[3]) == 0x1002


def test_returned_source_mac_has_locally_administered_bit() -> None:
    seg = line(1)
    frame = encode_frame([Datagram.device(Command.BRD, 0, 0, 2)], src=b"\x10\x10\x10\x10\x10\x10")
    reply = seg.process(frame)
    assert reply is not None
    assert decode_frame(reply).src == b"\x12\x10\x10\x10\x10\x10"
    assert reply[:6] == frame[:6] and len(reply) == len(frame)


def test_irq_field_is_or_of_masked_event_requests() -> None:
    seg = seg3()
    # Mask the AL status event on slave 1 only; AL status changes on every slave.
    one(seg, Datagram.device(Command.FPWR, 0x1001, R.ECAT_EVENT_MASK,
                             struct.pack("<H", R.EcatEvent.AL_STATUS)))
    one(seg, Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", 2)))
    d = one(seg, Datagram.device(Command.NOP, 0, 0, 1))
    assert d.irq & R.EcatEvent.AL_STATUS
    # reading AL status clears the event; the read itself still carries it (each
    # slave ORs its events into the header before it executes the datagram)
    assert one(seg, Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)).irq & R.EcatEvent.AL_STATUS
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0
    # a state change shows from the next datagram on, not in the AL control write itself
    assert not one(seg, Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", 1))).irq
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.AL_STATUS


def test_dl_status_event_cleared_by_reading_dl_status() -> None:
    seg = seg3()
    one(seg, Datagram.device(Command.BWR, 0, R.ECAT_EVENT_MASK, struct.pack("<H", R.EcatEvent.DL_STATUS)))
    # the links came up at power-on: pending until DL status (0x0110) is read
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == R.EcatEvent.DL_STATUS
    assert one(seg, Datagram.device(Command.FPRD, 0x1001, R.DL_STATUS, 2)).irq == R.EcatEvent.DL_STATUS
    # still pending at the slaves that were not read
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == R.EcatEvent.DL_STATUS
    assert one(seg, Datagram.device(Command.BRD, 0, R.DL_STATUS, 2)).irq == R.EcatEvent.DL_STATUS
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq == 0


def test_circulating_bit_destroys_frame_on_second_pass() -> None:
    seg = line(2)
    # close port 0 of the first slave: the frame comes back into its processing unit
    seg.slaves[0].write(R.DL_CONTROL_LOOP, bytes([R.LoopControl.CLOSED]))
    seg.state.topology_dirty = True
    assert seg.process(encode_frame([Datagram.device(Command.BWR, 0, R.USER_RAM, b"\x01")])) is None
    # both slaves were passed once before the frame was destroyed
    assert seg.slaves[1].read(R.USER_RAM, 1) == b"\x01"
    c = Datagram.device(Command.BRD, 0, R.TYPE, 1)
    c.circulating = True
    assert seg.process(encode_frame([c])) is None


def test_malformed_frame_counts_processing_error() -> None:
    seg = line(1)
    frame = bytearray(encode_frame([Datagram.device(Command.BRD, 0, 0, 2)]))
    frame[14] = 0x30  # EtherCAT length 48 > datagram: the datagram claims nothing consistent
    frame[20] = 0xFF  # LEN low byte -> runs past the end
    assert seg.process(bytes(frame)) is None
    assert seg.slaves[0].read(R.ECAT_PROCESSING_ERROR_COUNTER, 1) == b"\x01"
