"""The simulator's distributed clocks (sim.dc): oscillators, time-control loop, SYNC, latches."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from simhelp import address_all, fprd, fpwr, one, spec

from pyethercat.clock import VirtualClock
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.profiles import PROFILES, EscProfile
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.dc import decode_time_difference
from pyethercat.wire.sii import sii_crc

ST = 0x1000


#: An ET1100 whose DC unit counts 32 bits (no 64-bit feature flag).
NARROW = PROFILES["ET1100"].replace(features=int(R.Feature.DC_SUPPORTED))


def pair(ppm: float, profile: str = "ET1100",
         follower: EscProfile | None = None) -> tuple[Segment, VirtualClock]:
    """A reference and a follower drifting ``ppm`` (its chip ``follower``, else ``profile``)."""
    clock = VirtualClock(0)
    seg = Segment(clock)
    seg.advance_clock = False
    seg.add_slave(spec("ref", profile))
    seg.add_slave(spec("follower", profile if follower is None else follower, drift_ppm=ppm))
    address_all(seg)
    return seg, clock


def compensate(seg: Segment, clock: VirtualClock, cycles: int) -> None:
    """``cycles`` FRMW of the reference's time, one per 1 ms (the master's drift compensation)."""
    for _ in range(cycles):
        clock.advance(1_000_000)
        frmw(seg)


def low_word_gap(a: int, b: int) -> int:
    """|b - a| of two 32-bit system times (the shorter way round)."""
    return abs(((b - a + (1 << 31)) % (1 << 32)) - (1 << 31))


def frmw(seg: Segment, size: int = 8) -> Datagram:
    return one(seg, Datagram.device(Command.FRMW, ST, R.DC_SYSTEM_TIME, size))


def systimes(seg: Segment, size: int = 8) -> list[int]:
    return [int.from_bytes(fprd(seg, ST + i, R.DC_SYSTEM_TIME, size).data, "little")
            for i in range(len(seg.slaves))]


def start_loop(seg: Segment) -> None:
    # no filtering of the difference, speed filter 12; rewriting 0x0930 resets the loop
    one(seg, Datagram.device(Command.BWR, 0, R.DC_TIME_FILTER_DEPTH, bytes([0, 12])))
    one(seg, Datagram.device(Command.BWR, 0, R.DC_SPEED_COUNTER_START, struct.pack("<H", 0x1000)))


@pytest.mark.parametrize("ppm", [150.0, -150.0])
def test_time_control_loop_locks_a_drifting_clock(ppm: float) -> None:
    seg, clock = pair(ppm)
    start_loop(seg)
    compensate(seg, clock, 3000)  # 3 s of drift compensation at 1 kHz
    diff = decode_time_difference(struct.unpack("<I", fprd(seg, ST + 1, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0])
    assert diff <= 20
    # the learned speed correction cancels the quartz (0x0932 in 0.1 ppm)
    learned = struct.unpack("<h", fprd(seg, ST + 1, R.DC_SPEED_COUNTER_DIFF, 2).data)[0]
    assert learned == pytest.approx(-ppm * 10, abs=3)
    # left alone for a second, the corrected clock stays with the reference
    clock.advance(1_000_000_000)
    a, b = systimes(seg)
    assert abs(b - a) < 200
    # writing 0x0930 resets the filters: difference and learned speed gone, the quartz is back
    fpwr(seg, ST + 1, R.DC_SPEED_COUNTER_START, struct.pack("<H", 0x1000))
    assert fprd(seg, ST + 1, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data == bytes(4)
    assert fprd(seg, ST + 1, R.DC_SPEED_COUNTER_DIFF, 2).data == bytes(2)
    clock.advance(1_000_000_000)
    a2, b2 = systimes(seg)
    assert abs((b2 - a2) - (b - a) - ppm * 1000) < 200


def test_loop_correction_is_bounded_by_the_speed_counter_start() -> None:
    seg, clock = pair(150.0)
    start_loop(seg)
    # a small start value: at most (0x0400 - 0x7F) * 0.1 ppm = 89.7 ppm of correction
    fpwr(seg, ST + 1, R.DC_SPEED_COUNTER_START, struct.pack("<H", 0x0400))
    compensate(seg, clock, 2000)
    learned = struct.unpack("<h", fprd(seg, ST + 1, R.DC_SPEED_COUNTER_DIFF, 2).data)[0]
    assert learned == -(0x0400 - 0x7F)
    diff = decode_time_difference(struct.unpack("<I", fprd(seg, ST + 1, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0])
    assert diff > 10_000  # 60 ppm it cannot follow: the difference keeps growing


def test_a_new_delay_written_while_the_loop_runs_moves_the_follower() -> None:
    # The loop reads 0x0928 at every update: a delay written mid-way (a master that
    # measures again after a topology change) is taken at the next FRMW, and the
    # follower settles that much ahead of the reference's time as the frame saw it.
    seg, clock = pair(50.0)
    start_loop(seg)
    compensate(seg, clock, 1500)
    a, b = systimes(seg)
    assert abs(b - a) < 200
    fpwr(seg, ST + 1, R.DC_SYSTEM_TIME_DELAY, struct.pack("<I", 20_000))
    compensate(seg, clock, 3000)
    a, b = systimes(seg)
    assert abs((b - a) - 20_000) < 200


def test_filter_depth_smooths_the_difference() -> None:
    seg, clock = pair(0.0)
    start_loop(seg)
    fpwr(seg, ST + 1, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", 1600))  # 1.6 us ahead
    # the frame passes the follower 705 ns after the reference: its true delay
    fpwr(seg, ST + 1, R.DC_SYSTEM_TIME_DELAY, struct.pack("<I", 705))
    fpwr(seg, ST + 1, R.DC_TIME_FILTER_DEPTH, bytes([4]))  # (resets the loop)
    frmw(seg)
    raw = struct.unpack("<I", fprd(seg, ST + 1, R.DC_SYSTEM_TIME_DIFFERENCE, 4).data)[0]
    assert raw & 0x8000_0000  # local copy ahead: sign bit set
    assert abs(decode_time_difference(raw) - 100) <= 1  # 1/16 of the way to 1600


def test_32bit_follower_compares_low_double_words() -> None:
    seg, clock = pair(80.0, follower=NARROW)
    start_loop(seg)
    # the reference far beyond 2^32 ns: only the low double word reaches the 32-bit slave
    fpwr(seg, ST, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", 7 << 32))
    compensate(seg, clock, 2000)
    a, b = systimes(seg, 4)
    assert low_word_gap(a, b) < 50


def test_a_32bit_chip_put_in_a_64bit_followers_place_compares_low_double_words() -> None:
    # Hot swap while the master keeps the loop running: the loop's settings come back
    # the same, but the new chip counts 32 bits; what was worked out for the old one
    # must not stay in use.
    seg, clock = pair(0.0)
    start_loop(seg)
    fpwr(seg, ST, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", 7 << 32))
    compensate(seg, clock, 100)
    seg.insert_slave(1, spec("narrow", NARROW, drift_ppm=80.0))
    address_all(seg)
    start_loop(seg)  # (the same settings as before the swap)
    # the master sets the new chip's offset, as after a scan: its clock started at power-on
    a, b = systimes(seg, 4)
    fpwr(seg, ST + 1, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", (a - b) % (1 << 32)))
    compensate(seg, clock, 2000)
    a, b = systimes(seg, 4)
    assert low_word_gap(a, b) < 50


class Listener(DeviceApp):
    def __init__(self) -> None:
        super().__init__()
        self.sync0: list[int] = []
        self.sync1: list[int] = []

    def on_sync0(self, time_ns: int) -> None:
        self.sync0.append(time_ns)

    def on_sync1(self, time_ns: int) -> None:
        self.sync1.append(time_ns)


def start_sync(seg: Segment, station: int, start: int, cycle0: int, cycle1: int = 0,
               act: int = 0x03) -> None:
    fpwr(seg, station, R.DC_SYNC0_CYCLE, struct.pack("<II", cycle0, cycle1))
    fpwr(seg, station, R.DC_START_TIME, struct.pack("<Q", start))
    fpwr(seg, station, R.DC_ACTIVATION, bytes([act]))


def test_sync_pulses_are_recorded_with_their_true_time() -> None:
    seg, clock = pair(100.0)
    now = systimes(seg)[1]
    start = now + 1_000_000
    start_sync(seg, ST + 1, start, 250_000)
    assert fprd(seg, ST + 1, R.DC_ACTIVATION_STATUS, 1).data == bytes([R.DcActivationStatus.SYNC0_PENDING])
    clock.advance(2_100_000)
    seg.tick()
    sys_, true = seg.dc.sync.recorded_pulses()
    assert int(seg.dc.sync.pulses[1]) == 5  # start, +250, +500, +750, +1000 us
    last = seg.dc.sync.last_sync0()[1]
    assert last is not None and last[0] == start + 1_000_000
    # 100 ppm fast: the pulse at local +2 ms came 200 ns early in true time
    t_local_origin = float(seg.dc.t0[1])
    assert last[1] == pytest.approx(t_local_origin + (last[0] - seg.dc.local0[1]
                                                      - struct.unpack("<q", fprd(seg, ST + 1, R.DC_SYSTEM_TIME_OFFSET, 8).data)[0])
                                    / 1.0001, abs=10)
    assert fprd(seg, ST + 1, R.DC_SYNC0_STATUS, 1).data == b"\x01"
    assert fprd(seg, ST + 1, R.DC_ACTIVATION_STATUS, 1).data == b"\x00"
    report = seg.dc_report()[1]
    assert report["sync0_pulses"] == 5 and report["drift_ppm"] == pytest.approx(100.0)
    assert np.count_nonzero(~np.isnan(true[1])) == 5 and sys_[1, 0] == start


def test_single_shot_sync1_multiple_and_a_start_in_the_past() -> None:
    clock = VirtualClock(0)
    seg = Segment(clock)
    seg.advance_clock = False
    apps = [Listener(), Listener(), Listener()]
    for i, app in enumerate(apps):
        seg.add_slave(spec(f"s{i}", "ET1100", app=app))
    address_all(seg)
    now = systimes(seg)
    start_sync(seg, ST, now[0] + 100_000, 0)  # cycle 0: one pulse
    # SYNC1 every 3rd SYNC0 cycle, 20 us after it (0x09A4 = 2 cycles + 20 us)
    start_sync(seg, ST + 1, now[1] + 100_000, 100_000, 220_000, act=0x07)
    start_sync(seg, ST + 2, now[2] - 1_000, 100_000)  # already past: never reached
    clock.advance(1_000_000)
    seg.tick()
    assert apps[0].sync0 == [now[0] + 100_000] and 0 not in seg.dc.sync.sync_next
    s0 = apps[1].sync0
    assert s0 == [now[1] + 100_000 * k for k in range(1, 10)]
    assert apps[1].sync1 == [s0[k] + 220_000 for k in (0, 3, 6)]
    assert apps[2].sync0 == []
    assert fprd(seg, ST + 2, R.DC_ACTIVATION_STATUS, 1).data == bytes([R.DcActivationStatus.SYNC0_PENDING])


def sync_status(seg: Segment) -> tuple[int, int]:
    """(0x098E, 0x098F) of the follower as the master reads them (FPRD)."""
    data = fprd(seg, ST + 1, R.DC_SYNC0_STATUS, 2).data
    return data[0], data[1]


def test_sync_status_shows_each_pulse_for_the_pulse_length() -> None:
    """0x0982 = 1000 (10 us, from SII word 2): SYNC0 and SYNC1 status are set that long."""
    seg, clock = pair(0.0)
    # the firmware's EEPROM says 10 us; the master reloads it into the registers
    eeprom = seg.escs[1].eeprom
    head = bytearray(eeprom.image[:14])
    head[4:6] = struct.pack("<H", 1000)
    eeprom.firmware_write(0, bytes(head) + bytes([sii_crc(bytes(head)), 0]))
    fpwr(seg, ST + 1, R.SII_CONTROL, struct.pack("<H", R.SiiControl.CMD_RELOAD))
    assert fprd(seg, ST + 1, R.DC_SYNC_PULSE_LENGTH, 2).data == struct.pack("<H", 1000)
    # (drift 0 and a frame that passes within a microsecond: system time = clock + now)
    now = systimes(seg)[1]
    start = now + 1_000_000
    start_sync(seg, ST + 1, start, 250_000, 50_000, act=0x07)  # SYNC1 50 us after SYNC0

    def at(us: float) -> tuple[int, int]:
        clock.set(1_000_000 + int(us * 1000))
        return sync_status(seg)

    def brd_at(us: float) -> bytes:
        clock.set(1_000_000 + int(us * 1000))
        brd = one(seg, Datagram.device(Command.BRD, 0, R.DC_SYNC0_STATUS, 2))
        assert brd.wkc == 2
        return brd.data

    assert at(-5) == (0, 0)
    assert at(3) == (1, 0)       # SYNC0 on
    assert brd_at(19) == b"\x00\x00"  # 10 us later it is off again (a broadcast read too)
    assert at(20) == (0, 0)
    assert brd_at(52) == b"\x00\x01"
    assert at(53) == (0, 1)      # SYNC1
    assert at(70) == (0, 0)
    assert at(253) == (1, 0)     # the next cycle
    assert at(306) == (0, 1)
    # an EtherCAT read does not acknowledge anything: the next pulse shows again
    assert at(503) == (1, 0) and at(505) == (1, 0)


def test_sync_status_in_acknowledge_mode_stays_until_the_pdi_reads_it() -> None:
    """0x0982 = 0: a pulse sets the status until the PDI reads it; EtherCAT reads leave it."""
    seg, clock = pair(0.0)
    assert fprd(seg, ST + 1, R.DC_SYNC_PULSE_LENGTH, 2).data == b"\x00\x00"
    pdi = seg.escs[1].pdi
    now = systimes(seg)[1]
    start = now + 1_000_000
    # SYNC1 every 3rd SYNC0 cycle, 20 us after it: 0x09A4 = 2 cycles + 20 us
    start_sync(seg, ST + 1, start, 250_000, 520_000, act=0x07)

    def go(us: float) -> None:
        clock.set(1_000_000 + int(us * 1000))
        seg.tick()

    go(100)
    assert sync_status(seg) == (1, 0)
    go(240)
    assert sync_status(seg) == (1, 0)          # still set: nobody acknowledged
    assert pdi.read(R.DC_SYNC0_STATUS, 1) == b"\x01"  # the firmware reads it ...
    assert pdi.read(R.DC_SYNC0_STATUS, 1) == b"\x00"  # ... and so acknowledges it
    assert sync_status(seg) == (0, 0)
    go(260)
    assert pdi.read(R.DC_SYNC0_STATUS, 2) == b"\x01\x00"  # the next pulse; SYNC1 not yet
    go(510)
    assert pdi.read(R.DC_SYNC1_STATUS, 1) == b"\x00"  # SYNC1 comes at 520 us
    go(530)
    assert sync_status(seg) == (1, 1)
    assert pdi.read(R.DC_SYNC1_STATUS, 1) == b"\x01"  # acknowledges SYNC1 only
    assert sync_status(seg) == (1, 0)
    go(1260)
    assert pdi.read(R.DC_SYNC0_STATUS, 2) == b"\x01\x00"  # the next SYNC1: at 750 + 520 us
    go(1280)
    assert pdi.read(R.DC_SYNC0_STATUS, 2) == b"\x00\x01"
    assert pdi.read(R.DC_SYNC0_STATUS, 2) == b"\x00\x00"


def test_latch_inputs_stamp_system_time() -> None:
    seg, clock = pair(0.0)
    clock.advance(5_000)
    t = clock.now_ns()
    st = int(seg.dc.system_time(np.array([1]), t)[0])
    seg.latch_input(1, 0, True, t)
    assert fprd(seg, ST + 1, R.DC_LATCH0_STATUS, 1).data[0] & R.DcLatchStatus.POSITIVE_EDGE
    stamp = struct.unpack("<Q", fprd(seg, ST + 1, R.DC_LATCH0_POSITIVE, 8).data)[0]
    assert abs(stamp - st) <= 10
    # single-event mode for falling edges of unit 1: the first edge stays
    fpwr(seg, ST + 1, R.DC_LATCH1_CONTROL, bytes([R.DC_LATCH_CONTROL_NEGATIVE_SINGLE]))
    seg.latch_input(1, 1, False, t + 1000)
    seg.latch_input(1, 1, False, t + 9000)
    first = struct.unpack("<Q", fprd(seg, ST + 1, R.DC_LATCH1_NEGATIVE, 8).data)[0]
    assert abs(first - (st + 1000)) <= 10
    # writing the control again clears the stored event
    fpwr(seg, ST + 1, R.DC_LATCH1_CONTROL, bytes([R.DC_LATCH_CONTROL_NEGATIVE_SINGLE]))
    assert fprd(seg, ST + 1, R.DC_LATCH1_STATUS, 1).data[0] & R.DcLatchStatus.NEGATIVE_EDGE == 0


class TouchProbe(DeviceApp):
    """A device whose sensor drives the ESC's LATCH0 pin: it reports edges through its PDI."""

    def edge(self, rising: bool, t_ns: int | None = None) -> None:
        assert self.pdi is not None
        self.pdi.latch_input(0, rising, t_ns)


def test_a_device_application_stamps_latch_edges_through_its_pdi() -> None:
    clock = VirtualClock(0)
    seg = Segment(clock)
    seg.advance_clock = False
    probe = TouchProbe()
    seg.add_slave(spec("ref", "ET1100"))
    seg.add_slave(spec("probe", "ET1100", app=probe, drift_ppm=50.0))
    address_all(seg)
    fpwr(seg, ST + 1, R.DC_SYSTEM_TIME_OFFSET, struct.pack("<q", 3_000_000_000))
    clock.advance(7_000)
    now = clock.now_ns()
    expect = int(seg.dc.system_time(np.array([1]), now)[0])
    probe.edge(True)  # now
    status = fprd(seg, ST + 1, R.DC_LATCH0_STATUS, 1).data[0]
    assert status == R.DcLatchStatus.POSITIVE_EDGE | R.DcLatchStatus.PIN_STATE
    stamp = struct.unpack("<Q", fprd(seg, ST + 1, R.DC_LATCH0_POSITIVE, 8).data)[0]
    assert stamp == expect and stamp > 3_000_000_000  # system time: local + 0x0920
    # a falling edge at a given moment, 12.5 us later: the pin reads low again
    probe.edge(False, now + 12_500)
    status = fprd(seg, ST + 1, R.DC_LATCH0_STATUS, 1).data[0]
    assert status == R.DcLatchStatus.POSITIVE_EDGE | R.DcLatchStatus.NEGATIVE_EDGE
    fall = struct.unpack("<Q", fprd(seg, ST + 1, R.DC_LATCH0_NEGATIVE, 8).data)[0]
    assert abs((fall - stamp) - 12_500 * 1.00005) <= 10  # on the probe's 50 ppm fast clock
    assert probe.pdi is not None
    with pytest.raises(ValueError, match="latch unit 2"):
        probe.pdi.latch_input(2, True)


def test_a_latch_input_needs_distributed_clocks() -> None:
    clock = VirtualClock(0)
    seg = Segment(clock)
    probe = TouchProbe()
    no_dc = PROFILES["ET1100"].replace(features=0)
    seg.add_slave(spec("plain", no_dc, app=probe))
    with pytest.raises(ValueError, match="no distributed clocks"):
        probe.edge(True)


def test_control_channel_sets_drift_and_latches(tmp_path: Path) -> None:
    """``set_drift`` and ``latch`` over a running simulator's control socket; read back by a master."""
    import json
    import socket
    import threading

    from pyethercat.link.udp import UdpLink
    from pyethercat.master.master import Master
    from pyethercat.sim.server import SimServer

    seg = parse_topology('[segment]\ndrift_ppm = 0.0\n'
                         '[[slave]]\nname = "coupler"\ndevice = "builtin:coupler"\n'
                         '[[slave]]\nname = "di8"\ndevice = "builtin:di8"\n').build()
    link = UdpLink(bind=("127.0.0.1", 0))
    ctl = tmp_path / "ctl.sock"
    srv = SimServer(seg, link, control=ctl)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    host, port = link.address
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    client.settimeout(10)
    reader = client.makefile("rb")

    def control(**request: object) -> dict[str, object]:
        client.sendall(json.dumps(request).encode() + b"\n")
        answer: dict[str, object] = json.loads(reader.readline())
        assert answer.get("ok"), answer
        return answer

    m = Master(UdpLink(peer=(host, port)))
    try:
        client.connect(str(ctl))
        m.scan()
        control(cmd="set_drift", slave="di8", ppm=-37.5)
        slaves = control(cmd="dc")["slaves"]
        assert isinstance(slaves, list)
        assert [s["drift_ppm"] for s in slaves] == [0.0, pytest.approx(-37.5)]
        di8 = m.slaves[1]
        before = struct.unpack("<Q", m.read(di8, R.DC_SYSTEM_TIME, 8))[0]
        control(cmd="latch", slave="di8", unit=1, rising=False)
        after = struct.unpack("<Q", m.read(di8, R.DC_SYSTEM_TIME, 8))[0]
        assert m.read(di8, R.DC_LATCH1_STATUS, 1)[0] == R.DcLatchStatus.NEGATIVE_EDGE
        stamp = struct.unpack("<Q", m.read(di8, R.DC_LATCH1_NEGATIVE, 8))[0]
        assert before <= stamp <= after  # stamped with the slave's time when it came
        assert m.read(di8, R.DC_LATCH0_STATUS, 1) == b"\x00"  # the other unit saw nothing
    finally:
        m.close()
        client.close()
        srv.stop()
        thread.join(5)
        srv.close()
        link.close()


def test_topology_drift_defaults_to_random_within_100ppm_with_a_seed() -> None:
    text = "".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:di8"\n' for i in range(30))
    a = parse_topology(text).build().dc_report()
    b = parse_topology(text).build().dc_report()
    drifts = [s["drift_ppm"] for s in a]
    assert drifts == [s["drift_ppm"] for s in b]  # the same seed, the same oscillators
    assert all(abs(d) <= 100.0 for d in drifts) and max(drifts) - min(drifts) > 100
    c = parse_topology("[segment]\ndrift_seed = 3\n" + text).build().dc_report()
    assert [s["drift_ppm"] for s in c] != drifts
    exact = parse_topology("[segment]\ndrift_ppm = 0.0\n" + text).build().dc_report()
    assert {s["drift_ppm"] for s in exact} == {0.0}
    seg = parse_topology("[segment]\ndrift_ppm = 0.0\n" + text).build()
    seg.set_drift(4, 20.0)
    assert seg.dc_report()[4]["drift_ppm"] == pytest.approx(20.0)


@settings(max_examples=300, deadline=None)
@given(local0=st.floats(0, 2**62), rate=st.floats(0.999, 1.001), trim=st.floats(-4e-4, 4e-4),
       until=st.floats(0, 1e9), learned=st.floats(-4e-4, 4e-4), t0=st.integers(0, 2**60),
       ahead=st.integers(-10**6, 10**12), offset=st.integers(-2**63, 2**63 - 1), wide=st.booleans())
def test_one_slaves_system_time_read_is_the_array_paths_bit_for_bit(
        local0: float, rate: float, trim: float, until: float, learned: float, t0: int,
        ahead: int, offset: int, wide: bool) -> None:
    # The reference's 0x0910 read (every FRMW) takes a path in Python floats; it must
    # give what the array path gives for any clock state, 32-bit chips and wrap included.
    seg, _ = pair(0.0)
    dc = seg.dc
    dc.local0[1], dc.rate[1], dc.trim[1], dc.until[1], dc.learned[1] = local0, rate, trim, until, learned
    dc.t0[1] = t0
    dc.frame_t0 = t0 + ahead
    dc.words()[1, R.DC_SYSTEM_TIME_OFFSET // 8] = offset
    dc.wide[1] = wide
    dc._narrow = not wide  # (what add_slave works out for a 32-bit chip)
    one_path = dc.refresh_one(1)
    array_path = int(dc.refresh_system_time(np.array([1], np.int64))[0])
    assert one_path == array_path
