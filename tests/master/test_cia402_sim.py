"""Our master's CiA 402 helper against simulated drives on DC SYNC0, on virtual time.

Master and simulator share one virtual clock: the drives sample their
outputs on SYNC0 (1 ms), the master's frames pass the reference half a cycle
before it (the DC phase lock), so every scenario is exact and repeatable.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError, DriveError, DriveFaultError
from pyethercat.link.pair import PairLink
from pyethercat.master.cia402 import DriveEmergency, DriveFault, DriveGroup
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.dc import DcSettings
from pyethercat.master.master import Master
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.trajectory import s_curve, trapezoid
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.cia402 import DriveState, OperationMode

CSP_MAP = {0x1C12: [(0x1600, [(0x6040, 0, 16), (0x6060, 0, 8), (0x607A, 0, 32)])],
           0x1C13: [(0x1A00, [(0x6041, 0, 16), (0x6061, 0, 8), (0x6064, 0, 32), (0x60F4, 0, 32),
                              (0x603F, 0, 16)])]}


class Rig:
    """Drives on a segment, our master on the same virtual clock, cycles on a runner."""

    def __init__(self, slaves: str, *, mapping: dict[int, Any] | None = CSP_MAP,
                 sync: bool = True, cycle: float = 0.001, op: bool = True) -> None:
        self.clock = VirtualClock(1_000_000_000)
        self.seg: Segment = parse_topology(slaves).build(clock=self.clock)
        m = self.m = Master(PairLink.responder_link(self.seg.process), clock=self.clock)
        m.dc.master_time = lambda: self.clock.now_ns() + 10**18
        m.scan()
        m.set_state("PREOP")
        if mapping:
            for s in m.slaves:
                s.set_pdo_mapping(mapping)
        m.configure()
        m.dc.setup(DcSettings(static_sync=300))
        if sync:
            m.dc.configure_sync(1_000_000, 0)
        m.pd.bring_up(m.slaves, 5.0)
        plan = m.dc.cycle(int(cycle * 1e9), "master", self.clock)
        self.runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=cycle,
                                   clock=self.clock, check_interval=0, dc=plan)
        self.runner.run(cycles=300)
        if op:
            self.op()
        self.group = DriveGroup(m, runner=self.runner)

    def op(self) -> None:
        self.m.request_state("OP")
        self.runner.run(cycles=50)
        assert [s.state for s in self.m.read_states()] == [AlState.OP] * len(self.m.slaves)

    def model(self, i: int = 0):  # type: ignore[no-untyped-def]
        return self.seg.slaves[i].spec.model


def drives(n: int, device: str = 'device = "builtin:seed002-drive"') -> str:
    return "".join(f'[[slave]]\nname = "d{i}"\n{device}\n' for i in range(n))


def test_csp_s_curves_on_dc_follow_within_the_window() -> None:
    rig = Rig(drives(3))
    g = rig.group
    g.set_mode("csp")
    g.enable()
    assert g.states() == [DriveState.OPERATION_ENABLED] * 3
    start = g.positions_actual()
    goal = start + np.array([100_000, -50_000, 200_000])
    rec = g.follow(s_curve(start, goal, 4e5, 4e6, 8e7, 0.001), settle=30)
    assert rec is not None and rec.following_error is not None
    # at rest within one increment (static friction holds the last fraction)
    assert np.abs(g.positions_actual() - goal).max() <= 1
    assert (g.statuswords() & 0x0400).all()                   # target reached
    assert 0 < np.abs(rec.following_error).max() < 100        # feed-forward: a few increments
    for s in rig.m.slaves:                                    # DC mode, no SM event missed
        assert s.sdo_read(0x1C32, 1, "uint16") == 2
        assert s.sdo_read(0x1C32, 0x0B, "uint16") == 0
        assert s.sdo_read(0x1C32, 2, "uint32") == 1_000_000
        assert s.sdo_read(0x1C32, 3, "uint32") == 0           # outputs applied at SYNC0
        assert s.sdo_read(0x1C32, 5, "uint32") == 250_000     # minimum cycle time
        assert s.sdo_read(0x1C33, 1, "uint16") == 2           # inputs latched at SYNC0 too
        assert s.sdo_read(0x1C33, 2, "uint32") == 1_000_000   # the same cycle
        assert s.sdo_read(0x1C33, 3, "uint32") == 0


def test_following_error_is_demand_minus_actual_and_lags_on_acceleration() -> None:
    """0x60F4 is the position demand value minus the position actual value (IEC 61800-7-201):
    while a positive move accelerates at a constant rate the axis never leads its demand,
    and a move the other way mirrors it."""
    rig = Rig(drives(2))
    g = rig.group
    g.set_mode("csp")
    g.enable()
    start = g.positions_actual()
    move = trapezoid(start, start + np.array([60_000, -60_000]), 4e5, 4e6, 0.001)
    rec = g.follow(move, settle=30)
    assert rec is not None and rec.following_error is not None
    # the cycles in which the commanded move accelerates at 4e6 inc/s² (to 400,000 inc/s)
    accel = np.abs(np.diff(move.velocity[:, 0])) > 1.0
    accel[move.velocity[1:, 0] <= 0] = False
    rows = np.nonzero(accel)[0][5:100]                       # 0.1 s of it, the drive caught up
    fe = rec.following_error[rows]
    assert (fe[:, 0] >= 0).all() and (fe[:, 1] <= 0).all(), fe.T
    assert np.abs(fe).max() <= 5                              # the feed-forward does the work


def test_builtin_drive_gets_the_sii_pdos_assigned_and_runs() -> None:
    """The drive's 0x1C12/0x1C13 are empty at power-on: configure() writes the SII's PDOs
    to them (the drive would refuse SAFE-OP otherwise) and the drive answers in OP."""
    rig = Rig(drives(1), mapping=None)
    s = rig.m.slaves[0]
    assert [s.sdo_read(0x1C12, sub, "uint16" if sub else "uint8") for sub in (0, 1)] == [1, 0x1600]
    assert [s.sdo_read(0x1C13, sub, "uint16" if sub else "uint8") for sub in (0, 1)] == [1, 0x1A00]
    cfg = rig.m.process_data
    assert cfg is not None                                    # controlword + mode, status + mode
    assert (cfg.slaves[0].output_bytes, cfg.slaves[0].input_bytes) == (3, 3)
    d = rig.group.drive(0)
    assert d.state == DriveState.SWITCH_ON_DISABLED and d.statusword & 0x0250 == 0x0250
    d.enable()
    assert d.state == DriveState.OPERATION_ENABLED


def test_a_drive_group_names_the_slave_that_does_not_map_the_controlword() -> None:
    rig = Rig(drives(1) + '[[slave]]\nname = "in"\ndevice = "builtin:di8"\n', mapping=None)
    assert rig.group.positions == [0]                         # found by its mapped 0x6040/0x6041
    with pytest.raises(ConfigError, match=r"^slave 1 does not map 0x6040 \(controlword\) "
                                          r"into its outputs$"):
        DriveGroup(rig.m, [0, 1], runner=rig.runner)


@pytest.mark.parametrize("mode,index,stale,dtype", [
    ("csp", 0x607A, 30_000, "int32"),                         # a target left from a PP move
    ("csv", 0x60FF, 200_000, "int32"),                        # from a PV run
    ("cst", 0x6071, 300, "int16"),                            # 30 % of the rated torque
], ids=["csp", "csv", "cst"])
def test_cyclic_mode_with_an_unmapped_target_starts_where_the_axis_is(
        mode: str, index: int, stale: int, dtype: str) -> None:
    """The target of CSP/CSV/CST not in the PDOs still holds what was written last; the group
    writes it by SDO (actual position, zero velocity, zero torque) before the mode changes."""
    rig = Rig(drives(1), mapping=None)                        # controlword + mode only
    s = rig.m.slaves[0]
    d = rig.group.drive(0)
    d.enable()
    before = s.sdo_read(0x6064, 0, "int32")
    s.sdo_write(index, 0, before + stale if index == 0x607A else stale, dtype)
    d.set_mode(mode)
    rig.group.step(300)
    assert d.state == DriveState.OPERATION_ENABLED            # no following error fault
    assert abs(s.sdo_read(0x6064, 0, "int32") - before) <= 1  # the axis did not move
    assert s.sdo_read(index, 0, dtype) == (before if index == 0x607A else 0)


def test_following_error_fault_emergency_and_reset() -> None:
    rig = Rig(drives(2))
    g = rig.group
    g.set_mode("csp")
    g.enable()
    jump = np.tile(g.positions_actual() + np.array([1_000_000, 0]), (200, 1))
    with pytest.raises(DriveFaultError) as err:
        g.stream(jump)
    assert err.value.code == 0x8611 and "following error" in str(err.value)
    g.step(200)
    rig.m.poll_mailboxes()
    faults = [e for e in g.events if isinstance(e, DriveFault)]
    emcys = [e for e in g.events if isinstance(e, DriveEmergency)]
    assert [(f.position, f.code) for f in faults] == [(0, 0x8611)]
    assert [(e.position, e.code, e.register) for e in emcys] == [(0, 0x8611, 0x21)]
    assert g.states()[1] == DriveState.OPERATION_ENABLED      # the other drive runs on
    assert g.error_history(0)[0].code == 0x8611
    g.fault_reset(drives=[0])
    assert g.states()[0] == DriveState.SWITCH_ON_DISABLED
    g.enable()
    assert g.states() == [DriveState.OPERATION_ENABLED] * 2


def test_profile_position_move_quick_stop_and_homing() -> None:
    rig = Rig(drives(1))
    d = rig.group.drive(0)
    d.enable()
    start = d.actual_position
    d.move_to(start + 60_000, velocity=600_000, acceleration=6_000_000)
    # target reached: inside the position window 0x6067 (100) for 0x6068 (10 ms)
    assert abs(d.actual_position - (start + 60_000)) <= 100
    assert d.mode == OperationMode.PROFILE_POSITION
    d.move_to(-10_000, relative=True)                          # relative to the last target
    # the axis may come to rest a fraction of an increment past the target; the velocity
    # loop's integrator then has to overcome Coulomb friction (0x2100) before it creeps back
    rig.group.step(300)
    assert d.actual_position == start + 50_000
    rig.m.slaves[0].sdo_write(0x2100, 9, start + 80_000, "int32")  # the home switch
    rig.m.slaves[0].sdo_write(0x607C, 0, -1000, "int32")           # home reads 1000
    d.home(19)
    assert d.mode == OperationMode.HOMING
    assert rig.model().origin[0] == pytest.approx(start + 80_000 - 1000)
    d.quick_stop()
    assert d.state == DriveState.SWITCH_ON_DISABLED           # 0x605A = 2: ramp, then off
    with pytest.raises(DriveError, match="not enabled"):
        d.move_to(0)


def test_frames_after_sync0_are_missed_events_and_end_in_sync_unstable() -> None:
    rig = Rig(drives(1), cycle=0.002, op=False)               # frames every 2 ms, SYNC0 every 1
    rig.m.slaves[0].sdo_write(0x10F1, 2, 150, "uint16")       # sync error counter limit
    rig.op()                                                  # (+3 per missed event, -1 per good)
    g = rig.group
    g.set_mode("csp")
    g.enable()
    g.step(100)
    assert rig.m.read_states()[0].state == AlState.SAFEOP     # fell back: sync error
    assert rig.m.read_states()[0].code == AlStatusCode.SYNCHRONIZATION_ERROR
    assert rig.model().missed[0] >= 75                        # one SYNC0 of every two
    assert rig.m.slaves[0].sdo_read(0x1C32, 0x0B, "uint16") == rig.model().missed[0]
    rig.m.poll_mailboxes()
    emcy = [e for e in g.events if isinstance(e, DriveEmergency)][0]
    assert emcy.code == 0x8700 and emcy.data[:2] == bytes([62, 5])  # "sync unstable"
    assert rig.m.slaves[0].sdo_read(0x603F, 0, "uint16") == 0x8700
    assert rig.m.slaves[0].sdo_read(0x1C32, 0x20, "uint8") == 1  # sync error


def test_sync0_stopping_is_sync_unstable() -> None:
    rig = Rig(drives(1))
    rig.group.enable()
    rig.m.write(0, R.DC_ACTIVATION, b"\x00")                   # SYNC0 stops
    rig.runner.run(cycles=10)
    reading = rig.m.read_states()[0]
    assert (reading.state, reading.error, reading.code) == (
        AlState.SAFEOP, True, AlStatusCode.FATAL_SYNC_ERROR)
    assert rig.m.slaves[0].sdo_read(0x603F, 0, "uint16") == 0x8700


def test_safeop_to_op_refused_without_sync0_when_set_for_dc() -> None:
    rig = Rig(drives(1), op=False)
    assert rig.m.slaves[0].sdo_read(0x1C32, 1, "uint16") == 2  # DC SYNC0
    rig.m.write(0, R.DC_ACTIVATION, b"\x00")                   # the master forgets SYNC0
    rig.m.request_state("OP")
    rig.runner.run(cycles=20)
    reading = rig.m.read_states()[0]
    assert (reading.state, reading.error, reading.code) == (
        AlState.SAFEOP, True, AlStatusCode.NO_SYNC_ERROR)
    rig.m.poll_mailboxes()
    assert rig.m.slaves[0].sdo_read(0x603F, 0, "uint16") == 0x8700


@pytest.mark.parametrize("esi,mapping", [
    # the C-series ESI assigns controlword + mode only; its 0x1601 has the target position
    ("builtin:seed002_drive.xml", {0x1C12: [0x1600, 0x1601]}),
    ("kickcat_ingenia_esi.xml", None),                        # 0x1600/0x1A00 as the ESI assigns
    ("kickcat_ecat402-drive.xml", None),
])
def test_drives_built_from_esi_files_move(esi: str, mapping: dict[int, Any] | None,
                                         corpus_dir: Path) -> None:
    path = esi if esi.startswith("builtin:") else str(corpus_dir / "esi" / esi)
    rig = Rig(drives(2, f'esi = "{path}"'), mapping=mapping)
    g = rig.group
    g.set_mode("csp")
    g.enable()
    start = g.positions_actual()
    goal = start + np.array([30_000, -30_000])
    g.follow(s_curve(start, goal, 3e5, 3e6, 6e7, 0.001), settle=30)
    assert np.abs(g.positions_actual() - goal).max() <= 1
    assert (g.statuswords() & 0x0400).all()


def test_many_drives_move_together() -> None:
    rig = Rig(drives(20))
    g = rig.group
    g.set_mode("csp")
    g.enable()
    start = g.positions_actual()
    goal = start + np.arange(1, 21) * 5_000
    rec = g.follow(s_curve(start, goal, 2e5, 2e6, 4e7, 0.001, synchronized=True), settle=30)
    assert rec is not None
    assert np.abs(g.positions_actual() - goal).max() <= 1
    assert rec.commanded.shape == (len(rec.commanded), 20)


def test_homing_on_the_current_position_holds_there_and_can_be_repeated() -> None:
    """Method 37 takes the encoder's count as home and holds it, even while the axis still
    settles from a move; a second homing is not mistaken for done by the first one's bits."""
    rig = Rig(drives(1))
    d = rig.group.drive(0)
    model = rig.model()
    rig.m.slaves[0].sdo_write(0x6067, 0, 5000, "uint32")  # a wide position window: the move
    rig.m.slaves[0].sdo_write(0x6068, 0, 0, "uint16")     # is reached while the axis still runs
    d.enable()
    d.move_to(d.actual_position + 20_000, velocity=400_000, acceleration=4_000_000)
    d.home(37)
    assert d.mode == OperationMode.HOMING
    assert d.statusword & 0x3400 == 0x1400                   # attained, target reached, no error
    assert float(model.origin[0]).is_integer()               # a whole count, as the encoder's
    rig.group.step(300)                                      # the axis settles where it was homed
    assert d.actual_position == 0 and model.g_p[0] == model.origin[0]
    d.move_to(1_000)
    assert d.actual_position == pytest.approx(1_000, abs=5000)
    rig.group.step(300)
    d.home(37)                                               # "attained" from before: not done yet
    rig.group.step(300)
    assert d.actual_position == 0
