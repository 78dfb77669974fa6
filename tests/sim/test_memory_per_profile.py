"""ESC memory sized per chip: a row holds the registers and the chip's process RAM only.

An ET1200 has 1 KiB of process RAM (0x1000-0x13FF), an ET1100 8 KiB
(0x1000-0x2FFF): a segment of ET1200 terminals does not pay 64 KiB per slave.
Adding a chip with more RAM widens every row, and everything compiled with
flat indices (FMMU plans, broadcast plans, process-data gathers) follows.
"""

from __future__ import annotations

from simhelp import address_all, fmmu_bytes, fprd, fpwr, line, one, sm_bytes, spec

from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram

ST = 0x1000


def _map_outputs(seg: object, station: int, logical: int) -> None:
    fpwr(seg, station, R.sm_address(2), sm_bytes(0x1100, 2, R.SM_CONTROL_OUTPUTS))  # type: ignore[arg-type]
    fpwr(seg, station, R.fmmu_address(0),  # type: ignore[arg-type]
         fmmu_bytes(logical, 2, 0, 7, 0x1100, 0, int(R.FmmuType.WRITE)))


def test_rows_are_as_wide_as_the_largest_chip_and_widen_keeping_everything() -> None:
    seg = line(3, profile="ET1200")
    assert seg.memory.stride == 0x1400  # registers + 1 KiB
    assert seg.memory.nbytes == 2 * seg.memory.capacity * 0x1400
    address_all(seg)
    for i in range(3):
        _map_outputs(seg, ST + i, 0x100 + 2 * i)
    assert one(seg, Datagram.logical(Command.LWR, 0x100, b"\x01\x02\x03\x04\x05\x06")).wkc == 3
    fpwr(seg, ST + 1, 0x1200, b"kept")
    # memory the ET1200 lacks: not implemented, not counted
    assert fprd(seg, ST, 0x2000, 4).wkc == 0
    assert fprd(seg, ST, 0x13FC, 4).wkc == 1
    seg.add_slave(spec("big", "ET1100"))
    assert seg.memory.stride == 0x3000
    one(seg, Datagram.positional(Command.APWR, 3, R.STATION_ADDRESS, (ST + 3).to_bytes(2, "little")))
    # the rows moved: what was written is where it was, and the compiled FMMU plan follows
    assert fprd(seg, ST + 1, 0x1200, 4).data == b"kept"
    assert [sl.read(0x1100, 2) for sl in seg.slaves[:3]] == [b"\x01\x02", b"\x03\x04", b"\x05\x06"]
    _map_outputs(seg, ST + 3, 0x106)
    assert one(seg, Datagram.logical(Command.LWR, 0x100, bytes(range(0x10, 0x18)))).wkc == 4
    assert [sl.read(0x1100, 2) for sl in seg.slaves] == [b"\x10\x11", b"\x12\x13", b"\x14\x15",
                                                          b"\x16\x17"]
    # the ET1100 has RAM at 0x2000, the ET1200s still do not
    d = one(seg, Datagram.device(Command.BWR, 0, 0x2000, b"\xaa"))
    assert d.wkc == 1 and seg.slaves[3].read(0x2000, 1) == b"\xaa"
    assert seg.slaves[0].read(0x2000, 1) == b"\x00"


def test_an_sm_reaching_past_the_chips_ram_is_not_activated() -> None:
    seg = line(1, profile="ET1200")
    address_all(seg)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(0x13F0, 0x20, R.SM_CONTROL_OUTPUTS))
    assert not seg.slaves[0].esc.sm(2).enabled
    fpwr(seg, ST, R.sm_address(2), sm_bytes(0x13F0, 0x10, R.SM_CONTROL_INPUTS))
    assert seg.slaves[0].esc.sm(2).enabled
