"""SOEM (pysoem) drives the simulated C-series servo drive as a SOEM user would, over veth.

``pyethercat sim`` serves the drive (the built-in kind, or one built from its
ESI) on one end of a veth pair. pysoem, on the other end:

- configures DC and SYNC0 at 1 ms with ``dc_sync``, maps the PDOs for CSP
  in PRE-OP (0x1600/0x1A00 through SDOs in a ``config_func``) and goes to
  OP, sending each frame half a cycle away from SYNC0 on the DC time the
  previous frames brought back (what SOEM's examples do with ``ec_sync``);
- walks the drive through Switch on disabled, Ready to switch on, Switched on
  and Operation enabled with 0x06, 0x07, 0x0F;
- moves it 100,000 increments along a ramp: the following error stays in
  the window 0x6065 and the statusword shows "target reached" at the end;
- makes a following error on purpose (a jump of the target): the drive goes
  to Fault, sends emergency 0x8611 and shows it in 0x603F; a fault reset
  brings it back.

Our master's ``DriveGroup`` does the same over the same veth pair (SYNC0 at 1 ms,
CSP mapping, OP, enable, the ramp, the deliberate following error with its
typed events, the fault reset), the way a user of ``pyethercat.master.cia402``
would.

Then the drive refuses OP once SYNC0 is gone (AL status code 0x002D, "no
sync"), and, in OP, reports "sync unstable" when SYNC0 stops (0x002C and
emergency 0x8700 with the manual's number 62-5).

The host is not real-time (a shared 2-core machine whose wake-ups wander by
hundreds of microseconds): the test runs its cycle at SCHED_FIFO and raises
the drive's sync error counter limit 0x10F1:02, as an integrator on such a
host would; the SM events missed (0x1C32:0B) are printed, not asserted.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pyethercat.errors import DriveFaultError
from pyethercat.master.cia402 import DriveEmergency, DriveFault, DriveGroup
from pyethercat.master.master import Master
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire import registers as R
from pyethercat.wire.cia402 import DriveState

pysoem = pytest.importorskip("pysoem")

CYCLE_NS = 1_000_000
#: 0x10F1:02 for these tests: +3 per missed SM event, -1 per good one. On the loaded host
#: our Python loop missed ~500 events in the 1.2 s ramp, and in full suite runs the SOEM
#: test failed where it passes alone (1000 was the limit then). SYNC0 stopping is still
#: found at once (by the SYNC0 watchdog, not by this counter).
SYNC_ERROR_LIMIT = 60_000
RX = [0x60400010, 0x60600008, 0x607A0020]
TX = [0x60410010, 0x60610008, 0x60640020, 0x60F40020, 0x603F0010]
OUT_FMT, IN_FMT = "<HbI", "<HbiiH"
TOPOLOGIES = {
    "builtin": '[[slave]]\nname = "drive"\ndevice = "builtin:seed002-drive"\ndrift_ppm = 20.0\n',
    "esi": '[[slave]]\nname = "drive"\nesi = "builtin:seed002_drive.xml"\ndrift_ppm = -30.0\n',
}


@pytest.fixture(params=sorted(TOPOLOGIES))
def served(request: pytest.FixtureRequest, veth_pair: tuple[str, str],
           tmp_path: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "drive.toml"
    topo.write_text(TOPOLOGIES[request.param])
    handle = start_sim_process(topo, link=f"iface:{sim_end}", realtime=10)
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def u8(v: int) -> bytes:
    return bytes([v])


def u32(v: int) -> bytes:
    return struct.pack("<I", v)


def map_csp(slave: Any) -> None:
    """PDO mapping for CSP, in PRE-OP (pysoem calls this from config_map)."""
    for obj, words, assign in ((0x1600, RX, 0x1C12), (0x1A00, TX, 0x1C13)):
        slave.sdo_write(assign, 0, u8(0))
        slave.sdo_write(obj, 0, u8(0))
        for n, w in enumerate(words, 1):
            slave.sdo_write(obj, n, u32(w))
        slave.sdo_write(obj, 0, u8(len(words)))
        slave.sdo_write(assign, 1, struct.pack("<H", obj))
        slave.sdo_write(assign, 0, u8(1))
    slave.sdo_write(0x10F1, 2, struct.pack("<H", SYNC_ERROR_LIMIT))  # (see above)


class Soem:
    """A SOEM master cycling at 1 ms, phase-locked onto the DC time as SOEM's examples do."""

    def __init__(self, iface: str) -> None:
        self.m = pysoem.Master()
        self.m.always_release_gil = True
        self.m.open(iface)
        self.emergencies: list[Any] = []
        self.next = 0
        self.integral = 0
        self.cw, self.mode, self.target = 0, 8, 0
        self.inputs: tuple[int, ...] = (0, 0, 0, 0, 0)

    def setup(self) -> Any:
        """DC and SYNC0 first, then the PDO mapping (config_map asks for SAFE-OP at its end)."""
        assert self.m.config_init() == 1
        drive = self.m.slaves[0]
        drive.config_func = lambda _pos: map_csp(drive)
        drive.add_emergency_callback(self.emergencies.append)
        assert self.m.config_dc()
        drive.dc_sync(True, CYCLE_NS)
        self.m.config_map()
        assert (len(drive.output), len(drive.input)) == (7, 13)
        return drive

    def cycle(self, n: int = 1) -> tuple[int, ...]:
        """n cycles on absolute deadlines, each nudged so that the frame meets the reference
        clock half a cycle after SYNC0 (the DC time it brings back tells where it was)."""
        for _ in range(n):
            now = time.monotonic_ns()
            if not self.next or self.next < now - CYCLE_NS:
                self.next = now  # first cycle, or far behind: no burst of catch-up frames
            while (left := self.next - time.monotonic_ns()) > 200_000:
                time.sleep((left - 150_000) / 1e9)
            while time.monotonic_ns() < self.next:
                pass
            self.m.slaves[0].output = struct.pack(OUT_FMT, self.cw, self.mode, self.target & 0xFFFFFFFF)
            self.m.send_processdata()
            self.m.receive_processdata(2000)
            self.inputs = struct.unpack(IN_FMT, self.m.slaves[0].input)
            # PI control of the phase, as SOEM's ec_sync does with its offset time
            delta = (self.m.dc_time - CYCLE_NS // 2) % CYCLE_NS
            if delta > CYCLE_NS // 2:
                delta -= CYCLE_NS
            self.integral = max(-2_000_000, min(2_000_000, self.integral + delta))
            step = delta // 4 + self.integral // 64
            self.next += CYCLE_NS - max(-100_000, min(100_000, step))
        return self.inputs

    @property
    def sw(self) -> int:
        return self.inputs[0]

    def to_op(self) -> None:
        assert self.m.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE
        self.cycle(200)                                        # the PI loop settles first
        self.m.state = pysoem.OP_STATE
        self.m.write_state()
        for _ in range(500):
            self.cycle()
            if self.m.read_state() == pysoem.OP_STATE:
                return
        raise AssertionError(f"no OP: AL status 0x{self.m.slaves[0].al_status:04X}")

    def wait_sw(self, mask: int, value: int, cycles: int = 200) -> int:
        for _ in range(cycles):
            self.cycle()
            if self.sw & mask == value:
                return self.sw
        raise AssertionError(f"statusword 0x{self.sw:04X}, wanted 0x{value:04X} under 0x{mask:04X}")


@pytest.fixture
def realtime() -> Iterator[None]:
    """The test's cycle at SCHED_FIFO 5 (below the simulator's 10), restored afterwards."""
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))
    except (OSError, AttributeError):
        yield
        return
    try:
        yield
    finally:
        os.sched_setscheduler(0, before[0], before[1])


@pytest.mark.root
def test_soem_drives_the_drive_in_csp_on_dc(served: tuple[SimProcess, str], realtime: None) -> None:
    handle, iface = served
    s = Soem(iface)
    try:
        drive = s.setup()
        s.to_op()
        # --- the power state machine: 0x06, 0x07, 0x0F
        s.cw, s.target = 0x0000, s.inputs[2]
        assert s.wait_sw(0x4F, 0x40) & 0x4F == 0x40                 # switch on disabled
        for cw, mask, value in ((0x06, 0x6F, 0x21), (0x07, 0x6F, 0x23), (0x0F, 0x6F, 0x27)):
            s.cw = cw
            s.wait_sw(mask, value)
        assert s.inputs[1] == 8                                      # CSP displayed
        assert drive.sdo_read(0x1C32, 1) == struct.pack("<H", 2)     # DC SYNC0 (chosen by SYNC0)
        # --- 100,000 increments on a ramp (500 ms), then at rest
        start = s.inputs[2]
        window = struct.unpack("<I", drive.sdo_read(0x6065, 0))[0]
        worst = 0
        for k in range(1, 501):
            s.target = start + 100_000 * k // 500
            s.cycle()
            worst = max(worst, abs(s.inputs[3]))
            assert s.sw & 0x4F != 0x08, (f"fault 0x{s.inputs[4]:04X} at step {k}", [
                (hex(e.error_code), e.b1, hex(e.w1), hex(e.w2)) for e in s.emergencies])
        sw = s.wait_sw(0x0400, 0x0400)                               # target reached
        assert sw & 0x6F == 0x27 and abs(s.inputs[2] - (start + 100_000)) <= 100
        assert 0 < worst < window, worst
        missed = struct.unpack("<H", drive.sdo_read(0x1C32, 0x0B))[0]
        print(f"max following error {worst} (window {window}), SM events missed {missed}")
        # --- a following error on purpose: the target jumps
        s.target = s.inputs[2] + 2_000_000
        s.wait_sw(0x4F, 0x08, cycles=1000)                           # fault
        assert s.inputs[4] == 0x8611                                  # 0x603F (in the PDO)
        assert drive.sdo_read(0x603F, 0) == struct.pack("<H", 0x8611)
        codes = [e.error_code for e in s.emergencies]
        assert 0x8611 in codes, codes
        # --- fault reset (rising edge of bit 7) and back to operation
        s.target = s.inputs[2]
        s.cw = 0x0000
        s.cycle(5)
        s.cw = 0x0080
        s.wait_sw(0x4F, 0x40)
        assert s.inputs[4] == 0
        for cw, value in ((0x06, 0x21), (0x07, 0x23), (0x0F, 0x27)):
            s.cw = cw
            s.wait_sw(0x6F, value)
        # --- SYNC0 stops in OP: sync unstable
        drive.dc_sync(False, CYCLE_NS)
        for _ in range(100):
            s.cycle()
            if s.m.read_state() != pysoem.OP_STATE:
                break
        assert drive.al_status == 0x002C                              # fatal sync error
        assert drive.sdo_read(0x603F, 0) == struct.pack("<H", 0x8700)
        unstable = [e for e in s.emergencies if e.error_code == 0x8700]
        # data bytes 0, 1 (pysoem: b1, low byte of w1) carry the manual's error number 62-5
        assert unstable and (unstable[-1].b1, unstable[-1].w1 & 0xFF) == (62, 5)
    finally:
        s.m.close()


@pytest.mark.root
def test_op_refused_without_sync0_when_set_for_dc(served: tuple[SimProcess, str],
                                                  realtime: None) -> None:
    _handle, iface = served
    s = Soem(iface)
    try:
        drive = s.setup()
        assert s.m.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE
        drive.dc_sync(False, CYCLE_NS)                                # SYNC0 gone in SAFE-OP
        s.cycle(20)
        s.m.state = pysoem.OP_STATE
        s.m.write_state()
        for _ in range(100):
            s.cycle()
            s.m.read_state()
            if drive.al_status:
                break
        assert drive.state & 0x1F == 0x14 and drive.al_status == 0x002D  # SAFE-OP + error: no sync
        assert drive.sdo_read(0x603F, 0) == struct.pack("<H", 0x8700)
        assert R.DC_ACTIVATION  # (the register SOEM's dc_sync wrote)
    finally:
        s.m.close()


CSP_MAPPING = {0x1C12: [(0x1600, [(0x6040, 0, 16), (0x6060, 0, 8), (0x607A, 0, 32)])],
               0x1C13: [(0x1A00, [(0x6041, 0, 16), (0x6061, 0, 8), (0x6064, 0, 32),
                                  (0x60F4, 0, 32), (0x603F, 0, 16)])]}


@pytest.mark.root
def test_our_drive_group_drives_the_drive_in_csp_on_dc(served: tuple[SimProcess, str],
                                                       realtime: None) -> None:
    _handle, iface = served
    with Master.open(iface) as m:
        m.scan()
        m.set_state("PREOP")
        drive = m.slaves[0]
        drive.set_pdo_mapping(CSP_MAPPING)
        drive.sdo_write(0x10F1, 2, SYNC_ERROR_LIMIT, "uint16")  # (see above)
        m.configure()
        m.dc.setup()
        m.dc.configure_sync(CYCLE_NS)
        runner = m.start(0.001, dc="master")  # the runner's thread inherits SCHED_FIFO 5
        g = DriveGroup(m)
        assert g.states()[0] is not None
        # --- CSP, then 0x06, 0x07, 0x0F (one transition per answer) to Operation enabled
        g.set_mode("csp")
        g.enable()
        assert g.statuswords()[0] & 0x6F == 0x27
        assert drive.sdo_read(0x1C32, 1, "uint16") == 2  # DC SYNC0
        # --- 100,000 increments on a ramp (500 ms), then target reached
        start = int(g.positions_actual()[0])
        window = int(drive.sdo_read(0x6065, 0, "uint32"))
        ramp = start + 100_000 * np.arange(1, 501) // 500
        rec = g.stream(ramp, settle=100)
        assert rec is not None and rec.following_error is not None
        worst = int(np.abs(rec.following_error).max())
        assert 0 < worst < window, worst
        assert g.statuswords()[0] & 0x0400 and abs(int(g.positions_actual()[0]) - ramp[-1]) <= 100
        print(f"our master: max following error {worst} (window {window}), "
              f"SM events missed {drive.sdo_read(0x1C32, 0x0B, 'uint16')}, cycles "
              f"{runner.stats.cycles}, skipped {runner.stats.skipped}")
        # --- a following error on purpose: a fault with its code, typed events, 0x603F
        here = int(g.positions_actual()[0])
        with pytest.raises(DriveFaultError) as fault:
            g.stream(np.full(1000, here + 2_000_000), record=False)
        assert fault.value.code == 0x8611
        for _ in range(100):  # through Fault reaction active (a stop ramp) to Fault
            if g.states()[0] == DriveState.FAULT:
                break
            g.step(10)
        assert g.statuswords()[0] & 0x4F == 0x08
        assert drive.sdo_read(0x603F, 0, "uint16") == 0x8611
        assert any(isinstance(e, DriveFault) and e.code == 0x8611 for e in g.events), g.events
        assert any(isinstance(e, DriveEmergency) and e.code == 0x8611 for e in g.events), g.events
        assert [r.code for r in g.error_history(0)][0] == 0x8611
        # --- fault reset (rising edge of bit 7) and back to operation
        g.fault_reset()
        assert g.statuswords()[0] & 0x4F == 0x40 and drive.sdo_read(0x603F, 0, "uint16") == 0
        g.enable()
        assert g.statuswords()[0] & 0x6F == 0x27
        g.disable()
