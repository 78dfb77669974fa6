"""Logical (FMMU) access to sync-manager buffers follows the same SM rules as FPRD/FPWR.

Facts 3.13: a buffer counts as read when its last byte is read (status bit 1
'read event', the SM's AL event to the application, its ECAT event cleared),
and the ESC refuses EtherCAT writes into a buffer the master may only read
(direction 00, ECAT reads: SM1, SM3). An LRD/LRW that reads an input SM's
last byte through an FMMU is such a complete read; an LWR/LRW through a write
FMMU onto an input SM changes nothing and, like FPWR there, does not count
(ESC datasheet: the working counter counts accesses to accessible memory).
"""

from __future__ import annotations

import struct

import numpy as np
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
    one,
    sm_bytes,
    spec,
)

from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram

READ, WRITE = int(R.FmmuType.READ), int(R.FmmuType.WRITE)
ST = 0x1000
SM3_STATUS = R.sm_address(3) + R.SM_STATUS
#: SM3 with both interrupt bits: the read sets the AL event, clears the ECAT event.
IN_CONTROL = R.SM_CONTROL_INPUTS | R.SM_CONTROL_ECAT_EVENT


def _io(n: int = 1, in_len: int = 2) -> Segment:
    seg = Segment()
    for i in range(n):
        seg.add_slave(spec(f"io{i}", out_bits=16, in_bits=8 * in_len))
    address_all(seg)
    for i in range(n):
        fpwr(seg, ST + i, R.sm_address(2), sm_bytes(OUT_SM, 2, R.SM_CONTROL_OUTPUTS))
        fpwr(seg, ST + i, R.sm_address(3), sm_bytes(IN_SM, in_len, IN_CONTROL))
        # outputs at logical 0x100 + 2i, inputs at 0x200 + in_len * i
        fpwr(seg, ST + i, R.fmmu_address(0), fmmu_bytes(0x100 + 2 * i, 2, 0, 7, OUT_SM, 0, WRITE))
        fpwr(seg, ST + i, R.fmmu_address(1), fmmu_bytes(0x200 + in_len * i, in_len, 0, 7, IN_SM, 0, READ))
        seg.slaves[i].esc.pdi.set_inputs(bytes([0x10 + i] * in_len))
        # a pending SM3 ECAT event, as a firmware with ECAT-event SMs leaves it
        seg.slaves[i].esc.set_ecat_event(1 << (4 + 3))
    return seg


def _events(seg: Segment, i: int = 0) -> tuple[int, int, int]:
    s = seg.slaves[i]
    return (s.read(SM3_STATUS, 1)[0], struct.unpack("<I", s.read(R.AL_EVENT_REQUEST, 4))[0],
            s.u16(R.ECAT_EVENT_REQUEST))


def test_lrd_of_the_last_input_byte_is_a_buffer_read_like_fprd() -> None:
    by_fprd, by_lrd = _io(), _io()
    before = _events(by_lrd)
    assert not before[0] & R.SM_STATUS_READ_EVENT and before[2] & (1 << 7)
    assert fprd(by_fprd, ST, IN_SM, 2).data == b"\x10\x10"
    d = one(by_lrd, Datagram.logical(Command.LRD, 0x200, 2))
    assert d.wkc == 1 and d.data == b"\x10\x10"
    after = _events(by_lrd)
    assert after == _events(by_fprd)
    assert after[0] & R.SM_STATUS_READ_EVENT
    assert after[1] & (1 << (8 + 3))  # SM3 AL event to the application
    assert not after[2] & (1 << 7)  # SM3 ECAT event cleared by the read


def test_logical_read_without_the_last_byte_is_no_buffer_read() -> None:
    seg = _io()
    before = _events(seg)
    assert one(seg, Datagram.logical(Command.LRD, 0x200, 1)).wkc == 1
    assert _events(seg) == before
    # the last byte read alone completes it (as FPRD of IN_SM + 1 does)
    assert one(seg, Datagram.logical(Command.LRD, 0x201, 1)).wkc == 1
    assert _events(seg)[0] & R.SM_STATUS_READ_EVENT


def test_bit_fmmu_reading_a_bit_of_the_last_byte_completes_the_read() -> None:
    seg = _io(in_len=1)
    fpwr(seg, ST, R.fmmu_address(1), fmmu_bytes(0x300, 1, 2, 2, IN_SM, 4, READ))
    assert one(seg, Datagram.logical(Command.LRD, 0x300, 1)).data == b"\x04"  # bit 4 of 0x10
    assert _events(seg)[0] & R.SM_STATUS_READ_EVENT


def test_lrw_over_many_slaves_reads_every_input_buffer() -> None:
    seg = _io(5)
    outputs = bytes(range(1, 11))
    d = one(seg, Datagram.logical(Command.LRW, 0x100, outputs + bytes(0x100 - 10 + 10)))
    assert d.wkc == 5 * 3
    assert d.data[0x100:] == bytes(x for i in range(5) for x in (0x10 + i,) * 2)
    for i in range(5):
        status, al, ecat = _events(seg, i)
        assert status & R.SM_STATUS_READ_EVENT and al & (1 << 11) and not ecat & (1 << 7)
        assert seg.slaves[i].read(OUT_SM, 2) == outputs[2 * i: 2 * i + 2]


def test_fmmu_write_into_an_input_sm_is_refused() -> None:
    seg = _io()
    # a (mis)configured write FMMU onto the input buffer
    fpwr(seg, ST, R.fmmu_address(2), fmmu_bytes(0x400, 2, 0, 7, IN_SM, 0, WRITE))
    status = seg.slaves[0].read(SM3_STATUS, 1)
    d = one(seg, Datagram.logical(Command.LWR, 0x400, b"\xaa\xbb"))
    assert d.wkc == 0  # as FPWR into an input SM: not accessible, not counted
    assert fpwr(seg, ST, IN_SM, b"\xcc\xdd").wkc == 0
    assert seg.slaves[0].read(IN_SM, 2) == b"\x10\x10"
    assert seg.slaves[0].read(SM3_STATUS, 1) == status
    # LRW over outputs and the refused write: only the output write (+2) counts
    d = one(seg, Datagram.logical(Command.LRW, 0x100, bytes(0x302)))
    assert d.wkc == 2 + 1  # output write, input read
    d = one(seg, Datagram.logical(Command.LRW, 0x300, bytes(0x102)))
    assert d.wkc == 0 and seg.slaves[0].read(IN_SM, 2) == b"\x10\x10"


def test_bit_fmmu_write_into_input_sm_and_mailbox_in_is_refused() -> None:
    seg = Segment()
    seg.add_slave(spec("m", mailbox=True, out_bits=16, in_bits=16))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 2, R.SM_CONTROL_INPUTS))
    fpwr(seg, ST, R.fmmu_address(0), fmmu_bytes(0x10, 1, 1, 3, IN_SM + 1, 5, WRITE))
    fpwr(seg, ST, R.fmmu_address(1), fmmu_bytes(0x20, 4, 0, 7, MBX_IN, 0, WRITE))
    assert one(seg, Datagram.logical(Command.LWR, 0x10, b"\xff")).wkc == 0
    assert one(seg, Datagram.logical(Command.LWR, 0x20, b"\xff" * 4)).wkc == 0
    assert seg.slaves[0].read(IN_SM, 2) == bytes(2)
    assert seg.slaves[0].read(MBX_IN, 4) == bytes(4)


def test_write_refusal_follows_the_sm_configuration() -> None:
    seg = _io()
    fpwr(seg, ST, R.fmmu_address(2), fmmu_bytes(0x400, 2, 0, 7, IN_SM, 0, WRITE))
    assert one(seg, Datagram.logical(Command.LWR, 0x400, b"\xaa\xbb")).wkc == 0
    # SM3 disabled: plain RAM again, the FMMU write lands
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 2, IN_CONTROL, enable=0))
    assert one(seg, Datagram.logical(Command.LWR, 0x400, b"\xaa\xbb")).wkc == 1
    assert seg.slaves[0].read(IN_SM, 2) == b"\xaa\xbb"
    # SM3 turned into an output SM: writes complete its buffer
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 2, R.SM_CONTROL_OUTPUTS))
    assert one(seg, Datagram.logical(Command.LWR, 0x400, b"\x01\x02")).wkc == 1
    assert seg.slaves[0].read(SM3_STATUS, 1)[0] & R.SM_STATUS_WRITE_EVENT


@pytest.mark.parametrize("ordered", [False, True])
def test_read_event_also_on_the_ordered_path(ordered: bool) -> None:
    seg = _io(2)
    if ordered:
        # slave 1 writes the logical byte slave 0 reads (cross traffic): pass-by-pass path
        fpwr(seg, ST + 1, R.fmmu_address(2), fmmu_bytes(0x200, 1, 0, 7, OUT_SM, 0, WRITE))
    one(seg, Datagram.logical(Command.LRW, 0x200, bytes(4)))
    assert _events(seg, 0)[0] & R.SM_STATUS_READ_EVENT
    assert _events(seg, 1)[0] & R.SM_STATUS_READ_EVENT
    assert np.array_equal(seg.slaves[0].esc.row[SM3_STATUS: SM3_STATUS + 1],
                          seg.slaves[1].esc.row[SM3_STATUS: SM3_STATUS + 1])
