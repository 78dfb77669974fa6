"""The one fragment reassembler the SDO information, SoE and EoE reassemblers share."""

from __future__ import annotations

import pytest

from pyethercat.errors import MailboxError
from pyethercat.wire.mailbox.fragments import FragmentReassembler


def _down(strict: bool = True, limit: int = 1 << 20) -> FragmentReassembler:
    return FragmentReassembler("test", key_name="opcode", sequence_name="left", step=-1,
                               strict=strict, limit=limit)


def test_counting_down_joins_in_order() -> None:
    r = _down()
    assert r.feed(b"ab", key=2, sequence=2, last=False) is None
    assert r.in_progress and r.key == 2 and r.received == 2
    assert r.feed(b"cd", key=2, sequence=1, last=False) is None
    assert r.feed(b"e", key=2, sequence=0, last=True) == b"abcde"
    assert not r.in_progress and r.key is None


def test_strict_count_refuses_a_gap_loose_count_only_the_direction() -> None:
    r = _down()
    r.feed(b"a", key=1, sequence=5, last=False)
    with pytest.raises(MailboxError, match="left 3 where 4 was expected"):
        r.feed(b"b", key=1, sequence=3, last=False)
    assert not r.in_progress
    loose = _down(strict=False)
    loose.feed(b"a", key=1, sequence=5, last=False)
    assert loose.feed(b"b", key=1, sequence=3, last=False) is None
    with pytest.raises(MailboxError, match="does not follow"):
        loose.feed(b"c", key=1, sequence=3, last=False)


def test_key_change_offset_capacity_and_limit() -> None:
    r = _down()
    r.feed(b"a", key=1, sequence=2, last=False)
    with pytest.raises(MailboxError, match="opcode 7 inside a message with opcode 1"):
        r.feed(b"b", key=7, sequence=1, last=False)
    up = FragmentReassembler("eoe", key_name="frame", sequence_name="fragment", step=1)
    up.feed(b"x" * 32, key=0, sequence=0, last=False, first=True, capacity=64)
    with pytest.raises(MailboxError, match="offset 64 bytes, 32 received"):
        up.feed(b"y", key=0, sequence=1, last=False, first=False, offset=64)
    up.feed(b"x" * 32, key=0, sequence=0, last=False, first=True, capacity=64)
    with pytest.raises(MailboxError, match="exceed the announced 64-byte"):
        up.feed(b"y" * 33, key=0, sequence=1, last=True, first=False, offset=32)
    small = _down(limit=4)
    small.feed(b"abc", key=1, sequence=1, last=False)
    with pytest.raises(MailboxError, match="exceeds 4 bytes"):
        small.feed(b"de", key=1, sequence=0, last=True)


def test_a_new_first_fragment_drops_the_unfinished_message() -> None:
    up = FragmentReassembler("eoe", key_name="frame", sequence_name="fragment", step=1)
    with pytest.raises(MailboxError, match="without the first fragment"):
        up.feed(b"a", key=0, sequence=1, last=False, first=False)
    up.feed(b"a", key=0, sequence=0, last=False, first=True)
    assert up.feed(b"b", key=1, sequence=0, last=True, first=True) == b"b"
    assert up.dropped == 1
