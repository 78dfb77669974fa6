"""EoE frame streams: the fragmenter's rules and a reassembler that never delivers a damaged frame."""

from __future__ import annotations

import random
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.wire.mailbox.eoe import EoeFragment, decode_eoe
from pyethercat.wire.mailbox.eoe_stream import EoeReceiver, EoeSender, frame_length_ok


def ipv4_frame(size: int, tag: int) -> bytes:
    """An Ethernet frame of ``size`` bytes whose IPv4 total length fills it exactly."""
    assert size >= 34
    body = bytes((tag + i) & 0xFF for i in range(size - 34))
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, size - 14, tag, 0, 64, 17, 0,
                     bytes([10, 0, 0, 1]), bytes([10, 0, 0, 2]))
    return bytes([2, 0, 0, 0, 0, tag & 0xFF]) + bytes([2, 0, 0, 0, 1, 1]) + b"\x08\x00" + ip + body


def fragments(sender: EoeSender) -> list[bytes]:
    out: list[bytes] = []
    while (p := sender.current(0.0)) is not None:
        out.append(p)
        sender.taken()
    return out


def test_fragment_sizes_offsets_and_numbers_follow_the_rules() -> None:
    s = EoeSender(128)  # 118 bytes of room: 96-byte fragments, the last up to 118
    frame = ipv4_frame(1514, 7)
    s.push(frame, 0.0)
    parts = [decode_eoe(p) for p in fragments(s)]
    assert all(isinstance(p, EoeFragment) for p in parts)
    frags = [p for p in parts if isinstance(p, EoeFragment)]
    assert [len(f.data) for f in frags] == [96] * 15 + [74]
    assert frags[0].offset == 48  # ceil(1514 / 32) blocks announced
    assert [f.offset for f in frags[1:]] == [96 * k // 32 for k in range(1, 16)]
    assert [f.fragment_number for f in frags] == list(range(16))
    assert [f.last for f in frags] == [False] * 15 + [True]
    assert {f.frame_number for f in frags} == {0}
    assert s.stats.frames == 1 and s.stats.fragments == 16 and s.stats.bytes == 1514
    # frame numbers count modulo 16
    for k in range(17):
        s.push(ipv4_frame(60, k), 0.0)
    numbers = [decode_eoe(p) for p in fragments(s)]
    assert [m.frame_number for m in numbers if isinstance(m, EoeFragment)] == [
        (k + 1) % 16 for k in range(17)]


def test_current_repeats_until_taken_and_time_flags() -> None:
    s = EoeSender(1024)
    s.push(ipv4_frame(100, 1), 0.0, request_time=True, timestamp=0x11223344)
    a = s.current(0.0)
    assert a is not None and s.current(0.0) == a  # a refused write is repeated unchanged
    frag = decode_eoe(a)
    assert isinstance(frag, EoeFragment)
    assert frag.time_requested and frag.timestamp == 0x11223344 and frag.last
    s.taken()
    assert s.current(0.0) is None


def test_queue_limit_and_time_out_drop_frames() -> None:
    s = EoeSender(128, queue_limit=2, timeout=1.0)
    assert s.push(ipv4_frame(200, 1), 0.0) and s.push(ipv4_frame(200, 2), 0.0)
    assert not s.push(ipv4_frame(200, 3), 0.0)
    assert s.stats.dropped == 1
    first = s.current(0.0)
    assert first is not None
    s.taken()  # one fragment of frame 1 went; the slave then stops reading
    assert s.current(2.0) is None  # frame 1 timed out, frame 2 too (queued at 0.0)
    assert s.stats.timeouts == 2 and s.stats.dropped == 3
    assert not s.push(b"\x00" * 13, 2.0)  # shorter than an Ethernet header


def test_receiver_rebuilds_and_checks_announced_size() -> None:
    r = EoeReceiver()
    s = EoeSender(128)
    frame = ipv4_frame(1000, 3)
    s.push(frame, 0.0)
    got = [r.feed_payload(p, 0.0) for p in fragments(s)]
    assert got[-1] == frame and all(g is None for g in got[:-1])
    # IgH announces size / 32 + 1 blocks for a size that is a multiple of 32
    exact = ipv4_frame(96, 4)
    ok = r.feed(EoeFragment(exact, 0, 96 // 32 + 1, 1, True), 0.0)
    assert ok == exact
    # more blocks announced than the frame fills: something was lost
    assert r.feed(EoeFragment(ipv4_frame(100, 5), 0, 8, 2, True), 0.0) is None
    assert r.stats.errors == 1 and "announced" in r.last_error


def test_receiver_discards_stale_frame_after_time_out() -> None:
    r = EoeReceiver(timeout=0.5)
    s = EoeSender(128)
    s.push(ipv4_frame(300, 1), 0.0)
    parts = fragments(s)
    assert r.feed_payload(parts[0], 0.0) is None
    assert r.feed_payload(parts[1], 1.0) is None  # the frame expired before this one
    assert r.stats.timeouts == 1
    assert r.feed_payload(parts[2], 1.0) is None
    assert r.stats.frames == 0


def test_frame_length_check() -> None:
    f = ipv4_frame(80, 1)
    assert frame_length_ok(f) and not frame_length_ok(f[:-1])
    arp = bytes(12) + b"\x08\x06" + bytes(28)
    assert frame_length_ok(arp) and not frame_length_ok(arp[:-1])
    assert frame_length_ok(bytes(12) + b"\x88\xa4") and not frame_length_ok(bytes(13))


@st.composite
def damaged_streams(draw: st.DrawFn) -> tuple[list[bytes], list[bytes]]:
    """Fragments of up to 15 frames, reordered, duplicated, dropped and cut short.

    Up to 15 frames: frame numbers count modulo 16, so a fragment replayed
    16 frames late carries a number in use again and is indistinguishable
    (the mailbox counter check drops repeated mailboxes before EoE sees them).
    """
    mailbox = draw(st.sampled_from([48, 64, 128, 200, 522, 1024]))
    count = draw(st.integers(1, 15))
    frames = [ipv4_frame(draw(st.integers(60, 1514)), k) for k in range(count)]
    s = EoeSender(mailbox, queue_limit=16)
    for f in frames:
        s.push(f, 0.0)
    stream = fragments(s)
    rng = random.Random(draw(st.integers(0, 2**32 - 1)))
    for _ in range(draw(st.integers(0, 12))):
        i = rng.randrange(len(stream))
        op = rng.choice(("swap", "dup", "drop", "cut", "cut32"))
        if op == "swap" and len(stream) > 1:
            j = min(len(stream) - 1, i + rng.randint(1, 4))
            stream[i], stream[j] = stream[j], stream[i]
        elif op == "dup":
            stream.insert(min(len(stream), i + rng.randint(1, 6)), stream[i])
        elif op == "drop" and len(stream) > 1:
            del stream[i]
        elif op == "cut" and len(stream[i]) > 5:
            stream[i] = stream[i][:rng.randrange(4, len(stream[i]))]
        elif op == "cut32" and len(stream[i]) > 4 + 32:
            stream[i] = stream[i][:len(stream[i]) - 32]
    return frames, stream


@settings(max_examples=400, deadline=None)
@given(damaged_streams())
def test_damaged_streams_never_deliver_a_corrupt_frame(case: tuple[list[bytes], list[bytes]]
                                                       ) -> None:
    frames, stream = case
    r = EoeReceiver()
    originals = set(frames)
    for payload in stream:
        got = r.feed_payload(payload, 0.0)
        if got is not None:
            assert got in originals


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(60, 1514), min_size=1, max_size=40),
       st.sampled_from([48, 128, 1024]))
def test_undamaged_streams_deliver_every_frame(sizes: list[int], mailbox: int) -> None:
    frames = [ipv4_frame(n, k) for k, n in enumerate(sizes)]
    s = EoeSender(mailbox, queue_limit=64)
    r = EoeReceiver()
    for f in frames:
        s.push(f, 0.0)
    got = [x for p in fragments(s) if (x := r.feed_payload(p, 0.0)) is not None]
    assert got == frames
    assert r.stats.errors == 0 and r.stats.frames == len(frames)


def test_a_mailbox_too_small_for_a_fragment_drops_frames_and_counts_them() -> None:
    s = EoeSender(40)  # 30 bytes of room: not one 32-byte block
    assert s.push(bytes(60), 0.0)
    assert s.current(0.0) is None
    assert s.stats.dropped == 1 and s.stats.errors == 1 and not s.busy
