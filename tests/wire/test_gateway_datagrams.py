"""ETG.8200 gateway datagrams: the layout IgH's README shows, and what gets dropped."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.wire.gateway import (
    GATEWAY_PORT,
    GatewayError,
    decode_gateway_request,
    encode_gateway_reply,
    gateway_target,
)
from pyethercat.wire.mailbox.header import MailboxType

#: The request of IgH's mailbox_gateway/README: CoE SDO upload 0x1018:01 to address 4.
IGH_EXAMPLE = bytes.fromhex("10500A000400000300204018100100000000")
#: Its answer there (a Beckhoff module: vendor id 2).
IGH_ANSWER = bytes.fromhex("10500a000400002300304318100102000000")


def test_igh_readme_request_and_answer() -> None:
    assert GATEWAY_PORT == 34980
    req = decode_gateway_request(IGH_EXAMPLE)
    assert req.address == 4 and req.header.type == MailboxType.COE
    assert req.header.length == 10 and req.payload == IGH_EXAMPLE[8:]
    answer = IGH_ANSWER[2:]
    assert encode_gateway_reply(answer) == IGH_ANSWER


@pytest.mark.parametrize("datagram,reason", [
    (b"", "short"),
    (IGH_EXAMPLE[:7], "short"),
    (bytes.fromhex("1010") + IGH_EXAMPLE[2:], "type"),  # type 1: datagrams
    (bytes.fromhex("1058") + IGH_EXAMPLE[2:], "header"),  # reserved bit 11
    (bytes.fromhex("2050") + IGH_EXAMPLE[2:], "length"),  # says 32 bytes
    (bytes.fromhex("1050") + bytes.fromhex("0B00") + IGH_EXAMPLE[4:], "length"),
    (bytes.fromhex("0650") + bytes.fromhex("000004000003"), "length"),  # mailbox length 0
])
def test_bad_datagrams_have_a_reason(datagram: bytes, reason: str) -> None:
    with pytest.raises(GatewayError) as info:
        decode_gateway_request(datagram)
    assert info.value.reason == reason


def test_trailing_bytes_after_the_mailbox_are_ignored() -> None:
    req = decode_gateway_request(IGH_EXAMPLE + b"\x00" * 6)
    assert req.mailbox == IGH_EXAMPLE[2:]


def test_address_mapping_igh_kickcat_and_master() -> None:
    stations = [0x1001, 0x1002, 0x1003]
    assert gateway_target(0, stations) == -1
    assert gateway_target(0x1002, stations) == 1  # station address (KickCAT, ETG.1510)
    assert gateway_target(1000, stations) == 0  # IgH: position + 1000
    assert gateway_target(1002, stations) == 2
    assert gateway_target(1003, stations) is None
    assert gateway_target(4, stations) is None
    # KickCAT numbers its slaves 1001...: the station address wins over IgH's rule
    assert gateway_target(1001, [1001, 1002]) == 0


@given(st.binary(max_size=64))
def test_decoder_never_raises_anything_else(data: bytes) -> None:
    try:
        req = decode_gateway_request(data)
    except GatewayError:
        return
    assert len(req.mailbox) == 6 + req.header.length
