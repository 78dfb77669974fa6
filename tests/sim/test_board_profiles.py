"""Board profiles of the real corpus devices: what the real EK1100/EL2828/EL2889 read.

Each expectation is a reply the real slaves gave in the corpus captures
(../shared/corpus/pcap, see docs/simulator.md "ESC profiles").
"""

from __future__ import annotations

import struct
from pathlib import Path

from simhelp import address_all, fprd, fpwr, one, u16

from pyethercat.clock import VirtualClock
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram


def _bench(corpus_dir: Path) -> tuple[Segment, VirtualClock]:
    toml = "".join(
        f'[[slave]]\nname = "{d}"\nsii = "{corpus_dir / "sii" / f"ethercrab_{d}.bin"}"\n'
        for d in ("ek1100", "el2828", "el2889")
    )
    topo = parse_topology(toml)
    assert [s.profile.name for s in topo.slaves] == ["EK1100", "EL2828", "EL2889"]
    clock = VirtualClock(1_000_000_000)
    seg = topo.build(clock=clock)
    seg.advance_clock = False
    address_all(seg)
    return seg, clock


def test_identity_and_dc_units(corpus_dir: Path) -> None:
    seg, _ = _bench(corpus_dir)
    # twincat-scan-boxes: the EK1100's 0x0000-0x0009
    assert bytes(fprd(seg, 0x1000, 0x0000, 10).data) == bytes.fromhex("110003000808083bfc00")
    assert u16(fprd(seg, 0x1001, R.FEATURES, 2)) == 0x01FC
    assert u16(fprd(seg, 0x1002, R.FEATURES, 2)) == 0x00FC
    assert one(seg, Datagram(Command.BRD, 0, 0, b"\0")).data == b"\x13"
    # FMMUs 3.. and SMs 4.. exist on the EK1100 only
    assert one(seg, Datagram(Command.BWR, 0, R.fmmu_address(3) << 16, bytes(16))).wkc == 1
    assert one(seg, Datagram(Command.BWR, 0, R.sm_address(4) << 16, bytes(8))).wkc == 1
    # the EL2828 latches receive times but has no system time
    assert one(seg, Datagram(Command.BWR, 0, R.DC_RECEIVE_TIME_PORT0 << 16, bytes(4))).wkc == 3
    assert one(seg, Datagram(Command.BWR, 0, R.DC_SYSTEM_TIME << 16, bytes(8))).wkc == 2
    assert fprd(seg, 0x1001, R.DC_RECEIVE_TIME_ECAT, 8).wkc == 0
    frmw = one(seg, Datagram.device(Command.FRMW, 0x1000, R.DC_SYSTEM_TIME, 8))
    assert frmw.wkc == 2
    # the last slave's port 1 never latched: "hoff"; port 3 "Verl"
    latches = bytes(fprd(seg, 0x1002, R.DC_RECEIVE_TIME_PORT0, 16).data)
    assert latches[4:] == b"hoff" + bytes(4) + b"Verl"


def test_al_dl_and_sii_status(corpus_dir: Path) -> None:
    seg, _ = _bench(corpus_dir)
    # device emulation copies AL control bits 4:0, the acknowledge bit included
    assert one(seg, Datagram(Command.BWR, 0, R.AL_CONTROL << 16, b"\x11\x00")).wkc == 3
    assert [u16(fprd(seg, 0x1000 + i, R.AL_STATUS, 2)) for i in range(3)] == [0x11, 0x11, 0x11]
    # DL status bit 1 (PDI watchdog): EK1100 without PDI 0, EL28xx 1
    assert [u16(fprd(seg, 0x1000 + i, R.DL_STATUS, 2)) & 2 for i in range(3)] == [0, 2, 2]
    # SII control idle: EL2828 0x0050 below SAFEOP, 0x0040 from SAFEOP on
    assert [u16(fprd(seg, 0x1000 + i, R.SII_CONTROL, 2)) for i in range(3)] == [0x40, 0x50, 0x40]
    fpwr(seg, 0x1001, R.AL_CONTROL, struct.pack("<H", 4))
    assert u16(fprd(seg, 0x1001, R.AL_STATUS, 2)) == 4
    assert u16(fprd(seg, 0x1001, R.SII_CONTROL, 2)) == 0x40


def test_eeprom_timing_and_write_cycle(corpus_dir: Path) -> None:
    seg, clock = _bench(corpus_dir)
    ek = 0x1000
    fpwr(seg, ek, R.SII_CONTROL, struct.pack("<HI", 0x0100, 8))  # read word 8
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x8140  # busy + read command
    clock.advance(700_000)
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x0040
    # replay-ek1100-alias-address: write word 4, then word 7 1.2 ms later
    fpwr(seg, ek, R.SII_DATA, b"\xcd\xab")
    fpwr(seg, ek, R.SII_CONTROL, struct.pack("<HI", 0x0201, 4))
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x8240  # busy, write enable spent
    clock.advance(1_200_000)
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x0040
    fpwr(seg, ek, R.SII_DATA, b"\x52\x00")
    fpwr(seg, ek, R.SII_CONTROL, struct.pack("<HI", 0x0201, 7))
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x2040  # not acknowledged
    clock.advance(2_500_000)
    fpwr(seg, ek, R.SII_CONTROL, struct.pack("<HI", 0x0201, 7))
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x8240
    clock.advance(300_000)
    assert u16(fprd(seg, ek, R.SII_CONTROL, 2)) == 0x0040
    esc = seg.slaves[0].esc
    assert bytes(esc.sii[8:10]) == b"\xcd\xab" and bytes(esc.sii[14:16]) == b"\x52\x00"
