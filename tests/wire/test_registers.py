"""The shared register map against the facts sheet (section 3), entry by entry."""

from __future__ import annotations

import pytest

from pyethercat.wire import registers as R
from pyethercat.wire.registers import RegisterAccess

RW, RO = RegisterAccess.RW, RegisterAccess.R

# (address, size, access) as facts sheet section 3 gives them.
FACTS = [
    (0x0000, 1, RO), (0x0001, 1, RO), (0x0002, 2, RO), (0x0004, 1, RO), (0x0005, 1, RO),
    (0x0006, 1, RO), (0x0007, 1, RO), (0x0008, 2, RO),
    (0x0010, 2, RW), (0x0012, 2, RO), (0x0040, 1, RW),
    (0x0100, 4, RW), (0x0108, 2, RW), (0x0110, 2, RO),
    (0x0120, 2, RW), (0x0130, 2, RO), (0x0134, 2, RO), (0x0140, 1, RO), (0x0141, 1, RO),
    (0x0200, 2, RW), (0x0204, 4, RO), (0x0210, 2, RO), (0x0220, 4, RO),
    (0x0300, 1, RW), (0x0301, 1, RW), (0x0306, 1, RW), (0x0307, 1, RW), (0x0308, 1, RW),
    (0x030B, 1, RW), (0x030C, 1, RW), (0x030D, 1, RW), (0x030E, 2, RO), (0x0310, 1, RW),
    (0x0313, 1, RW),
    (0x0400, 2, RW), (0x0410, 2, RW), (0x0420, 2, RW), (0x0440, 2, RO), (0x0442, 1, RW),
    (0x0443, 1, RW),
    (0x0500, 1, RW), (0x0501, 1, RO), (0x0502, 2, RW), (0x0504, 4, RW), (0x0508, 8, RW),
    (0x0510, 2, RW), (0x0512, 1, RW), (0x0513, 1, RW), (0x0514, 2, RW), (0x0516, 1, RW),
    (0x0517, 1, RO), (0x0518, 1, RO), (0x051B, 1, RO),
    (0x0900, 4, RW), (0x0904, 4, RO), (0x0908, 4, RO), (0x090C, 4, RO), (0x0910, 8, RW),
    (0x0918, 8, RO), (0x0920, 8, RW), (0x0928, 4, RW), (0x092C, 4, RO), (0x0930, 2, RW),
    (0x0932, 2, RO), (0x0934, 1, RW), (0x0935, 1, RW), (0x0980, 1, RW), (0x0981, 1, RW),
    (0x0982, 2, RO), (0x0984, 1, RO), (0x098E, 1, RO), (0x098F, 1, RO), (0x0990, 8, RW),
    (0x0998, 8, RO), (0x09A0, 4, RW), (0x09A4, 4, RW), (0x09A8, 1, RW), (0x09A9, 1, RW),
    (0x09AE, 1, RO), (0x09AF, 1, RO), (0x09B0, 8, RO), (0x09B8, 8, RO), (0x09C0, 8, RO),
    (0x09C8, 8, RO), (0x09F0, 4, RO), (0x09F8, 4, RO), (0x09FC, 4, RO),
    (0x0F80, 128, RW),
]


@pytest.mark.parametrize(("address", "size", "access"), FACTS, ids=[f"0x{a:04X}" for a, _, _ in FACTS])
def test_register_as_in_the_facts_sheet(address: int, size: int, access: RegisterAccess) -> None:
    reg = R.register_at(address)
    assert reg is not None
    assert (reg.size, reg.access) == (size, access), reg.name


def test_fmmu_and_sm_blocks() -> None:
    for n in (0, 7, 15):
        base = 0x0600 + 16 * n
        assert R.fmmu_address(n) == base
        sizes = {off: R.register_at(base + off).size for off in (0, 4, 6, 7, 8, 0xA, 0xB, 0xC)}  # type: ignore[union-attr]
        assert sizes == {0: 4, 4: 2, 6: 1, 7: 1, 8: 2, 0xA: 1, 0xB: 1, 0xC: 1}
        sm = 0x0800 + 8 * n
        assert R.sm_address(n) == sm
        got = [(r.size, r.access) for r in (R.register_at(sm + o) for o in range(8)) if r]
        assert got == [(2, RW), (2, RW), (1, RW), (1, RO), (1, RW), (1, RO)]


def test_no_two_registers_overlap_and_names_resolve() -> None:
    for a, b in zip(R.REGISTERS, R.REGISTERS[1:], strict=False):
        assert a.address + a.size <= b.address, (a, b)
    assert R.register_name(0x0130) == "AL status"
    assert R.register_name(0x0101) == "DL control+1"
    assert R.register_name(0x0003) == "Build+1"
    assert R.register_name(0x1000) is None and R.register_name(0x0009 + 1) is None


def test_bit_values() -> None:
    # Control bytes of facts 3.13, composed and as constants.
    assert R.sm_control(R.SmMode.MAILBOX, R.SmDirection.WRITE) == R.SM_CONTROL_MAILBOX_OUT == 0x26
    assert R.sm_control(R.SmMode.MAILBOX, R.SmDirection.READ) == R.SM_CONTROL_MAILBOX_IN == 0x22
    assert R.sm_control(R.SmMode.BUFFERED, R.SmDirection.WRITE, watchdog=True) == 0x64
    assert R.sm_control(R.SmMode.BUFFERED, R.SmDirection.READ) == R.SM_CONTROL_INPUTS == 0x20
    assert (R.SM_STATUS_MAILBOX_FULL, R.SM_STATUS_BUFFER_MASK) == (0x08, 0x30)
    assert (R.SM_ACTIVATE_REPEAT, R.SM_PDI_REPEAT_ACK) == (0x02, 0x02)
    assert R.Feature.DC_SUPPORTED | R.Feature.DC_64BIT | R.Feature.ENHANCED_DC_SYNC == 0x010C
    assert R.Feature.LRW_NOT_SUPPORTED == 0x0200 and R.Feature.FIXED_FMMU_SM == 0x0800
    assert [R.dl_status_link(p) for p in range(4)] == [0x10, 0x20, 0x40, 0x80]
    assert [R.dl_status_loop(p) | R.dl_status_com(p) for p in range(4)] == [
        0x0300, 0x0C00, 0x3000, 0xC000]
    assert R.DL_CONTROL_ALIAS_ENABLE == 1 << 24 and R.DL_CONTROL_ALIAS == 0x0103
    assert R.port_types(0x0F) == [R.PortType.MII, R.PortType.MII,
                                  R.PortType.NOT_IMPLEMENTED, R.PortType.NOT_IMPLEMENTED]
    assert (R.AL_STATE_MASK, R.AL_ERROR_FLAG, R.AL_ID_FLAG) == (0x0F, 0x10, 0x20)
    assert R.ecat_event_sm(0) == 0x10 and R.ecat_event_sm(7) == 0x0800  # KickCAT/gatorcat
    assert R.EcatEvent.DL_STATUS == 0x04 and R.EcatEvent.AL_STATUS == 0x08
    assert R.al_event_sm(0) == 0x100 and R.AlEvent.WATCHDOG == 0x40
    assert (R.SiiControl.CMD_READ, R.SiiControl.CMD_WRITE, R.SiiControl.CMD_RELOAD) == (
        0x0100, 0x0200, 0x0400)
    assert (R.SII_ERROR_MASK, R.SiiControl.BUSY, R.SiiControl.READ_8_BYTES) == (0x7800, 0x8000, 0x40)
    assert (R.FmmuType.READ, R.FmmuType.WRITE) == (1, 2)
    assert R.DcActivation.CYCLIC | R.DcActivation.SYNC0 == 0x03
    assert R.DcActivation.CYCLIC | R.DcActivation.SYNC0 | R.DcActivation.SYNC1 == 0x07
    assert R.watchdog_unit_ns(R.WATCHDOG_DIVIDER_DEFAULT) == 100_000
    assert tuple(b"RES") == R.ESC_RESET_SEQUENCE
    assert (R.DC_SPEED_COUNTER_START_DEFAULT, R.DC_TIME_FILTER_DEPTH_DEFAULT,
            R.DC_SPEED_FILTER_DEPTH_DEFAULT) == (0x1000, 4, 12)


def test_esc_features_decoded_once_for_master_and_simulator() -> None:
    """Master's EscInfo and simulator's EscProfile read 0x0008 through the same mixin."""
    from pyethercat.master.slave import EscInfo
    from pyethercat.sim.profiles import PROFILES

    class Word(R.EscFeaturesMixin):
        def __init__(self, features: int) -> None:
            self.features = features

    ek1100 = Word(0x00FC)  # corpus EK1100 register 0x0008
    assert (ek1100.dc_supported, ek1100.dc_64bit, ek1100.lrw_supported) == (True, True, True)
    assert (ek1100.rw_supported, ek1100.bitwise_fmmu, ek1100.fixed_fmmu_sm) == (True, True, False)
    limited = Word(0x0E01)  # byte FMMUs, no LRW, no RW, fixed FMMU/SM, no DC
    assert (limited.dc_supported, limited.dc_64bit, limited.lrw_supported) == (False, False, False)
    assert (limited.rw_supported, limited.bitwise_fmmu, limited.fixed_fmmu_sm) == (False, False, True)
    for word in (0x00FC, 0x0E01, 0x0004):
        master_view, sim_view = EscInfo(features=word), PROFILES["ET1100"].replace(features=word)
        for name in ("dc_supported", "dc_64bit", "lrw_supported", "rw_supported",
                     "bitwise_fmmu", "fixed_fmmu_sm"):
            assert getattr(master_view, name) == getattr(sim_view, name) == getattr(Word(word), name)


def test_port_descriptor_round_trip() -> None:
    for descriptor in range(256):
        assert R.port_descriptor(R.port_types(descriptor)) == descriptor
    assert R.port_descriptor([R.PortType.EBUS, R.PortType.EBUS]) == 0x0A
    implemented = [t for t in R.PortType if t.implemented]
    assert implemented == [R.PortType.EBUS, R.PortType.MII]
