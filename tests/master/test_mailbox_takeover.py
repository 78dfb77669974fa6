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
