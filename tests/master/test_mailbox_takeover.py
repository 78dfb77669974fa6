"""Our master takes over slaves that another master left in PREOP (simulated segment).

A slave drops a mailbox request whose counter repeats the last one it took,
and a slave another master used remembers that master's last counter (1..7).
The other master here is a second ``Master`` on the same simulated segment
(builtin:coe-io), which numbers its requests as SOEM does: 1, 2, ... 7, 1.
After it did k uploads, a fresh master (scan without reset, the slave stays
in PREOP) must read the object: with k = 1 or 8 its first request (counter 1)
is dropped, so it is sent again with counter 2. A reply the other master
never read is dropped before the first request.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.coe import SdoInitiateUploadRequest
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType

TOPOLOGY = '[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n'
VENDOR, PRODUCT = 0x00504543, 0x00050001


class Recorder:
    """The segment's responder, keeping what the master sent."""

    def __init__(self, seg: object) -> None:
        self.seg = seg
        self.sent: list[bytes] = []

    def __call__(self, frame: bytes) -> bytes | None:
        self.sent.append(bytes(frame))
        return self.seg.process(frame)  # type: ignore[attr-defined,no-any-return]


@pytest.fixture
def segment(tmp_path: Path) -> object:
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "io.toml"
    path.write_text(TOPOLOGY)
    return load_topology(path).build()


def other_master(segment: object, uploads: int) -> Master:
    a = Master(PairLink.responder_link(segment.process), clock=VirtualClock())  # type: ignore[attr-defined]
    a.scan()
    a.set_state("PREOP")
    for _ in range(uploads):
        assert a.slaves[0].sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    return a


def sm0_counters(frames: list[bytes], offset: int) -> list[int]:
    return [MailboxHeader.decode(d.data).counter for f in frames
            for d in decode_frame(f).datagrams if d.command == Command.FPWR and d.ado == offset]


@pytest.mark.parametrize("k", range(9))
def test_upload_after_another_master_did_k_uploads(segment: object, k: int) -> None:
    other_master(segment, k).close()
    rec = Recorder(segment)
    b = Master(PairLink.responder_link(rec), clock=VirtualClock())
    b.scan(reset=False)
    s = b.slaves[0]
    assert s.al_state == AlState.PREOP  # left there by the other master
    assert s.sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert s.mbx is not None
    counters = sm0_counters(rec.sent, s.mbx.rx_offset)
    if k % 7 == 1:
        # the other master's last counter was 1: ours was dropped, then sent as 2
        assert counters == [1, 2] and s.mbx.stats.resent == 1
    else:
        assert counters == [1] and s.mbx.stats.resent == 0
    # and the counters run on from there
    assert s.sdo_read(0x1018, 2, "uint32") == PRODUCT  # type: ignore[attr-defined]


def test_a_reply_the_other_master_never_read_is_dropped_first(segment: object) -> None:
    a = other_master(segment, 3)
    box = a.slaves[0].mbx
    assert box is not None
    # The other master asks for 0x1018:02 and goes away before reading the answer.
    box.send(MailboxType.COE, SdoInitiateUploadRequest(0x1018, 2).encode(), fetch=False)
    a.close()
    b = Master(PairLink.responder_link(segment.process), clock=VirtualClock())  # type: ignore[attr-defined]
    b.scan(reset=False)
    # 0x1018:01, not the stale answer about 0x1018:02 still waiting in SM1
    assert b.slaves[0].sdo_read(0x1018, 1, "uint32") == VENDOR  # type: ignore[attr-defined]
    assert b.slaves[0].sdo_read(0x1018, 2, "uint32") == PRODUCT  # type: ignore[attr-defined]


# --- every protocol: a session after a session ------------------------------------------------
#
# Each session sends its first message with counter 1. When the session before ended on
# counter 1 too (one FoE read request, one SoE read, one gateway request), the slave drops
# the new session's first request as a repetition; only sending it again with counter 2
# gets an answer.

PROTOCOLS_TOPOLOGY = ('[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n'
                      'foe = true\nsoe = true\n')


def _one_request(m: Master, protocol: str) -> object:
    """One request of ``protocol`` that the slave answers (an error answer counts)."""
    from pyethercat.errors import FoeNotFound
    from pyethercat.master.foe import FoeClient
    from pyethercat.master.gateway import MailboxGateway
    from pyethercat.master.soe import SoeClient
    from pyethercat.wire.gateway import GatewayRequest, decode_gateway_request
    from pyethercat.wire.mailbox.coe import decode_coe

    s = m.slaves[0]
    assert s.mbx is not None
    if protocol == "foe":
        with pytest.raises(FoeNotFound, match="0x8001"):
            s.client(FoeClient).read("nothere")
        return "not found"
    if protocol == "soe":
        return s.client(SoeClient).read(1)  # S-0-0001 value: one request, one answer
    assert protocol == "gateway"
    body = SdoInitiateUploadRequest(0x1018, 1).encode()
    raw = (struct.pack("<H", (6 + len(body)) | 0x5000)
           + struct.pack("<HHBB", len(body), s.station_address, 0, 0x13) + body)
    request: GatewayRequest = decode_gateway_request(raw)
    with MailboxGateway(m, bind=("127.0.0.1", 0)) as gw:
        answer = gw.forward(s, request)
    assert answer is not None
    return decode_coe(answer[6:])


@pytest.mark.parametrize("protocol", ["foe", "soe", "gateway"])
def test_a_session_after_a_session(tmp_path: Path, protocol: str) -> None:
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "io.toml"
    path.write_text(PROTOCOLS_TOPOLOGY)
    segment = load_topology(path).build()
    answers = []
    for session in range(2):
        rec = Recorder(segment)
        m = Master(PairLink.responder_link(rec), clock=VirtualClock())
        m.scan(reset=False)
        if session == 0:
            m.set_state("PREOP")
        answers.append(_one_request(m, protocol))
        s = m.slaves[0]
        assert s.mbx is not None
        counters = sm0_counters(rec.sent, s.mbx.rx_offset)
        if session == 0:
            assert counters[0] == 1  # the first session ends on counter 1
        else:
            # dropped as a repetition of the first session's last counter, then sent as 2
            assert counters[:2] == [1, 2] and s.mbx.stats.resent == 1
        m.close()
    assert answers[0] == answers[1]


def test_a_fragmented_soe_write_after_a_session(tmp_path: Path) -> None:
    """Only an SoE write's last fragment is answered: the first must not be the one dropped."""
    from pyethercat.master.soe import SoeClient
    from pyethercat.sim.topology import load_topology
    from pyethercat.wire.mailbox.soe import parse_idn
    from pyethercat.wire.mailbox.soe_transfer import encode_soe_list

    path = tmp_path / "io.toml"
    path.write_text(PROTOCOLS_TOPOLOGY)
    segment = load_topology(path).build()
    a = Master(PairLink.responder_link(segment.process), clock=VirtualClock())  # type: ignore[attr-defined]
    a.scan()
    a.set_state("PREOP")
    assert _one_request(a, "soe") == (1000).to_bytes(2, "little")  # ends on counter 1
    a.close()
    b = Master(PairLink.responder_link(segment.process), clock=VirtualClock())  # type: ignore[attr-defined]
    b.scan(reset=False)
    soe = b.slaves[0].client(SoeClient)
    idns = [parse_idn(f"S-0-{n:04d}") for n in range(40, 140)]  # 204 bytes: two fragments
    soe.write(24, encode_soe_list(b"".join(i.to_bytes(2, "little") for i in idns)))
    assert soe.read_value(24) == idns
