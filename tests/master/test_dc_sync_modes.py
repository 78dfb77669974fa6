"""SYNC0 set-up and the 0x1C32/0x1C33 sync modes, against the simulator's CoE devices.

builtin:coe-io is a CoE device whose 0x1C32 offers free run, SM synchronous
and DC SYNC0 (sub 4); a device left in (or defaulting to) DC mode refuses
SAFEOP without SYNC0 with its AL status code.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import AlStatusError
from pyethercat.link.pair import PairLink
from pyethercat.master.dc import DcSettings
from pyethercat.master.master import Master
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.mailbox.objects import StandardObject, SyncMode, SyncSub

TOPOLOGY = """
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "di8"
device = "builtin:di8"
[[slave]]
name = "io"
device = "builtin:coe-io"
"""
OUT, IN = StandardObject.SM_OUTPUT_SYNC, StandardObject.SM_INPUT_SYNC


def open_demo() -> Master:
    clock = VirtualClock(1_000_000_000)
    seg = parse_topology(TOPOLOGY).build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + 10**18
    m.scan()
    m.configure()
    return m


def coe_io(m: Master):  # type: ignore[no-untyped-def]
    return next(s for s in m.slaves if s.name.startswith("PEC-COEIO"))


def test_slaves_with_sync0_get_dc_mode_and_their_cyclic_unit() -> None:
    m = open_demo()
    m.dc.setup(DcSettings(static_sync=300))
    sync = m.dc.configure_sync(1_000_000, 50_000)
    assert len(sync) == 2 and all(st.assign_activate == 0x0300 for st in sync.values())
    m.pd.bring_up(m.slaves, 5.0)
    a = coe_io(m)
    assert a.al_state == AlState.SAFEOP
    assert a.sdo_read(OUT, SyncSub.SYNC_MODE, "uint16") == SyncMode.DC_SYNC0
    assert a.sdo_read(IN, SyncSub.SYNC_MODE, "uint16") == SyncMode.DC_SYNC0
    # the cyclic unit runs SYNC0 from a start time on the 1 ms grid, shifted by 50 us
    act, start, cycle = (m.read(a, R.DC_CYCLIC_UNIT_CONTROL, 2),
                         struct.unpack("<Q", m.read(a, R.DC_START_TIME, 8))[0],
                         struct.unpack("<I", m.read(a, R.DC_SYNC0_CYCLE, 4))[0])
    assert act == b"\x00\x03" and cycle == 1_000_000 and start % 1_000_000 == 50_000
    status = {st.position: st for st in m.dc.status()}[a.position]
    assert status.assign_activate is not None and status.assign_activate.sync0


def test_a_slave_needing_dc_without_it_is_refused_with_its_al_code() -> None:
    m = open_demo()
    a = coe_io(m)
    m.set_state("PREOP")
    a.sdo_write(OUT, SyncSub.SYNC_MODE, int(SyncMode.DC_SYNC0), "uint16")
    with pytest.raises(AlStatusError) as err:
        m.pd.bring_up(m.slaves, 5.0)
    assert err.value.code == AlStatusCode.INVALID_DC_SYNC_CONFIG


def test_a_slave_left_in_dc_mode_goes_back_to_sm_event_when_it_gets_no_pulses() -> None:
    m = open_demo()
    a = coe_io(m)
    m.set_state("PREOP")
    a.sdo_write(OUT, SyncSub.SYNC_MODE, int(SyncMode.DC_SYNC0), "uint16")
    m.dc.setup(DcSettings(static_sync=0))
    m.dc.configure_sync(1_000_000, slaves=[s for s in m.slaves[1:] if s is not a])
    m.pd.bring_up(m.slaves, 5.0)
    assert a.al_state == AlState.SAFEOP
    assert a.sdo_read(OUT, SyncSub.SYNC_MODE, "uint16") == SyncMode.SM_EVENT


def test_sync0_cycle_below_the_device_minimum_is_refused() -> None:
    m = open_demo()
    m.dc.setup(DcSettings(static_sync=0))
    a = coe_io(m)
    m.dc.configure_sync(50_000, slaves=[a])  # 50 us; the device's minimum is 100 us
    with pytest.raises(AlStatusError) as err:
        m.pd.bring_up(m.slaves, 5.0)
    assert err.value.code == AlStatusCode.DC_INVALID_SYNC0_CYCLE_TIME


def test_the_esi_op_mode_wins_over_the_sii_and_its_assign_activate_reaches_0x0980(
        tmp_path: Path) -> None:
    """The slave's EEPROM says DC-Synchron 0x0300; the ESI the master is given says 0x0730
    (cyclic unit, SYNC0 and SYNC1, both latch units on the PDI): 0x0730 is written."""
    from pyethercat.esi.bundled import bundled_esi
    from pyethercat.master.clocks import sync_assign_activate
    from pyethercat.master.esi_config import apply_esi_config, esi_specs

    clock = VirtualClock(1_000_000_000)
    seg = parse_topology('[[slave]]\nname = "drive"\nesi = "builtin:seed002_drive.xml"\n'
                         ).build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + 10**18
    m.scan()
    drive = m.slaves[0]
    assert drive.sii is not None
    assert [mode.assign_activate for mode in drive.sii.dc_modes] == [0x0000, 0x0300]
    assert sync_assign_activate(drive) == 0x0300  # from the SII alone
    esi = bundled_esi("seed002_drive.xml").read_text()
    assert esi.count("<AssignActivate>#x300</AssignActivate>") == 1
    mine = tmp_path / "drive.xml"
    mine.write_text(esi.replace("<AssignActivate>#x300</AssignActivate>",
                                "<AssignActivate>#x730</AssignActivate>"))
    specs = esi_specs([(mine, None, None)])
    # the ESI's first op mode, SM-synchronous: no SYNC pulses, whatever the SII offers
    apply_esi_config(m, specs)
    assert drive.dc_op_mode is not None and drive.dc_op_mode.op_mode == "Synchron"
    assert sync_assign_activate(drive) == 0
    specs[0].op_mode = "DC"
    apply_esi_config(m, specs)
    assert drive.dc_op_mode is not None and drive.dc_op_mode.op_mode == "DC"
    assert sync_assign_activate(drive) == 0x0730
    m.dc.setup(DcSettings(static_sync=0))
    sync = m.dc.configure_sync(1_000_000, 0, sync1_delay_ns=100_000)
    assert sync[0].assign_activate == 0x0730
    m.dc.apply_sync()
    assert m.read(drive, R.DC_CYCLIC_UNIT_CONTROL, 2) == b"\x30\x07"
    assert struct.unpack("<II", m.read(drive, R.DC_SYNC0_CYCLE, 8)) == (1_000_000, 100_000)
