"""The standard CoE object table (facts 7.8, 7.9) and its helpers."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import ConfigError
from pyethercat.wire import mailbox
from pyethercat.wire.mailbox.objects import (
    SM_PDO_ASSIGNMENT_COUNT,
    Cia402Object,
    IdentitySub,
    StandardObject,
    SyncMode,
    SyncModeSupported,
    SyncSub,
    assignment_sm,
    is_pdo_assignment,
    is_pdo_mapping,
    is_rxpdo_mapping,
    is_txpdo_mapping,
    mapping_word,
    sm_pdo_assignment,
    sm_sync_mode,
    split_mapping_word,
)
from pyethercat.wire.sii import SyncManagerType


def test_indices_are_the_facts() -> None:
    s = StandardObject
    assert (s.DEVICE_TYPE, s.ERROR_REGISTER, s.IDENTITY) == (0x1000, 0x1001, 0x1018)
    assert (s.DEVICE_NAME, s.HARDWARE_VERSION, s.SOFTWARE_VERSION) == (0x1008, 0x1009, 0x100A)
    assert (s.ERROR_SETTINGS, s.STATION_ADDRESS) == (0x10F1, 0x1100)
    assert (s.RXPDO_MAPPING_FIRST, s.RXPDO_MAPPING_LAST) == (0x1600, 0x17FF)
    assert (s.TXPDO_MAPPING_FIRST, s.TXPDO_MAPPING_LAST) == (0x1A00, 0x1BFF)
    assert int(s.SM_COMM_TYPE) == 0x1C00
    assert (s.SM_PDO_ASSIGNMENT_FIRST, s.SM_PDO_ASSIGNMENT_LAST) == (0x1C10, 0x1C2F)
    assert (s.RXPDO_ASSIGNMENT, s.TXPDO_ASSIGNMENT) == (0x1C12, 0x1C13)
    assert (s.SM_OUTPUT_SYNC, s.SM_INPUT_SYNC) == (0x1C32, 0x1C33)
    assert StandardObject(0x1018).name == "IDENTITY"
    assert [int(m) for m in IdentitySub] == [1, 2, 3, 4]
    assert (Cia402Object.CONTROLWORD, Cia402Object.STATUSWORD) == (0x6040, 0x6041)
    assert int(Cia402Object.POSITION_ACTUAL_VALUE) == 0x6064


def test_package_exports() -> None:
    assert mailbox.StandardObject is StandardObject
    assert mailbox.sm_pdo_assignment(3) == 0x1C13
    assert mailbox.is_rxpdo_mapping(0x1600) and mailbox.is_txpdo_mapping(0x1A00)
    assert int(mailbox.SyncSub.CYCLE_TIME) == 2


def test_sm_pdo_assignment_range() -> None:
    assert SM_PDO_ASSIGNMENT_COUNT == 32
    assert sm_pdo_assignment(0) == 0x1C10
    assert sm_pdo_assignment(2) == StandardObject.RXPDO_ASSIGNMENT
    assert sm_pdo_assignment(31) == 0x1C2F
    for bad in (-1, 32):
        with pytest.raises(ConfigError, match=f"SM{bad} "):
            sm_pdo_assignment(bad)
    assert assignment_sm(0x1C13) == 3
    assert is_pdo_assignment(0x1C2F) and not is_pdo_assignment(0x1C30)
    assert not is_pdo_assignment(0x1C0F)
    with pytest.raises(ConfigError, match="0x1C32"):
        assignment_sm(0x1C32)


@given(st.integers(0, 31))
def test_assignment_round_trip(sm: int) -> None:
    assert assignment_sm(sm_pdo_assignment(sm)) == sm


@pytest.mark.parametrize(("index", "rx", "tx"), [
    (0x15FF, False, False), (0x1600, True, False), (0x17FF, True, False),
    (0x1800, False, False), (0x19FF, False, False), (0x1A00, False, True),
    (0x1BFF, False, True), (0x1C00, False, False), (0x1C12, False, False),
])
def test_mapping_ranges(index: int, rx: bool, tx: bool) -> None:
    assert is_rxpdo_mapping(index) is rx
    assert is_txpdo_mapping(index) is tx
    assert is_pdo_mapping(index) is (rx or tx)


def test_mapping_word_example_and_limits() -> None:
    # SOEM's example (facts 7.8): object 0x6010, subindex 7, 16 bits.
    assert mapping_word(0x6010, 7, 16) == 0x60100710
    assert split_mapping_word(0x60100710) == (0x6010, 7, 16)
    assert mapping_word(0, 0, 7) == 0x00000007  # a 7-bit gap
    for args in ((0x10000, 0, 8), (0x6000, 0x100, 8), (0x6000, 1, 256), (-1, 0, 8)):
        with pytest.raises(ConfigError, match="out of range"):
            mapping_word(*args)


@given(st.integers(0, 0xFFFF), st.integers(0, 0xFF), st.integers(0, 0xFF))
def test_mapping_word_round_trip(index: int, sub: int, bits: int) -> None:
    word = mapping_word(index, sub, bits)
    assert 0 <= word <= 0xFFFFFFFF
    assert word.to_bytes(4, "little")[0] == bits  # the length is the first byte on the wire
    assert split_mapping_word(word) == (index, sub, bits)


def test_sync_objects() -> None:
    assert (SyncSub.SYNC_MODE, SyncSub.SYNC0_CYCLE_TIME) == (1, 0x0A)
    assert (SyncSub.RXPDO_TOGGLE_FAILED, SyncSub.MAX_SM_SYNC_DISTANCE) == (0x0E, 0x12)
    assert int(SyncSub.SYNC_ERROR) == 0x20
    assert [int(m) for m in SyncMode] == [0, 1, 2, 3, 0x22]
    assert sm_sync_mode(2) == SyncMode.SM2_EVENT
    with pytest.raises(ConfigError):
        sm_sync_mode(32)
    assert int(SyncModeSupported.FREE_RUN | SyncModeSupported.SYNCHRONOUS
               | SyncModeSupported.DC_SYNC0) == 0x0007
    assert int(SyncModeSupported.SUBORDINATED_CYCLES) == 0x10


def test_sm_comm_types_are_the_sii_codes() -> None:
    # 0x1C00 sub n+1 uses the SyncM type numbering (facts 7.8 and 5.5).
    assert [int(t) for t in SyncManagerType] == [0, 1, 2, 3, 4]
