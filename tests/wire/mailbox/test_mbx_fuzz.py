"""Mutated and random mailboxes: decoders raise only typed errors (MailboxError)."""

from __future__ import annotations

import contextlib

from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import EtherCATError, MailboxError
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import (
    SdoInfoGetOdListResponse,
    SdoInfoReassembler,
    SdoInitiateUploadResponse,
    SdoUploadClient,
    decode_coe,
    encode_sdo_info_fragments,
)
from pyethercat.wire.mailbox.eoe import EoeFragment, EoeReassembler, decode_eoe, eoe_fragment
from pyethercat.wire.mailbox.foe import decode_foe
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox
from pyethercat.wire.mailbox.soe import SoeReassembler, decode_soe

SEEDS = [
    bytes.fromhex("0020 40 18 10 01 00000000"),
    bytes.fromhex("0030 43 18 10 01 9A020000"),
    bytes.fromhex("0030 41 08 10 00 20000000") + b"0123456789",
    bytes.fromhex("0020 10 61626364656667"),
    bytes.fromhex("0010 3081 11 0102030405"),
    bytes.fromhex("0080 86 00 0200 4060 00 78 0600 1000 3F00 0000 0000 FFFF 0000"),
    bytes.fromhex("0080 04 00 0000 1810 2300 04 09") + b"Identity",
    bytes.fromhex("0200 0000 2F000000 020000000001 C0A8010A FFFFFF00 C0A80101 00000000")
    + bytes(32),
    bytes.fromhex("0013 4200 0102"),
    bytes.fromhex("02 00 00000000") + b"firmware",
    bytes.fromhex("12 40 1800 0110"),
]
TYPES = [MailboxType.COE, MailboxType.EOE, MailboxType.FOE, MailboxType.SOE, MailboxType.ERR]


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(SEEDS)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "cut", "grow", "set"]))
        if op == "flip" and data:
            i = draw(st.integers(0, len(data) - 1))
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and data:
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        elif op == "cut":
            data = data[: draw(st.integers(0, len(data)))]
        else:
            data += draw(st.binary(max_size=8))
    return bytes(data)


@settings(max_examples=400)
@given(mutated())
def test_mutated_payloads(payload: bytes) -> None:
    for decode in (decode_coe, decode_eoe, decode_foe, decode_soe):
        try:
            msg = decode(payload)
        except MailboxError:
            continue
        msg.encode()


@settings(max_examples=300)
@given(
    st.sampled_from(TYPES),
    mutated() | st.binary(max_size=80),
    st.integers(0, 7),
    st.integers(0, 40),
)
def test_mutated_mailboxes(mtype: MailboxType, payload: bytes, counter: int, pad: int) -> None:
    frame = encode_mailbox(mtype, payload, counter=counter, size=6 + len(payload) + pad)
    with contextlib.suppress(MailboxError):
        decode_message(frame)


@given(st.binary(max_size=120))
def test_random_bytes_everywhere(raw: bytes) -> None:
    for decode in (decode_coe, decode_eoe, decode_foe, decode_soe, decode_message):
        with contextlib.suppress(MailboxError):
            decode(raw)


@given(st.lists(st.binary(max_size=40), max_size=8))
def test_info_reassembler_random(frames: list[bytes]) -> None:
    r = SdoInfoReassembler()
    good = encode_sdo_info_fragments(SdoInfoGetOdListResponse(1, tuple(range(30))), 32)
    for f in [*good[:2], *(bytes.fromhex("0080") + x for x in frames), *good]:
        with contextlib.suppress(MailboxError):
            r.feed(f)


@given(
    st.lists(
        st.tuples(
            st.integers(0, 63),
            st.integers(0, 63),
            st.integers(0, 15),
            st.booleans(),
            st.binary(max_size=70),
        ),
        max_size=12,
    )
)
def test_eoe_reassembler_random(frags: list[tuple[int, int, int, bool, bytes]]) -> None:
    r = EoeReassembler()
    for num, off, fno, last, data in [
        *(
            (f.fragment_number, f.offset, f.frame_number, f.last, f.data)
            for f in eoe_fragment(bytes(200), 64)
        ),
        *frags,
    ]:
        try:
            out = r.feed(EoeFragment(data, num, off, fno, last))
        except MailboxError:
            continue
        assert out is None or isinstance(out, bytes)


@given(st.lists(mutated(), max_size=6))
def test_soe_reassembler_and_upload_client_random(payloads: list[bytes]) -> None:
    soe = SoeReassembler()
    client = SdoUploadClient(0x1008, 0)
    client.start()
    client.receive(SdoInitiateUploadResponse(0x1008, 0, b"", expedited=False, complete_size=50))
    for p in payloads:
        with contextlib.suppress(MailboxError):
            soe.feed(decode_soe(p))
        try:
            client.receive(decode_coe(p))
        except EtherCATError as exc:
            assert isinstance(exc, MailboxError)  # SdoAbort is a MailboxError too
