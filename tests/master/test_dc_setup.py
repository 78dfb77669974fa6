"""The sans-IO DC set-up (master.dc.DcSetup), driven by hand with the replies of real slaves.

The register values are those of the replay-dc capture in the corpus
(ethercrab on an EK1100, EL2828 and EL2889): the EL2828 has receive times
but no system time (its 0x0918 read comes back with working counter 0).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import pytest

from pyethercat.errors import ConfigError
from pyethercat.master.dc import (
    DcError,
    DcSettings,
    DcSetup,
    DcSlaveInfo,
    SyncSettings,
    run_dc_setup,
    sync_config_writes,
)
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import MAX_PAYLOAD, Command, Datagram
from pyethercat.wire.dc import encode_time_difference

FULL = 0x00FC    # EK1100, EL2889: DC, 64-bit
LATCH = 0x01FC   # EL2828: DC bit set, but no system time behind it
HOFF = int.from_bytes(b"hoff", "little")

SLAVES = [
    DcSlaveInfo(0, 0x1000, FULL, frozenset({0, 1}), "EK1100"),
    DcSlaveInfo(1, 0x1001, LATCH, frozenset({0, 1}), "EL2828"),
    DcSlaveInfo(2, 0x1002, FULL, frozenset({0}), "EL2889"),
]
PORTS = {0x1000: (0x3C620F52, 0x3C6211AA, 0, 0x6C726556),
         0x1001: (0x3D0BD6AE, 0x3D0BD7E4, 0, 0x6C726556),
         0x1002: (0x3C8065EC, HOFF, 0, 0x6C726556)}
EPU = {0x1000: 0xF53C620F52, 0x1002: 0xF53C8065EC}


class Bus:
    """Answers the set-up's datagrams as the three real slaves did; records what it got."""

    def __init__(self, differences: dict[int, int] | None = None) -> None:
        self.sent: list[list[Datagram]] = []
        self.written: dict[tuple[int, int], bytes] = {}
        self.differences = differences or {0x1000: 0, 0x1002: -35}

    def __call__(self, batch: Sequence[Datagram]) -> list[Datagram]:
        self.sent.append(list(batch))
        out = []
        for d in batch:
            data, wkc = bytes(d.data), 0
            if d.command == Command.BWR and d.ado == R.DC_RECEIVE_TIME_PORT0:
                wkc = 3
            elif d.command == Command.BWR:
                wkc = 2   # loop registers: the two slaves with a system time
            elif d.command == Command.FPRD and d.ado == R.DC_RECEIVE_TIME_PORT0:
                data, wkc = struct.pack("<4I", *PORTS[d.adp]), 1
            elif d.command == Command.FPRD and d.ado == R.DC_RECEIVE_TIME_ECAT:
                if d.adp in EPU:
                    data, wkc = struct.pack("<Q", EPU[d.adp]), 1
            elif d.command == Command.FPWR:
                self.written[(d.adp, d.ado)] = data
                wkc = 1 if d.adp in EPU else 0
            elif d.command == Command.FRMW:
                data, wkc = struct.pack("<Q", 12345), 2
            elif d.command == Command.FPRD and d.ado == R.DC_SYSTEM_TIME_DIFFERENCE:
                data, wkc = struct.pack("<I", encode_time_difference(self.differences[d.adp])), 1
            out.append(Datagram(d.command, d.index, d.address, data, wkc=wkc))
        return out


def test_setup_on_the_corpus_slaves() -> None:
    bus = Bus()
    waits: list[float] = []
    report = run_dc_setup(bus, SLAVES, DcSettings(static_sync=1000), master_time=lambda: 0,
                          sleep=waits.append)
    # the compensation's requests (2 frames each) are spaced by 2 ms of master time
    assert waits == [0.002] * 6
    first = bus.sent[0]
    assert len(first) == 1 and (first[0].command, first[0].ado, len(first[0].data)) == (
        Command.BWR, R.DC_RECEIVE_TIME_PORT0, 4)
    # all latches read in one batch: 0x0900 (16 bytes) and 0x0918 (8 bytes) per DC slave
    reads = bus.sent[1]
    assert [(d.adp, d.ado, len(d.data)) for d in reads] == [
        (0x1000, 0x0900, 16), (0x1000, 0x0918, 8), (0x1001, 0x0900, 16), (0x1001, 0x0918, 8),
        (0x1002, 0x0900, 16), (0x1002, 0x0918, 8)]
    assert [s.kind for s in report.slaves] == ["64-bit", "latch-only", "64-bit"]
    assert report.reference == 0 and report.slaves[0].reference
    # delays as ethercrab computed them from the same latches: 145 and 300 ns
    assert [s.delay_ns for s in report.slaves] == [0, 145, 300]
    # offsets: master time 0 + delay - 0x0918, one 12-byte write (offset + delay) per slave
    writes = bus.sent[2]
    assert [(d.adp, d.ado, len(d.data)) for d in writes] == [(0x1000, 0x0920, 12),
                                                             (0x1002, 0x0920, 12)]
    assert bus.written[(0x1002, 0x0920)] == struct.pack("<qI", 300 - 0xF53C8065EC, 300)
    assert report.slaves[0].offset_ns == -0xF53C620F52
    assert report.slaves[1].offset_ns is None  # no system time: nothing written
    # loop reset: filter depths (0 and 12), then the speed counter start 0x1000
    reset = bus.sent[3]
    assert [(d.command, d.ado, bytes(d.data)) for d in reset] == [
        (Command.BWR, 0x0934, b"\x00\x0c"), (Command.BWR, 0x0930, b"\x00\x10")]
    # static compensation: 1000 FRMW of the reference's 0x0910, many per frame
    frmw = [d for batch in bus.sent for d in batch if d.command == Command.FRMW]
    assert len(frmw) == 1000
    assert {(d.adp, d.ado, len(d.data)) for d in frmw} == {(0x1000, 0x0910, 8)}
    per_frame = MAX_PAYLOAD // 20
    assert report.static_frames == -(-1000 // per_frame) and report.static_frames <= 14
    # check: 0x092C of the slaves that follow, by magnitude
    assert [s.difference_ns for s in report.slaves] == [0, None, 35]
    assert report.worst_difference_ns == 35 and not report.unsynchronised
    assert report.warnings == []


def test_setup_reports_slaves_still_off_after_compensation() -> None:
    bus = Bus({0x1000: 0, 0x1002: 25_000})
    report = run_dc_setup(bus, SLAVES, DcSettings(static_sync=10), master_time=lambda: 0)
    assert [s.position for s in report.unsynchronised] == [2]
    assert "25000 ns" in report.warnings[0]


def test_32bit_slave_gets_two_writes() -> None:
    slaves = [SLAVES[0], SLAVES[1], DcSlaveInfo(2, 0x1002, R.Feature.DC_SUPPORTED, frozenset({0}))]
    bus = Bus()
    report = run_dc_setup(bus, slaves, DcSettings(static_sync=0), master_time=lambda: 0)
    writes = bus.sent[2]
    assert [(d.adp, d.ado, len(d.data)) for d in writes] == [
        (0x1000, 0x0920, 12), (0x1002, 0x0920, 4), (0x1002, 0x0928, 4)]
    # the low double word of -0x0918 (+ delay) as a 32-bit value
    assert bus.written[(0x1002, 0x0920)] == struct.pack("<I", (300 - 0xF53C8065EC) & 0xFFFFFFFF)
    assert report.slaves[2].kind == "32-bit"
    assert not any(d.command == Command.FRMW for b in bus.sent for d in b)


def test_named_reference_and_errors() -> None:
    with pytest.raises(ConfigError, match="slave 1 has no DC system time"):
        run_dc_setup(Bus(), SLAVES, DcSettings(reference=1, static_sync=0), master_time=lambda: 0)
    # naming the last slave: the EK1100 with a system time would be passed before it
    with pytest.raises(ConfigError, match="passed before the reference"):
        run_dc_setup(Bus(), SLAVES, DcSettings(reference=2, static_sync=0), master_time=lambda: 0)
    with pytest.raises(DcError, match="no DC found"):
        DcSetup([DcSlaveInfo(0, 0x1000, 0, frozenset({0}))])
    setup = DcSetup(SLAVES)
    with pytest.raises(ConfigError):
        setup.receive([])
    setup.next_request(0)
    with pytest.raises(ConfigError):
        setup.next_request(0)


def test_sync_config_writes_order_and_values() -> None:
    s = SyncSettings(0x0700, 1_000_000, shift0=20_000, cycle1=250_000)
    start = s.start_time(5_123_456_789)
    assert start == 5_224_000_000 + 20_000
    writes = sync_config_writes(s, start)
    assert writes == [
        (R.DC_CYCLIC_UNIT_CONTROL, b"\x00\x00"),
        (R.DC_SYNC0_CYCLE, struct.pack("<II", 1_000_000, 250_000)),
        (R.DC_START_TIME, struct.pack("<Q", start)),
        (R.DC_CYCLIC_UNIT_CONTROL, b"\x00\x07"),
    ]
    assert sync_config_writes(s, start, dc_64bit=False)[2] == (R.DC_START_TIME,
                                                                struct.pack("<I", start & 0xFFFFFFFF))
    # no pulses asked for: the unit is only switched off
    assert sync_config_writes(SyncSettings(0, 0)) == [(R.DC_CYCLIC_UNIT_CONTROL, b"\x00\x00")]
    # SYNC1 every 3rd cycle: the start grid is the SYNC1 period
    s3 = SyncSettings(0x0700, 1_000_000, cycle1=2_000_000)
    assert s3.grid == 3_000_000 and s3.start_time(0) % 3_000_000 == 0


@pytest.mark.parametrize("shift", [-1, 1_000_000, 1_500_000])
def test_a_shift_outside_the_cycle_is_refused(shift: int) -> None:
    with pytest.raises(ConfigError, match=f"SYNC0 shift {shift} ns must lie within the cycle"):
        SyncSettings(0x0300, 1_000_000, shift0=shift)
    assert SyncSettings(0x0300, 1_000_000, shift0=999_999).start_time(0) == 101_000_000 + 999_999
    assert SyncSettings(0x0300, 0, shift0=5_000).shift0 == 5_000  # single shot: any delay


def test_trace_of_the_compensation() -> None:
    bus = Bus()
    report = run_dc_setup(bus, SLAVES, DcSettings(static_sync=1500, trace_every=592),
                          master_time=lambda: 7)
    # FRMW go out in chunks of 2 frames (148 datagrams): a snapshot after 592, 1184 and at the end
    assert [(t, n) for t, n, _ in report.trace] == [(7, 592), (7, 1184), (7, 1500)]
    assert report.trace[0][2] == (0, 35)
