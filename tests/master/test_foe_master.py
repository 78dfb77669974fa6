"""Our master's FoE client on a lossy link: lost frames, lost replies, 1 MiB files.

The simulated slave is the Kollmorgen AKD of the corpus (its SII announces FoE
and has 1 KiB mailboxes), served by the simulator's FoE server.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import EtherCATError
from pyethercat.link.pair import PairLink
from pyethercat.master.foe import FoeClient
from pyethercat.master.master import Master
from pyethercat.sim.foe import FoeProtocol
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.header import MailboxType

AKD = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "sii" / "ethercrab_akd.bin"
MIB = random.Random(2024).randbytes(1 << 20)


def _segment() -> Segment:
    return parse_topology(f'[[slave]]\nname = "akd"\nsii = "{AKD}"\n').build()


def _server(seg: Segment) -> FoeProtocol:
    return seg.slaves[0].spec.app.protocols[MailboxType.FOE]  # type: ignore[union-attr,no-any-return]


def _master(responder: Callable[[bytes], bytes | None]) -> tuple[Master, FoeClient]:
    m = Master(PairLink.responder_link(responder), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    mbx = m.slaves[0].mbx
    assert mbx is not None
    return m, FoeClient(mbx)


def test_one_mib_round_trip() -> None:
    seg = _segment()
    _m, c = _master(seg.process)
    c.write("image.bin", MIB)
    assert _server(seg).store.files["image.bin"] == MIB
    assert c.read("image.bin") == MIB
    # 1 KiB mailbox: 1012 bytes per packet, and 1 MiB is no multiple of it: the read
    # request and one ACK per DATA packet
    assert c.stats.packets == 1 + len(MIB) // 1012 + 1


def test_lost_reply_is_recovered_by_repeat_request() -> None:
    seg = _segment()
    count = {"sm1_reads": 0, "dropped": 0}

    def lose_one_reply(frame: bytes) -> bytes | None:
        reply = seg.process(frame)
        if reply is None:
            return None
        for d in decode_frame(reply).datagrams:
            # the 40th SM1 read that took a message out of the slave: its reply is lost
            if d.command == Command.FPRD and len(d.data) == 1024 and d.wkc == 1:
                count["sm1_reads"] += 1
                if count["sm1_reads"] == 40:
                    count["dropped"] += 1
                    return None
        return reply

    m, c = _master(lose_one_reply)
    data = MIB[:200_000]
    c.write("x.bin", data)
    assert count["dropped"] == 1
    assert _server(seg).store.files["x.bin"] == data
    mbx = m.slaves[0].mbx
    assert mbx is not None and mbx.stats.repeat_requests == 1


@pytest.mark.parametrize("seed", range(20))
def test_one_mib_write_with_one_percent_of_frames_lost(seed: int) -> None:
    """Byte-identical or a typed error; never a silently corrupt file."""
    seg = _segment()
    rng = random.Random(seed)
    lost = {"request": 0, "reply": 0}

    def lossy(frame: bytes) -> bytes | None:
        # half the losses before the slave saw the frame, half on the way back
        if rng.random() < 0.005:
            lost["request"] += 1
            return None
        reply = seg.process(frame)
        if rng.random() < 0.005:
            lost["reply"] += 1
            return None
        return reply

    m, c = _master(lossy)
    try:
        c.write("fw.bin", MIB)
    except EtherCATError as exc:
        assert "fw.bin" not in _server(seg).store.files, f"partial file after {exc!r}"
        return
    assert _server(seg).store.files["fw.bin"] == MIB
    assert lost["request"] + lost["reply"] > 0
