"""Mailbox link layer of the simulated slave under the sequences SOEM produces when it times out.

Each test replays, frame by frame, a sequence seen in captures of pysoem against
the simulator on a loaded machine (see docs/simulator.md, "Mailbox under
master timeouts"): a reply read by the slave but given up by the master, the
repeat request that follows (facts 6.6), a second reply already queued behind
the lost one, the mailbox stopped in INIT with a reply still unread (facts 3.13:
a deactivated SM loses its buffer state).
"""

from __future__ import annotations

import struct

import pytest
from coehelp import MBX_IN, MBX_OUT, MBX_SIZE, CoeSlave, coe_of, sm_bytes

from pyethercat.sim.coe import coe_server
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import (
    Emergency,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
)
from pyethercat.wire.mailbox.header import MailboxHeader

SM1 = R.sm_address(1)


@pytest.fixture
def slave() -> CoeSlave:
    return CoeSlave()


def repeat_request(slave: CoeSlave) -> int:
    """SOEM's repeat request: read 0x080D..0x080E, toggle activate bit 1, write both back.

    Returns the new repeat bit after waiting for the slave's acknowledge (0x080F bit 1).
    """
    status_act = bytearray(slave.fprd(SM1 + R.SM_STATUS, 2).data)
    status_act[1] ^= R.SM_ACTIVATE_REPEAT
    assert slave.fpwr(SM1 + R.SM_STATUS, bytes(status_act)) == 1
    repeat = status_act[1] & R.SM_ACTIVATE_REPEAT
    ack = slave.fprd(SM1 + R.SM_PDI_CONTROL, 1).data[0] & R.SM_PDI_REPEAT_ACK
    assert bool(ack) == bool(repeat), "repeat request not acknowledged"
    return repeat


def sm1_full(slave: CoeSlave) -> bool:
    return bool(slave.fprd(SM1 + R.SM_STATUS, 1).data[0] & R.SM_STATUS_MAILBOX_FULL)


def test_repeat_resends_the_read_reply_not_the_one_posted_after_it(slave: CoeSlave) -> None:
    # Two replies waiting: the first in SM1, the second queued behind it.
    slave.send(SdoInitiateUploadRequest(0x1018, 1).encode())
    slave.send(SdoInitiateUploadRequest(0x1018, 2).encode())
    lost = slave.fetch()  # read by the slave, but the master gave the frame up
    assert lost is not None and coe_of(lost).subindex == 1  # type: ignore[attr-defined]
    # Reading SM1 let the slave post the queued reply at once.
    assert sm1_full(slave)
    repeat_request(slave)
    again = slave.fetch()
    assert again == lost  # the repeat brings back what was read, not the newer reply
    following = slave.fetch()
    assert following is not None and coe_of(following).subindex == 2  # type: ignore[attr-defined]
    assert slave.fetch() is None


def test_repeat_twice_before_reading_keeps_the_withdrawn_reply(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1018, 1).encode())
    slave.send(SdoInitiateUploadRequest(0x1018, 2).encode())
    slave.send(SdoInitiateUploadRequest(0x1018, 3).encode())
    lost = slave.fetch()
    repeat_request(slave)
    repeat_request(slave)  # the master times out on the repeated one too, before reading it
    assert slave.fetch() == lost
    subs = []
    while (raw := slave.fetch()) is not None:
        subs.append(coe_of(raw).subindex)  # type: ignore[attr-defined]
    assert subs == [2, 3]


def test_repeat_after_the_repeated_reply_was_read_resends_it_again(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1018, 1).encode())
    lost = slave.fetch()
    repeat_request(slave)
    assert slave.fetch() == lost
    repeat_request(slave)  # lost once more
    assert slave.fetch() == lost
    assert slave.fetch() is None


def test_repeat_with_nothing_read_yet_leaves_the_posted_reply(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1018, 1).encode())
    posted = bytes(slave.seg.slaves[0].esc.row[MBX_IN: MBX_IN + MBX_SIZE].tobytes())
    repeat_request(slave)  # the request frame never reached the slave: nothing was read
    assert slave.fetch() == posted
    assert slave.fetch() is None


def test_soem_segmented_upload_with_a_late_sm1_read(slave: CoeSlave) -> None:
    """The sequence of a failed pysoem run: the answers lag one request behind
    (an SM0 write SOEM had given up on was served), then a late SM1 read and a
    repeat request. The master must still receive every segment exactly once."""
    header = SdoInitiateUploadRequest(0x2000, 0)
    slave.send(header.encode())
    first = coe_of(slave.fetch() or b"")
    assert isinstance(first, SdoInitiateUploadResponse)
    data = bytearray(first.data)
    toggle = False
    # Segment request 1 is served, but the master timed out on its FPWR: it sends
    # request 2 right away (toggle flipped, as SOEM's loop does), so from now on
    # each SM1 read returns the answer to the previous request.
    slave.send(SdoUploadSegmentRequest(toggle).encode())
    toggle = not toggle
    slave.send(SdoUploadSegmentRequest(toggle).encode())
    toggle = not toggle
    rounds = 0
    while True:
        raw = slave.fetch()
        assert raw is not None
        if rounds == 5:
            # this read reaches the slave late: the master has given it up and
            # asks for a repeat; the slave posted the next reply meanwhile
            repeat_request(slave)
            again = slave.fetch()
            assert again == raw
            raw = again
        seg = coe_of(raw)
        assert isinstance(seg, SdoUploadSegmentResponse)
        data += seg.data
        if seg.last:
            break
        slave.send(SdoUploadSegmentRequest(toggle).encode())
        toggle = not toggle
        rounds += 1
    assert bytes(data) == bytes(i & 0xFF for i in range(4096))


def test_unread_reply_does_not_survive_init(slave: CoeSlave) -> None:
    """Facts 3.13/6.5: stopping the mailbox (INIT) deactivates SM0/SM1, which drops
    their buffer state; the next session starts with an empty SM1."""
    coe_server(slave.app).emergency(0x1000, 1)
    coe_server(slave.app).emergency(0x2000, 2)
    assert sm1_full(slave)
    assert slave.request_state(AlState.INIT)[0] == int(AlState.INIT)
    # the next master writes the same SM configuration again (no change for the ESC)
    slave.fpwr(R.sm_address(0), sm_bytes(MBX_OUT, MBX_SIZE, R.SM_CONTROL_MAILBOX_OUT))
    slave.fpwr(R.sm_address(1), sm_bytes(MBX_IN, MBX_SIZE, R.SM_CONTROL_MAILBOX_IN))
    assert not sm1_full(slave)
    assert slave.request_state(AlState.PREOP)[0] == int(AlState.PREOP)
    assert not sm1_full(slave)
    assert slave.fetch() is None  # working counter 0: nothing left over
    # a repeat request in the new session has no old mailbox to bring back
    repeat_request(slave)
    assert slave.fetch() is None
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode(), counter=1)
    header, msg = slave.fetch_message()
    assert isinstance(msg, SdoInitiateUploadResponse) and header.counter == 1


def test_sm1_disabled_by_the_master_drops_the_unread_reply(slave: CoeSlave) -> None:
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode())
    assert sm1_full(slave)
    assert slave.fpwr(SM1 + R.SM_ACTIVATE, b"\x00") == 1
    assert not sm1_full(slave)
    assert slave.fpwr(SM1 + R.SM_ACTIVATE, b"\x01") == 1
    assert not sm1_full(slave) and slave.fetch() is None


def test_emergency_then_reply_with_repeat_in_between(slave: CoeSlave) -> None:
    """SOEM files an emergency it reads while waiting for an SDO reply; a repeat
    request after the emergency was read must not skip the reply behind it."""
    coe_server(slave.app).emergency(0x8210, 0x10)
    slave.send(SdoInitiateUploadRequest(0x1000, 0).encode())
    emcy = slave.fetch()
    assert emcy is not None and isinstance(coe_of(emcy), Emergency)
    repeat_request(slave)
    assert slave.fetch() == emcy
    reply = slave.fetch()
    assert reply is not None
    assert isinstance(coe_of(reply), SdoInitiateUploadResponse)
    assert MailboxHeader.decode(reply).counter == MailboxHeader.decode(emcy).counter % 7 + 1


def test_sm0_status_word_write_by_soem_leaves_sm0_alone(slave: CoeSlave) -> None:
    # SOEM writes status and activate together; the status byte is read-only.
    before = slave.fprd(SM1, 8).data
    status_act = bytearray(before[R.SM_STATUS: R.SM_STATUS + 2])
    assert slave.fpwr(SM1 + R.SM_STATUS, struct.pack("<BB", 0xFF, status_act[1])) == 1
    assert slave.fprd(SM1, 8).data == before
