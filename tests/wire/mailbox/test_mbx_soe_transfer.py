"""SoE service state machines and element encodings."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import MailboxError, SoeAbort, SoeTimeoutError
from pyethercat.wire.mailbox.header import encode_mailbox
from pyethercat.wire.mailbox.soe import (
    SoeElement,
    SoeMessage,
    SoeOpCode,
    SoeReassembler,
    decode_soe,
)
from pyethercat.wire.mailbox.soe_transfer import (
    SoeAttribute,
    SoeDataType,
    SoeReadClient,
    SoeWriteClient,
    decode_soe_list,
    decode_soe_text,
    encode_soe_list,
    encode_soe_text,
    soe_error_response,
    soe_read_response_fragments,
)


def test_attribute_bits_as_soem_reads_them() -> None:
    # SOEM ec_SoEattributet: factor 15:0, length 17:16, list 18, command 19, type 22:20,
    # decimals 27:24, write protection 28/29/30
    a = SoeAttribute(4, SoeDataType.SIGNED, conversion_factor=1, decimals=3,
                     write_protected_op=True)
    word = int.from_bytes(a.encode(), "little")
    assert word == 1 | 2 << 16 | 2 << 20 | 3 << 24 | 1 << 30
    assert SoeAttribute.decode(a.encode()) == a
    lst = SoeAttribute(2, SoeDataType.IDN, is_list=True)
    assert int.from_bytes(lst.encode(), "little") >> 16 & 0x7F == 1 | 1 << 2 | 5 << 4
    with pytest.raises(MailboxError):
        SoeAttribute(3)


@given(st.sampled_from([1, 2, 4, 8]), st.sampled_from(list(SoeDataType)), st.booleans(),
       st.booleans(), st.integers(0, 0xFFFF), st.integers(0, 15), st.booleans(), st.booleans(),
       st.booleans())
def test_attribute_round_trip(length: int, dtype: SoeDataType, is_list: bool, cmd: bool,
                              factor: int, decimals: int, p: bool, s: bool, o: bool) -> None:
    a = SoeAttribute(length, dtype, is_list, cmd, factor, decimals, p, s, o)
    assert SoeAttribute.decode(a.encode()) == a


def test_lists_and_text() -> None:
    assert encode_soe_list(b"\x18\x00\x10\x00", 16) == bytes.fromhex("0400 1000 1800 1000")
    assert decode_soe_list(encode_soe_list(b"abc", 8)) == (b"abc", 8)
    assert decode_soe_text(encode_soe_text("rpm")) == "rpm"
    with pytest.raises(MailboxError):
        decode_soe_list(bytes.fromhex("0900 1000 01"))  # says 9 bytes, has 1
    with pytest.raises(MailboxError):
        encode_soe_list(bytes(5), 4)


def test_read_client_joins_fragments_and_checks_the_answer() -> None:
    data = bytes(range(256)) * 2
    frags = soe_read_response_fragments(0x0018, data, 64, drive=2)
    assert len(frags) > 1 and all(f.incomplete for f in frags[:-1])
    assert [f.fragments_left for f in frags[:-1]] == list(range(len(frags) - 1, 0, -1))
    client = SoeReadClient(0x0018, drive=2, timeout=1.0)
    req = client.start(5.0)
    assert req == SoeMessage(SoeOpCode.READ_REQUEST, 0x0018, SoeElement.VALUE, 2)
    for f in frags:
        client.receive(decode_soe(f.encode()), 5.1)
    assert client.done and client.data == data
    for f in frags:
        assert len(encode_mailbox(5, f.encode())) <= 64


def test_errors_are_typed_and_wrong_answers_refused() -> None:
    client = SoeReadClient(0x8001, drive=1)
    client.start(0.0)
    with pytest.raises(SoeAbort) as info:
        client.receive(soe_error_response(SoeOpCode.READ_RESPONSE, 0x8001, 0x1001, drive=1),
                       0.0)
    assert info.value.code == 0x1001 and info.value.idn == "P-0-0001"
    assert "no IDN" in str(info.value) and info.value.drive == 1
    other = SoeReadClient(0x20)
    other.start(0.0)
    with pytest.raises(MailboxError, match="drive 3"):
        other.receive(SoeMessage(SoeOpCode.READ_RESPONSE, 0x20, SoeElement.VALUE, 3), 0.0)
    third = SoeReadClient(0x20)
    third.start(0.0)
    with pytest.raises(MailboxError, match="answered for S-0-0033"):
        third.receive(SoeMessage(SoeOpCode.READ_RESPONSE, 0x21, data=b"\x00\x00"), 0.0)


def test_write_client_fragments_and_takes_one_answer() -> None:
    data = bytes(300)
    client = SoeWriteClient(0x0018, data, mailbox_size=128)
    reqs = client.start(0.0)
    assert len(reqs) == 3 and [r.incomplete for r in reqs] == [True, True, False]
    assert reqs[-1].idn == 0x0018 and [r.idn for r in reqs[:-1]] == [2, 1]
    joined = SoeReassembler()
    out = [joined.feed(decode_soe(r.encode())) for r in reqs]
    assert out[-1] is not None and out[-1].data == data
    client.receive(SoeMessage(SoeOpCode.WRITE_RESPONSE, 0x0018), 0.1)
    assert client.done
    refused = SoeWriteClient(0x24, b"\x01\x02", mailbox_size=128)
    refused.start(0.0)
    with pytest.raises(SoeAbort, match="0x7004"):
        refused.receive(soe_error_response(SoeOpCode.WRITE_RESPONSE, 0x24, 0x7004), 0.0)


def test_deadline() -> None:
    client = SoeReadClient(1, timeout=0.25)
    client.start(1.0)
    client.check_deadline(1.2)
    with pytest.raises(SoeTimeoutError, match="S-0-0001"):
        client.check_deadline(1.25)
