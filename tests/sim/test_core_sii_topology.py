"""SII interface, ports and topology, error counters, faults, DC registers."""

from __future__ import annotations

import struct

from simhelp import address_all, fprd, fpwr, line, make_sii, one, spec, u16, xfer

from pyethercat.clock import VirtualClock
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.segment import Segment, SimSlaveSpec
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame
from pyethercat.wire.sii import parse_sii, sii_crc

ST = 0x1000


def sii_cmd(seg: Segment, command: int, word: int) -> int:
    """Start an SII command and read the status once the EEPROM is done with it
    (7 ms of segment time cover any profile's read, write and write cycle)."""
    fpwr(seg, ST, R.SII_CONTROL, struct.pack("<HI", command, word))
    seg.clock.advance(7_000_000)  # type: ignore[attr-defined]
    return u16(fprd(seg, ST, R.SII_CONTROL, 2))


# --- SII --------------------------------------------------------------------------------------


def test_sii_read_8_and_4_bytes() -> None:
    seg = Segment()
    seg.add_slave(spec("a", product=0xCAFE))
    address_all(seg)
    image = seg.slaves[0].esc.sii
    status = sii_cmd(seg, R.SiiControl.CMD_READ, 0x08)
    assert status & R.SiiControl.READ_8_BYTES and not status & R.SiiControl.BUSY
    assert fprd(seg, ST, R.SII_DATA, 8).data == bytes(image[16:24])
    assert struct.unpack_from("<I", fprd(seg, ST, R.SII_DATA + 4, 4).data)[0] == 0xCAFE
    seg4 = Segment()
    seg4.add_slave(spec("b", profile="LAN9252"))
    address_all(seg4)
    status = sii_cmd(seg4, R.SiiControl.CMD_READ, 0x08)
    assert not status & R.SiiControl.READ_8_BYTES
    assert fprd(seg4, ST, R.SII_DATA, 8).data[4:] == bytes(4)
    # beyond the image: erased EEPROM
    sii_cmd(seg, R.SiiControl.CMD_READ, 0x7FF0)
    assert fprd(seg, ST, R.SII_DATA, 8).data == b"\xff" * 8


def test_sii_write_needs_write_enable_and_reload_applies_alias() -> None:
    seg = Segment()
    seg.add_slave(spec("a"))
    address_all(seg)
    fpwr(seg, ST, R.SII_DATA, struct.pack("<H", 0x0123))
    status = sii_cmd(seg, R.SiiControl.CMD_WRITE, 4)
    assert status & R.SiiControl.WRITE_ENABLE_ERROR
    status = sii_cmd(seg, 0, 0)  # NOP clears the error bits
    assert not status & R.SiiControl.WRITE_ENABLE_ERROR
    status = sii_cmd(seg, R.SiiControl.CMD_WRITE | R.SiiControl.WRITE_ENABLE, 4)
    assert not status & R.SII_ERROR_MASK
    image = seg.slaves[0].esc.sii
    assert image[8:10] == b"\x23\x01"
    # fix the header checksum (word 7) the way a master would after editing word 4
    crc = sii_crc(bytes(image[:14]))
    fpwr(seg, ST, R.SII_DATA, struct.pack("<H", crc))
    sii_cmd(seg, R.SiiControl.CMD_WRITE | R.SiiControl.WRITE_ENABLE, 7)
    assert u16(fprd(seg, ST, R.STATION_ALIAS, 2)) == 0  # not before a reload
    status = sii_cmd(seg, R.SiiControl.CMD_RELOAD, 0)
    assert not status & R.SiiControl.CHECKSUM_ERROR
    assert u16(fprd(seg, ST, R.STATION_ALIAS, 2)) == 0x0123
    # read back through the interface
    sii_cmd(seg, R.SiiControl.CMD_READ, 4)
    assert fprd(seg, ST, R.SII_DATA, 2).data == b"\x23\x01"


def test_sii_checksum_error_at_load_and_ownership_and_busy() -> None:
    image = bytearray(make_sii("bad", alias=0x55))
    image[14] ^= 0xFF
    seg = Segment(VirtualClock(0))
    seg.add_slave(SimSlaveSpec("bad", bytes(image), PROFILES["ET1100"]))
    address_all(seg)
    status = u16(fprd(seg, ST, R.SII_CONTROL, 2))
    assert status & R.SiiControl.CHECKSUM_ERROR
    assert u16(fprd(seg, ST, R.STATION_ALIAS, 2)) == 0
    assert not u16(fprd(seg, ST, R.DL_STATUS, 2)) & R.DlStatus.PDI_OPERATIONAL
    fpwr(seg, ST, R.SII_CONFIG, b"\x01")  # PDI owns the EEPROM
    assert sii_cmd(seg, R.SiiControl.CMD_READ, 0) & R.SiiControl.ACK_ERROR
    fpwr(seg, ST, R.SII_CONFIG, b"\x00")
    sii_cmd(seg, 0, 0)
    seg.sii_busy_ns = 1_000_000
    fpwr(seg, ST, R.SII_CONTROL, struct.pack("<HI", R.SiiControl.CMD_READ, 8))
    seg.clock.advance(900_000)
    assert u16(fprd(seg, ST, R.SII_CONTROL, 2)) & R.SiiControl.BUSY
    seg.clock.advance(200_000)
    assert not u16(fprd(seg, ST, R.SII_CONTROL, 2)) & R.SiiControl.BUSY


def test_alias_from_sii_at_power_up_and_override() -> None:
    seg = Segment()
    seg.add_slave(spec("a", alias_sii=0x0ABC))
    seg.add_slave(spec("b", alias_sii=0x0ABC, alias=0x0DEF))
    assert seg.slaves[0].u16(R.STATION_ALIAS) == 0x0ABC
    assert seg.slaves[1].u16(R.STATION_ALIAS) == 0x0DEF
    assert parse_sii(bytes(seg.slaves[0].esc.sii)).station_alias == 0x0ABC


# --- topology ------------------------------------------------------------------------------


def tree() -> Segment:
    seg = Segment()
    seg.add_slave(spec("coupler", "ET1100"))            # 0
    seg.add_slave(spec("a", "ET1200"))                  # 1 on coupler port 1
    seg.add_slave(spec("branch", "ET1200"), parent=0, port=3)  # 2 on coupler port 3
    seg.add_slave(spec("b", "ET1200"))                  # 3 after a? no: after branch (line order)
    return seg


def test_tree_processing_order_and_dl_status() -> None:
    seg = tree()
    # slave 3 continues the line from slave 2 (the branch)
    route = seg.route.passes.tolist()
    assert route == [0, 2, 3, 1]  # coupler, port 3 branch first, then port 1
    d = one(seg, Datagram.positional(Command.APRD, 1, R.TYPE, 1))
    assert d.data == b"\x12"
    seg.slaves[2].write(R.USER_RAM, b"\x02")
    assert one(seg, Datagram.positional(Command.APRD, 1, R.USER_RAM, 1)).data == b"\x02"
    dl = seg.slaves[0].u16(R.DL_STATUS)
    for p in (0, 1, 3):
        assert dl & R.dl_status_link(p) and dl & R.dl_status_com(p) and not dl & R.dl_status_loop(p)
    assert dl & R.dl_status_loop(2) and not dl & R.dl_status_link(2)
    last = seg.slaves[1].u16(R.DL_STATUS)
    assert last & R.dl_status_loop(1) and not last & R.dl_status_link(1)


def test_break_in_the_middle_closes_loop_and_counts_lost_link() -> None:
    seg = line(4, profile="ET1200")
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 4
    seg.break_link(1, 1)
    d = one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1))
    assert d.wkc == 2 and d.adp == 2
    s1 = seg.slaves[1]
    assert s1.u16(R.DL_STATUS) & R.dl_status_loop(1)
    assert s1.read(R.LOST_LINK_COUNTER + 1, 1) == b"\x01"
    # DL status change is an ECAT event; masked in, it shows in the IRQ field
    one(seg, Datagram.device(Command.BWR, 0, R.ECAT_EVENT_MASK, struct.pack("<H", R.EcatEvent.DL_STATUS)))
    assert one(seg, Datagram.device(Command.NOP, 0, 0, 1)).irq & R.EcatEvent.DL_STATUS
    seg.restore_link(1, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 4
    # clearing the lost-link counters (write to the group)
    one(seg, Datagram.device(Command.BWR, 0, R.LOST_LINK_COUNTER, bytes(4)))
    assert s1.read(R.LOST_LINK_COUNTER + 1, 1) == b"\x00"


def test_break_in_tree_branch_keeps_the_rest() -> None:
    seg = tree()
    seg.break_link(0, 3)
    assert seg.route.passes.tolist() == [0, 1]
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 2


def test_loop_control_open_loses_frames_closed_cuts_off() -> None:
    seg = line(3, profile="ET1200")
    # last slave: port 1 forced open with no link -> the frame is lost
    one(seg, Datagram.positional(Command.APWR, 2, R.DL_CONTROL_LOOP, bytes([R.LoopControl.OPEN << 2])))
    assert seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
    one_slave_fix = Segment()
    del one_slave_fix
    seg.slaves[2].write(R.DL_CONTROL_LOOP, b"\x00")
    seg.state.topology_dirty = True
    # first slave: port 1 forced closed -> only it answers
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, bytes([R.LoopControl.CLOSED << 2])))
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1


def test_auto_close_stays_closed_after_link_loss_until_rewritten() -> None:
    seg = line(2, profile="ET1200")
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, bytes([R.LoopControl.AUTO_CLOSE << 2])))
    seg.break_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    seg.restore_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP, bytes([R.LoopControl.AUTO_CLOSE << 2])))
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 2


def test_crc_error_counters_localise_the_fault() -> None:
    seg = line(4, profile="ET1200")
    seg.corrupt_frames(2, 0, count=1)
    assert seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
    counters = [s.read(R.RX_ERROR_COUNTER, 12) for s in seg.slaves]
    assert counters[2][0] == 1  # invalid frame counter port 0 of the slave behind the bad link
    assert counters[3][8] == 1  # forwarded error counter port 0 of the next one
    assert counters[2][9] == 1 and counters[1][9] == 1 and counters[0][9] == 1  # return path
    assert counters[0][0] == 0 and counters[1][0] == 0
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 4  # only one frame hit
    one(seg, Datagram.device(Command.BWR, 0, R.RX_ERROR_COUNTER, bytes(8)))
    assert seg.slaves[2].read(R.RX_ERROR_COUNTER, 1) == b"\x00"


def test_power_off_on_and_drop() -> None:
    seg = line(3, profile="ET1200")
    address_all(seg)
    fpwr(seg, 0x1001, R.AL_CONTROL, struct.pack("<H", AlState.PREOP))
    seg.power_off(1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 1
    seg.power_on(1)
    assert one(seg, Datagram.device(Command.BRD, 0, 0, 1)).wkc == 3
    assert seg.slaves[1].u16(R.STATION_ADDRESS) == 0
    assert seg.slaves[1].al_state == AlState.INIT
    seg.drop_probability(1.0)
    assert seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) is None
    seg.drop_probability(0.5, seed=1)
    results = [seg.process(encode_frame([Datagram.device(Command.BRD, 0, 0, 1)])) for _ in range(40)]
    assert 5 < sum(r is None for r in results) < 35


# --- DC ---------------------------------------------------------------------------------------


def test_receive_time_latch_and_system_time() -> None:
    seg = Segment(VirtualClock(10_000_000))
    for i in range(3):
        seg.add_slave(spec(f"s{i}", "ET1100"), cable_delay_ns=5)
    address_all(seg)
    one(seg, Datagram.device(Command.BWR, 0, R.DC_RECEIVE_TIME_PORT0, bytes(4)))
    t = [struct.unpack("<IIII", fprd(seg, 0x1000 + i, R.DC_RECEIVE_TIME_PORT0, 16).data) for i in range(3)]
    # port 1 time - port 0 time = round trip through the slaves behind: a pass
    # through a chip with MII ports takes 700 ns, each cable 5 ns
    assert t[1][1] - t[1][0] == 700 + 5 + 700 + 5
    assert t[0][1] - t[0][0] == 700 + 5 + (700 + 5 + 700 + 5) + 700 + 5
    assert t[2][1] == 0  # port 1 of the last slave was not visited
    # latches count in 10 ns ticks
    assert all(v % 10 == 0 for v in t[0] + t[1] + t[2])
    epu = [struct.unpack("<q", fprd(seg, 0x1000 + i, R.DC_RECEIVE_TIME_ECAT, 8).data)[0] for i in range(3)]
    # the processing unit is passed half-way through the chip, one link (705 ns) apart
    assert abs(epu[1] - epu[0] - 705) < 10 and abs(epu[2] - epu[1] - 705) < 10
    # system time = local time + offset
    before = struct.unpack("<q", fprd(seg, 0x1002, R.DC_SYSTEM_TIME, 8).data)[0]
    fpwr(seg, 0x1002, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", 1_000_000_000))
    after = struct.unpack("<q", fprd(seg, 0x1002, R.DC_SYSTEM_TIME, 8).data)[0]
    assert 1_000_000_000 < after - before < 1_000_100_000


def test_drift_and_frmw_distribution() -> None:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("ref", "ET1100"))
    seg.add_slave(spec("fast", "ET1100", drift_ppm=100.0))
    address_all(seg)
    assert isinstance(seg.clock, VirtualClock)
    seg.clock.advance(1_000_000_000)
    ds = xfer(seg, Datagram.device(Command.FPRD, 0x1000, R.DC_SYSTEM_TIME, 8),
              Datagram.device(Command.FPRD, 0x1001, R.DC_SYSTEM_TIME, 8))
    a, b = (struct.unpack("<q", d.data)[0] for d in ds)
    assert 99_000 < b - a < 101_000  # 100 ppm over one second
    # no filtering of the difference (resets the loop too), then one FRMW
    one(seg, Datagram.device(Command.BWR, 0, R.DC_TIME_FILTER_DEPTH, bytes([0, 12])))
    d = one(seg, Datagram.device(Command.FRMW, 0x1000, R.DC_SYSTEM_TIME, 8))
    assert d.wkc == 2
    diff = struct.unpack("<I", fprd(seg, 0x1001, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0]
    assert diff & 0x80000000 and 99_000 < (diff & 0x7FFFFFFF) < 101_000
    # DC registers exist only on DC chips; ET1200 has them, an IP core without DC would not
    nodc = Segment()
    nodc.add_slave(SimSlaveSpec("x", make_sii("x"), PROFILES["ET1100"].replace(features=0)))
    assert one(nodc, Datagram.device(Command.BRD, 0, R.DC_SYSTEM_TIME, 8)).wkc == 0


def test_sync0_events_reach_the_application() -> None:
    from pyethercat.sim.device import DeviceApp

    class App(DeviceApp):
        def __init__(self) -> None:
            super().__init__()
            self.syncs: list[int] = []

        def on_sync0(self, time_ns: int) -> None:
            self.syncs.append(time_ns)

    app = App()
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("s", "ET1100", app=app))
    address_all(seg)
    now = struct.unpack("<q", fprd(seg, ST, R.DC_SYSTEM_TIME, 8).data)[0]
    start = now + 1_000_000
    fpwr(seg, ST, R.DC_SYNC0_CYCLE, struct.pack("<I", 1_000_000))
    fpwr(seg, ST, R.DC_START_TIME, struct.pack("<Q", start))
    fpwr(seg, ST, R.DC_ACTIVATION, bytes([R.DcActivation.CYCLIC | R.DcActivation.SYNC0]))
    assert isinstance(seg.clock, VirtualClock)
    seg.clock.advance(3_500_000)
    seg.tick()
    assert app.syncs[:3] == [start, start + 1_000_000, start + 2_000_000]
    assert fprd(seg, ST, R.DC_SYNC0_STATUS, 1).data == b"\x01"


def test_sync0_of_several_slaves_fires_per_slave_and_stops_when_deactivated() -> None:
    """Each slave's pulses follow its own start time; deactivating one stops only its pulses."""
    from pyethercat.sim.device import DeviceApp

    class App(DeviceApp):
        def __init__(self) -> None:
            super().__init__()
            self.syncs: list[int] = []

        def on_sync0(self, time_ns: int) -> None:
            self.syncs.append(time_ns)

    apps = [App() for _ in range(3)]
    seg = Segment(VirtualClock(0))
    for i, app in enumerate(apps):
        seg.add_slave(spec(f"s{i}", "ET1100", app=app))
    address_all(seg)
    starts = []
    for i in range(3):
        st = ST + i
        now = struct.unpack("<q", fprd(seg, st, R.DC_SYSTEM_TIME, 8).data)[0]
        starts.append(now + (i + 1) * 1_000_000)
        fpwr(seg, st, R.DC_SYNC0_CYCLE, struct.pack("<I", 1_000_000))
        fpwr(seg, st, R.DC_START_TIME, struct.pack("<Q", starts[-1]))
        fpwr(seg, st, R.DC_ACTIVATION, bytes([R.DcActivation.CYCLIC | R.DcActivation.SYNC0]))
    assert isinstance(seg.clock, VirtualClock)
    seg.clock.advance(2_600_000)
    seg.tick()
    assert apps[0].syncs == [starts[0], starts[0] + 1_000_000]
    assert apps[1].syncs == [starts[1]]
    assert apps[2].syncs == []
    fpwr(seg, ST + 1, R.DC_ACTIVATION, b"\x00")
    seg.clock.advance(2_000_000)
    seg.tick()
    assert apps[0].syncs == [starts[0] + k * 1_000_000 for k in range(4)]
    assert apps[1].syncs == [starts[1]]
    assert apps[2].syncs == [starts[2], starts[2] + 1_000_000]


def test_sii_registers_keep_their_values_while_a_command_runs() -> None:
    """0x0502-0x050F are written only when the interface is idle (ET1100
    datasheet section II): a master that does not wait for busy to clear
    cannot change the address of a read in progress or start another."""
    seg = line(1, profile="ET1200")
    seg.sii_busy_ns = 680_000  # the ET1200 datasheet's read time (table 47)
    address_all(seg)
    image = bytes(seg.slaves[0].esc.sii)
    fpwr(seg, ST, R.SII_CONTROL, struct.pack("<HI", R.SiiControl.CMD_READ, 0x08))
    d = fpwr(seg, ST, R.SII_CONTROL, struct.pack("<HI", R.SiiControl.CMD_READ, 0x20))
    assert d.wkc == 1  # the registers exist: the access is counted, the data dropped
    assert struct.unpack("<I", seg.slaves[0].read(R.SII_ADDRESS, 4))[0] == 0x08
    seg.clock.advance(700_000)  # type: ignore[attr-defined]
    assert not u16(fprd(seg, ST, R.SII_CONTROL, 2)) & R.SiiControl.BUSY
    assert fprd(seg, ST, R.SII_DATA, 4).data == image[0x10:0x14]
