"""Prepared cyclic frames: encoded once, data patched in place, replies checked by offsets."""

from __future__ import annotations

import struct

from fake_esc_segment import FakeSegment, FakeSlave
from master_sii_helpers import io_sii

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.scheduler import Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame
from pyethercat.wire.sii import build_sii

# Slave RAM the fake ESCs let us write and read back (no FMMUs needed).
_RAM = 0x1000


def _setup(n: int = 2, sees_own_frames: bool = False
           ) -> tuple[Scheduler, FakeSegment, list[bytes]]:
    seg = FakeSegment([FakeSlave(build_sii(io_sii(f"io{i}"))) for i in range(n)])
    sent: list[bytes] = []

    def responder(frame: bytes) -> list[bytes] | bytes | None:
        sent.append(frame)
        return seg.process(frame)

    link = PairLink.responder_link(responder)
    # A medium that shows our own frames as received ones (not what a pair does).
    link.sees_own_frames = sees_own_frames
    s = Scheduler(link, clock=VirtualClock())
    s.transact([Datagram.positional(Command.APWR, i, reg.STATION_ADDRESS,
                                    struct.pack("<H", 0x1001 + i)) for i in range(n)])
    return s, seg, sent


def test_data_patched_in_place_goes_out_and_replies_are_read_at_offsets() -> None:
    s, _, sent = _setup(2)
    tpl = s.prepare_cyclic([Datagram.device(Command.BWR, 0, _RAM, bytes(3)),
                            Datagram.device(Command.FPRD, 0x1002, _RAM, 3)])
    assert tpl.lengths == (3, 3)
    indices = []
    for value in (b"\x01\x02\x03", b"\xaa\xbb\xcc"):
        at = tpl.data_offsets[0]
        tpl.frame[at:at + 3] = value
        raw = s.exchange_prepared(tpl)
        assert raw is not None
        # What went out is exactly what a full encode of the same datagrams gives.
        out = decode_frame(sent[-1])
        indices.append(out.datagrams[0].index)
        assert sent[-1] == encode_frame([Datagram(d.command, out.datagrams[0].index, d.address,
                                                  d.data) for d in out.datagrams])
        assert out.datagrams[0].data == value
        # BWR reached both slaves; the FPRD in the same frame sees the new bytes.
        assert tpl.wkc(raw, 0) == 2 and tpl.wkc(raw, 1) == 1
        at = tpl.data_offsets[1]
        assert raw[at:at + 3] == value
    assert indices[0] != indices[1]
    assert s.stats.frames_received == s.stats.frames_sent


def test_queued_acyclic_datagrams_ride_behind_the_template() -> None:
    s, _, sent = _setup(2)
    s.acyclic_hold = 10.0
    reqs = s.submit([Datagram.device(Command.FPRD, 0x1001 + i, reg.AL_STATUS, 2)
                     for i in range(2)])
    frames_before = len(sent)
    tpl = s.prepare_cyclic([Datagram.logical(Command.LRW, 0x10000, bytes(4))])
    ticket = s.send_prepared(tpl)
    assert ticket.carried == 2
    assert len(sent) == frames_before + 1
    f = decode_frame(sent[-1])
    assert [d.command for d in f.datagrams] == [Command.LRW, Command.FPRD, Command.FPRD]
    assert [d.more for d in f.datagrams] == [True, True, False]
    raw = ticket.wait_raw()
    assert raw is not None and tpl.wkc(raw, 0) == 0  # no FMMU: nobody answers the LRW
    assert [r.result().wkc for r in reqs] == [1, 1]
    # The template itself is unchanged: the next frame carries only the LRW.
    raw = s.exchange_prepared(tpl)
    assert raw is not None and len(decode_frame(sent[-1]).datagrams) == 1
    replies = ticket.wait()
    assert replies is not None and [d.command for d in replies] == [Command.LRW]


def test_lost_duplicated_and_looped_back_replies() -> None:
    s, seg, sent = _setup(1, sees_own_frames=True)
    tpl = s.prepare_cyclic([Datagram.device(Command.BRD, 0, reg.TYPE, 2)])
    seg.faults[seg.frames] = "drop"
    assert s.exchange_prepared(tpl) is None
    seg.faults[seg.frames] = "echo"  # our own frame seen again, then the reply
    raw = s.exchange_prepared(tpl)
    assert raw is not None and tpl.wkc(raw, 0) == 1
    assert s.stats.looped_back == 1
    seg.faults[seg.frames] = "dup"
    assert s.exchange_prepared(tpl) is not None
    # The second copy is read (and dropped) while waiting for the next reply.
    assert s.exchange_prepared(tpl) is not None
    assert s.stats.duplicates == 1


def test_mismatching_reply_loses_the_frame_with_a_reason() -> None:
    s, seg, _ = _setup(1)
    tpl = s.prepare_cyclic([Datagram.device(Command.BRD, 0, reg.TYPE, 2)])

    def longer(reply: bytes) -> bytes:
        f = decode_frame(reply)
        d = f.datagrams[0]
        return encode_frame([Datagram(d.command, d.index, d.address, b"\0" * 4, 0, 1)],
                            src=f.src)

    seg.faults[seg.frames] = longer
    ticket = s.send_prepared(tpl)
    assert ticket.wait_raw() is None
    assert ticket.lost and ticket.error is not None
    assert "4 data bytes, sent 2" in str(ticket.error)
    assert s.stats.malformed == 1
    # The next cycle works again.
    raw = s.exchange_prepared(tpl)
    assert raw is not None and tpl.wkc(raw, 0) == 1
