"""The simulated CiA 402 drive (builtin:seed002-drive) driven frame by frame, without DC.

Every test talks to the drive as a master does: SDOs through the mailbox,
process data through SM2/SM3, AL control. Without SYNC0 the drive runs one
cycle per output buffer (SM synchronous mode, 1 ms of virtual time apart),
and warns with statusword bit 7 that it has no hardware sync (the manual's
warning 63-3).
"""

from __future__ import annotations

import struct

import pytest
from coehelp import SM2, SM3, CoeSlave

from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.cia402 import DriveState, decode_state
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import Emergency
from pyethercat.wire.mailbox.header import MailboxType

# RxPDO: controlword, mode, target position, target velocity, target torque (13 bytes)
RX = [0x60400010, 0x60600008, 0x607A0020, 0x60FF0020, 0x60710010]
RX_FMT = "<Hbiih"
# TxPDO: statusword, mode display, position, velocity, torque, following error, error code
TX = [0x60410010, 0x60610008, 0x60640020, 0x606C0020, 0x60770010, 0x60F40020, 0x603F0010]
TX_FMT = "<HbiihiH"
OUT_LEN, IN_LEN = struct.calcsize(RX_FMT), struct.calcsize(TX_FMT)
WARN = 0x0080  # no SYNC0: the drive synchronises on the frames and says so


def u8(v: int) -> bytes:
    return bytes([v])


def u16(v: int) -> bytes:
    return struct.pack("<H", v)


def i16(v: int) -> bytes:
    return struct.pack("<h", v)


def u32(v: int) -> bytes:
    return struct.pack("<I", v)


def i32(v: int) -> bytes:
    return struct.pack("<i", v)


class Drive:
    """One drive in OP with the test mapping; ``cycle`` sends outputs and returns inputs."""

    def __init__(self, mapped: bool = True) -> None:
        self.s = CoeSlave("seed002-drive", serial=1)
        if not mapped:  # as from power-on: nothing assigned, no process-data SMs
            return
        for obj, words, assign in ((0x1600, RX, 0x1C12), (0x1A00, TX, 0x1C13)):
            self.s.download(obj, 0, u8(0))
            for n, w in enumerate(words, 1):
                self.s.download(obj, n, u32(w))
            self.s.download(obj, 0, u8(len(words)))
            self.s.download(assign, 0, u8(1))
        self.s.configure_process_data(OUT_LEN, IN_LEN)
        self.out = dict(cw=0, mode=8, pos=0, vel=0, torque=0)
        self.last: dict[str, int] = {}

    def op(self) -> None:
        assert self.s.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)
        self.cycle()
        assert self.s.request_state(AlState.OP) == (int(AlState.OP), 0)

    def cycle(self, n: int = 1, **out: int) -> dict[str, int]:
        self.out.update(out)
        for _ in range(n):
            self.s.clock.advance(1_000_000)
            o = self.out
            assert self.s.fpwr(SM2, struct.pack(RX_FMT, o["cw"], o["mode"], o["pos"], o["vel"],
                                                o["torque"])) == 1
            d = self.s.fprd(SM3, IN_LEN)
            assert d.wkc == 1
            sw, mode, pos, vel, tq, fe, err = struct.unpack(TX_FMT, bytes(d.data))
            self.last = dict(sw=sw, mode=mode, pos=pos, vel=vel, torque=tq, fe=fe, err=err)
        return self.last

    @property
    def state(self) -> DriveState | None:
        return decode_state(self.last["sw"])

    def enable(self, mode: int = 8) -> None:
        self.cycle(mode=mode)
        for cw in (0x06, 0x07, 0x0F):
            self.cycle(2, cw=cw, pos=self.last["pos"])
        assert self.state == DriveState.OPERATION_ENABLED, hex(self.last["sw"])

    def emergencies(self) -> list[Emergency]:
        out = []
        while (raw := self.s.fetch()) is not None:
            header, msg = decode_message(raw)
            if header.type == MailboxType.COE and isinstance(msg, Emergency):
                out.append(msg)
        return out

    def sdo(self, index: int, sub: int, fmt: str) -> int:
        value: int = struct.unpack(fmt, self.s.upload(index, sub))[0]
        return value


@pytest.fixture
def drive() -> Drive:
    d = Drive()
    d.op()
    return d


def test_power_state_machine_with_the_standard_statuswords(drive: Drive) -> None:
    assert drive.cycle(cw=0x0000)["sw"] == 0x0250 | WARN      # switch on disabled, remote
    assert drive.cycle(cw=0x000F)["sw"] == 0x0250 | WARN      # 0x0F is no transition there
    assert drive.cycle(cw=0x0006)["sw"] == 0x0231 | WARN      # ready to switch on
    assert drive.cycle(cw=0x0007)["sw"] & 0x6F == 0x23        # switched on
    sw = drive.cycle(cw=0x000F)["sw"]
    assert sw & 0x6F == 0x27 and sw & 0x1000                  # enabled, follows the target (CSP)
    assert drive.cycle(cw=0x0007)["sw"] & 0x6F == 0x23        # disable operation
    assert drive.cycle(cw=0x0006)["sw"] & 0x6F == 0x21        # shutdown
    assert drive.cycle(cw=0x000F)["sw"] & 0x6F == 0x27        # 3 and 4 at once from ready
    assert drive.cycle(cw=0x0000)["sw"] & 0x4F == 0x40        # disable voltage
    assert drive.sdo(0x6502, 0, "<I") == 0x3A5                # PP, PV, HM, CSP, CSV, CST


def test_fault_reset_needs_a_rising_edge_of_bit_7(drive: Drive) -> None:
    drive.enable()
    drive.cycle(15, pos=drive.last["pos"] + 2_000_000)        # a jump no motor can follow
    drive.cycle(200, cw=0x008F)                               # bit 7 already high when it faults
    assert drive.state == DriveState.FAULT
    assert drive.last["err"] == 0x8611
    drive.cycle(5, cw=0x0080)                                 # still high: no edge, no reset
    assert drive.state == DriveState.FAULT
    drive.cycle(cw=0x0000)
    assert drive.cycle(cw=0x0080)["sw"] & 0x4F == 0x40        # the edge resets it
    assert drive.last["err"] == 0


@pytest.mark.parametrize("option,ends", [(0, DriveState.SWITCH_ON_DISABLED),
                                         (2, DriveState.SWITCH_ON_DISABLED),
                                         (6, DriveState.QUICK_STOP_ACTIVE)])
def test_quick_stop_option_codes(drive: Drive, option: int, ends: DriveState) -> None:
    drive.s.download(0x605A, 0, i16(option))
    drive.s.download(0x6085, 0, u32(10_000_000))              # quick stop deceleration
    drive.enable(mode=9)                                      # CSV
    drive.cycle(300, vel=500_000)
    assert abs(drive.last["vel"] - 500_000) < 5_000
    start = drive.last["pos"]
    drive.cycle(cw=0x000B)                                    # quick stop (bit 2 = 0)
    if option == 0:
        assert drive.state == DriveState.SWITCH_ON_DISABLED   # torque off at once: it coasts
        return
    assert drive.state == DriveState.QUICK_STOP_ACTIVE and drive.last["sw"] & 0x6F == 0x07
    drive.cycle(200)
    assert drive.state == ends
    assert drive.last["vel"] == 0
    # braking distance of the quick stop ramp: v^2 / (2 a) = 12500 increments
    assert 11_000 < drive.last["pos"] - start < 15_000
    if option == 6:
        drive.cycle(2, cw=0x000F)                             # back to operation (codes 5-8)
        assert drive.state == DriveState.OPERATION_ENABLED


def test_profile_position_handshake_and_move(drive: Drive) -> None:
    drive.s.download(0x6081, 0, u32(400_000))
    drive.s.download(0x6083, 0, u32(4_000_000))
    drive.s.download(0x6084, 0, u32(4_000_000))
    drive.enable(mode=1)
    assert drive.last["mode"] == 1
    home = drive.last["pos"]
    sw = drive.cycle(cw=0x003F, pos=home + 100_000)["sw"]     # new set-point, immediately
    assert sw & 0x1000                                        # set-point acknowledge
    assert not sw & 0x0400                                    # moving: target not reached
    sw = drive.cycle(cw=0x002F)["sw"]
    assert not sw & 0x1000                                    # ack drops with bit 4
    drive.cycle(500)
    assert drive.last["sw"] & 0x0400 and drive.last["pos"] == home + 100_000
    # relative move with a buffered second set-point (bit 5 = 0)
    drive.cycle(cw=0x005F, pos=-30_000)                       # relative, immediate
    drive.cycle(cw=0x004F)
    drive.cycle(2, cw=0x005F, pos=-20_000)                    # a second one, not immediate
    drive.cycle(cw=0x004F)
    drive.cycle(600)
    assert drive.last["pos"] == home + 50_000 and drive.last["sw"] & 0x0400


def test_velocity_torque_and_halt(drive: Drive) -> None:
    drive.enable(mode=3)                                      # profile velocity
    drive.cycle(200, vel=300_000)
    assert drive.last["sw"] & 0x0400 and abs(drive.last["vel"] - 300_000) < 1000
    drive.cycle(200, cw=0x010F)                               # halt
    assert drive.last["vel"] == 0 and drive.last["sw"] & 0x1400 == 0x1400  # reached, speed 0
    drive.cycle(2, cw=0x000F, mode=10, torque=0)              # cyclic synchronous torque
    assert drive.last["mode"] == 10
    drive.cycle(20, torque=500)                               # 0.5 N m on 2e-4 kg m^2
    assert drive.last["vel"] > 0 and 450 <= drive.last["torque"] <= 500
    # max torque 0x6072 caps the torque
    drive.s.download(0x6072, 0, u16(200))
    drive.cycle(3, torque=1000)
    assert drive.last["torque"] == 200


def test_inertia_sets_the_acceleration(drive: Drive) -> None:
    drive.enable(mode=10)
    drive.cycle(10, torque=1000)                              # 1 N m
    v1 = drive.last["vel"]
    drive.cycle(2, torque=0, cw=0x0000)
    drive.cycle(1000)                                         # coasts to a stop on friction
    assert drive.last["vel"] == 0
    drive.s.download(0x2100, 1, struct.pack("<f", 4e-4))      # twice the inertia
    drive.enable(mode=10)
    drive.cycle(10, torque=1000)
    assert 0.4 < drive.last["vel"] / v1 < 0.6


def test_software_limits_clamp_the_target(drive: Drive) -> None:
    drive.s.download(0x607D, 1, i32(-1000))
    drive.s.download(0x607D, 2, i32(20_000))
    drive.enable()
    for target in range(0, 30_001, 100):                      # a ramp past the upper limit
        sw = drive.cycle(pos=target)["sw"]
        assert bool(sw & 0x0800) == (target > 20_000)         # internal limit active
    drive.cycle(200)
    assert drive.last["pos"] == 20_000 and drive.state == DriveState.OPERATION_ENABLED


# 0x2100 "Simulated axis": where the switches a homing method looks for are
_NEG_LIMIT, _POS_LIMIT, _HOME_SWITCH = 7, 8, 9


@pytest.mark.parametrize("method,switch,switch_pos,expected", [
    (37, None, None, 0),                     # current position
    (35, None, None, 0),                     # current position (the older number)
    (19, _HOME_SWITCH, 30_000, 30_000),      # home switch, falling edge
    (20, _HOME_SWITCH, 30_000, 30_000),      # home switch, rising edge
    (34, None, None, 65_536),                # next index pulse upwards (one per revolution)
    (33, None, None, -65_536),               # next index pulse downwards
    (17, _NEG_LIMIT, -40_000, -40_000),      # negative limit switch
    (18, _POS_LIMIT, 40_000, 40_000),        # positive limit switch
    (1, _NEG_LIMIT, -40_000, 0),             # negative limit, then the index pulse above it
    (2, _POS_LIMIT, 40_000, 0),              # positive limit, then the index pulse below it
])
def test_homing_methods(drive: Drive, method: int, switch: int | None, switch_pos: int | None,
                        expected: int) -> None:
    if switch is not None:
        drive.s.download(0x2100, switch, i32(switch_pos or 0))
    drive.s.download(0x6098, 0, bytes([method & 0xFF]))
    drive.s.download(0x607C, 0, i32(-500))                   # home position reads 500
    drive.s.download(0x6099, 1, u32(100_000))
    drive.s.download(0x6099, 2, u32(50_000))
    drive.enable(mode=6)
    drive.cycle(cw=0x001F)                                    # homing operation start
    for _ in range(400):
        if drive.cycle(10)["sw"] & 0x1400 == 0x1400:
            break
    sw = drive.last["sw"]
    assert sw & 0x1400 == 0x1400 and not sw & 0x2000, hex(sw)   # attained, reached, no error
    model = drive.s.app.model  # type: ignore[attr-defined]
    # the home position is where the method says (raw increments from power-on); the
    # new zero is home + home offset, so the home position reads -home offset = 500
    assert model.origin[0] == pytest.approx(expected - 500, abs=1)
    assert drive.sdo(0x6064, 0, "<i") == round(model.p[0] - model.origin[0])


def test_unknown_homing_method_is_a_homing_error(drive: Drive) -> None:
    drive.s.download(0x6098, 0, bytes([5]))
    drive.enable(mode=6)
    drive.cycle(20, cw=0x001F)
    assert drive.last["sw"] & 0x2000                          # homing error


def test_following_error_raises_an_emergency_and_fault(drive: Drive) -> None:
    drive.emergencies()
    drive.enable()
    drive.cycle(15, pos=drive.last["pos"] + 1_000_000)       # 10 ms beyond the window
    assert drive.state == DriveState.FAULT_REACTION_ACTIVE   # quick stop ramp (0x605E = 2)
    drive.cycle(150)
    assert drive.state == DriveState.FAULT
    assert drive.last["err"] == 0x8611
    (emcy,) = drive.emergencies()
    assert emcy.error_code == 0x8611 and emcy.error_register == 0x21
    assert drive.sdo(0x603F, 0, "<H") == 0x8611
    assert drive.sdo(0x1001, 0, "<B") == 0x21
    assert drive.sdo(0x1003, 0, "<B") == 1 and drive.sdo(0x1003, 1, "<I") & 0xFFFF == 0x8611
    drive.cycle(cw=0x0080)
    assert drive.state == DriveState.SWITCH_ON_DISABLED
    assert [e.error_code for e in drive.emergencies()] == [0]  # "error reset"
    assert drive.sdo(0x603F, 0, "<H") == 0 and drive.sdo(0x1001, 0, "<B") == 0
    drive.s.download(0x1003, 0, u8(0))                        # the history is cleared by 0
    assert drive.sdo(0x1003, 1, "<I") == 0


def test_limit_switch_is_a_reference_limit_fault(drive: Drive) -> None:
    drive.s.download(0x2100, 8, i32(10_000))                  # positive limit switch
    drive.enable(mode=9)
    drive.cycle(300, vel=200_000)
    assert drive.state in (DriveState.FAULT_REACTION_ACTIVE, DriveState.FAULT)
    assert drive.last["err"] == 0x8612
    assert [e.error_code for e in drive.emergencies()] == [0x8612]
    assert drive.sdo(0x60FD, 0, "<I") & 0x2                   # positive limit switch input


def test_leaving_op_while_enabled_is_a_communication_fault(drive: Drive) -> None:
    drive.enable()
    drive.emergencies()
    drive.s.request_state(AlState.SAFEOP)
    (emcy,) = drive.emergencies()
    assert emcy.error_code == 0x7500 and emcy.data[:2] == bytes([62, 0])
    assert drive.sdo(0x6041, 0, "<H") & 0x4F in (0x0F, 0x08)


def test_unsupported_mode_is_not_displayed(drive: Drive) -> None:
    drive.cycle(mode=9)
    assert drive.cycle(mode=7)["mode"] == 9                   # interpolated position: no


def test_following_error_bit_13_comes_before_the_fault(drive: Drive) -> None:
    drive.s.download(0x6066, 0, u16(50))                      # following error time out 50 ms
    drive.enable()
    start = drive.last["pos"]
    sw = drive.cycle(3, pos=start + 1_000_000)["sw"]          # far outside the window 0x6065
    assert sw & 0x2000 and drive.state == DriveState.OPERATION_ENABLED
    assert drive.last["fe"] > drive.sdo(0x6065, 0, "<I")      # demand minus actual: positive
    drive.cycle(3, pos=drive.last["pos"])                     # back inside before the time out
    assert not drive.last["sw"] & 0x2000 and drive.state == DriveState.OPERATION_ENABLED


def test_sms_laid_out_with_nothing_assigned_are_refused() -> None:
    """0x1C12/0x1C13 are empty at power-on (the master assigns): SMs sized from the SII's
    PDOs (3 bytes each) match no assigned PDO and SAFE-OP is refused, as a real slave does."""
    d = Drive(mapped=False)
    assert d.sdo(0x1C12, 0, "<B") == 0 and d.sdo(0x1C13, 0, "<B") == 0
    d.s.configure_process_data(3, 3)
    status, code = d.s.request_state(AlState.SAFEOP)
    assert status & 0x1F == 0x12 and code == AlStatusCode.INVALID_OUTPUT_CONFIG
    (emcy,) = d.emergencies()
    assert emcy.error_code == 0xA000 and emcy.data == bytes([62, 3, 2]) + u16(0)
    # the assignment the SII describes makes the same SMs right
    d.s.ack(AlState.PREOP)
    d.s.download(0x1C12, 1, u16(0x1600))
    d.s.download(0x1C12, 0, u8(1))
    d.s.download(0x1C13, 1, u16(0x1A00))
    d.s.download(0x1C13, 0, u8(1))
    assert d.s.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)


def test_sm2_length_wrong_is_refused_with_emergency_and_fault() -> None:
    d = Drive()
    d.s.configure_process_data(OUT_LEN + 2, IN_LEN)
    status, code = d.s.request_state(AlState.SAFEOP)
    assert status & 0x1F == 0x12 and code == AlStatusCode.INVALID_OUTPUT_CONFIG
    (emcy,) = d.emergencies()
    assert emcy.error_code == 0xA000                          # PRE-OP -> SAFE-OP failed
    assert emcy.data == bytes([62, 3, 2]) + u16(OUT_LEN)      # manual 62-3, SM2, its length
    assert d.sdo(0x603F, 0, "<H") == 0xA000
    assert d.sdo(0x6041, 0, "<H") & 0x4F == 0x08              # CiA 402 fault


def test_sm3_length_wrong_is_refused_with_emergency_and_fault() -> None:
    d = Drive()
    d.s.configure_process_data(OUT_LEN, IN_LEN + 2)
    status, code = d.s.request_state(AlState.SAFEOP)
    assert status & 0x1F == 0x12 and code == AlStatusCode.INVALID_INPUT_CONFIG
    (emcy,) = d.emergencies()
    assert emcy.error_code == 0xA000
    assert emcy.data == bytes([62, 4, 3]) + u16(IN_LEN)       # manual 62-4, SM3, its length
    assert d.sdo(0x6041, 0, "<H") & 0x4F == 0x08


def test_sync_parameters_on_the_sm_event(drive: Drive) -> None:
    """0x1C32/0x1C33 (ETG.1020) of a drive synchronised on the frames (no SYNC0)."""
    assert drive.sdo(0x1C32, 1, "<H") == 0x0001               # synchronous with SM2
    assert drive.sdo(0x1C32, 3, "<I") == 0                    # shift time: outputs at once
    assert drive.sdo(0x1C32, 4, "<H") == 0x0007               # free run, SM2, DC SYNC0
    assert drive.sdo(0x1C32, 5, "<I") == 250_000              # minimum cycle time 250 us
    assert drive.sdo(0x1C33, 1, "<H") == 0x0022               # inputs latched on the SM2 event
    assert drive.sdo(0x1C33, 3, "<I") == 0
    assert drive.sdo(0x1C33, 5, "<I") == 250_000


def test_sync0_faster_than_the_minimum_cycle_time_refuses_safeop() -> None:
    d = Drive()
    d.s.download(0x1C32, 1, u16(2))                           # DC SYNC0
    d.s.fpwr(R.DC_SYNC0_CYCLE, u32(125_000))                  # 125 us < 0x1C32:05
    d.s.fpwr(R.DC_ACTIVATION, bytes([R.DcActivation.CYCLIC | R.DcActivation.SYNC0]))
    status, code = d.s.request_state(AlState.SAFEOP)
    assert status & 0x1F == 0x12 and code == AlStatusCode.DC_INVALID_SYNC0_CYCLE_TIME
    d.s.ack(AlState.PREOP)
    d.s.fpwr(R.DC_SYNC0_CYCLE, u32(250_000))                  # at the minimum: accepted
    assert d.s.request_state(AlState.SAFEOP) == (int(AlState.SAFEOP), 0)


def test_set_for_dc_without_sync0_refuses_safeop() -> None:
    d = Drive()
    d.s.download(0x1C32, 1, u16(2))                           # DC SYNC0
    status, code = d.s.request_state(AlState.SAFEOP)
    assert code == AlStatusCode.INVALID_DC_SYNC_CONFIG and status & 0x1F == 0x12
    (emcy,) = d.emergencies()
    assert emcy.error_code == 0x8700 and emcy.data[:2] == bytes([63, 3])  # "no DC found"
    assert d.sdo(0x603F, 0, "<H") == 0x8700
