"""The CiA download sequences for PDO mapping and assignment objects (one builder for
``CoeClient.write_pdo_mapping``/``write_pdo_assignment`` and ``set_pdo_mapping``)."""

from __future__ import annotations

from pyethercat.master.coe import pdo_assignment_writes, pdo_mapping_writes


def test_mapping_writes_clear_sub0_write_entries_then_count() -> None:
    assert pdo_mapping_writes(0x1A00, [(0x6000, 1, 1), (0, 0, 7)]) == [
        (0x1A00, 0, b"\x00"),
        (0x1A00, 1, bytes.fromhex("01010060")),  # 0x60000101: index 6000, sub 1, 1 bit
        (0x1A00, 2, bytes.fromhex("07000000")),  # a 7-bit gap
        (0x1A00, 0, b"\x02"),
    ]


def test_assignment_writes_go_to_0x1c10_plus_sm() -> None:
    assert pdo_assignment_writes(3, [0x1A00, 0x1A01]) == [
        (0x1C13, 0, b"\x00"),
        (0x1C13, 1, b"\x00\x1a"),
        (0x1C13, 2, b"\x01\x1a"),
        (0x1C13, 0, b"\x02"),
    ]
    assert pdo_assignment_writes(2, []) == [(0x1C12, 0, b"\x00"), (0x1C12, 0, b"\x00")]
