"""Merging the two copies of a ring frame, and the routing decisions (master.redundancy).

The copies are made by hand from the rules of a ring: every slave
processes exactly one copy. The expected merged frame is the frame an
intact line would have returned.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from pyethercat.master.pdu import Request
from pyethercat.master.redundancy import (
    GIVE_UP_AFTER,
    PORT_A,
    PORT_B,
    Redundancy,
    copy_wkcs,
    hand_copies,
    mark_for_port,
    merge_copies,
    order_dependent,
    ring_gap,
    sent_on,
    split_counts,
)
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame


def frame(*dgs: Datagram) -> bytes:
    return encode_frame(list(dgs))


def processed(sent: bytes, i: int, data: bytes | None = None, wkc: int = 0, adp_step: int = 0,
              irq: int = 0) -> bytes:
    """``sent`` with datagram ``i`` as slaves left it."""
    dgs = decode_frame(sent).datagrams
    d = dgs[i]
    dgs[i] = Datagram(d.command, d.index, ((d.adp + adp_step) & 0xFFFF) | (d.ado << 16),
                      d.data if data is None else data, d.irq | irq, d.wkc + wkc)
    return encode_frame(dgs)


def test_lrw_split_ring_takes_each_halfs_inputs_and_adds_wkcs() -> None:
    # 8 logical bytes: outputs of slave 0 (bytes 0-1), inputs of slave 0 (2-3),
    # inputs of slave 3 behind the break (4-5), outputs of slave 3 (6-7).
    out = bytes([0x11, 0x22, 0, 0, 0, 0, 0x77, 0x88])
    sent = frame(Datagram.logical(Command.LRW, 0x10000, out))
    a_side = processed(sent, 0, bytes([0x11, 0x22, 0xA1, 0xA2, 0, 0, 0x77, 0x88]), wkc=3)
    b_side = processed(sent, 0, bytes([0x11, 0x22, 0, 0, 0xB1, 0xB2, 0x77, 0x88]), wkc=3)
    merged = merge_copies(sent, [a_side, b_side])
    (d,) = decode_frame(merged).datagrams
    assert d.data == bytes([0x11, 0x22, 0xA1, 0xA2, 0xB1, 0xB2, 0x77, 0x88])
    assert d.wkc == 6


def test_input_equal_to_the_sent_byte_is_still_right() -> None:
    # slave 0's input happens to equal what the master sent: taking the other copy is the same
    sent = frame(Datagram.logical(Command.LRW, 0, bytes([0x5A, 0])))
    a_side = processed(sent, 0, bytes([0x5A, 0]), wkc=1)
    b_side = processed(sent, 0, bytes([0x5A, 0x3C]), wkc=1)
    (d,) = decode_frame(merge_copies(sent, [a_side, b_side])).datagrams
    assert d.data == bytes([0x5A, 0x3C]) and d.wkc == 2


def test_intact_ring_processed_copy_wins_over_untouched_one() -> None:
    sent = frame(Datagram.device(Command.BRD, 0, 0x0130, 2))
    processed_all = processed(sent, 0, b"\x08\x00", wkc=6, adp_step=6)
    untouched = sent
    (d,) = decode_frame(merge_copies(sent, [untouched, processed_all])).datagrams
    assert (d.data, d.wkc, d.adp) == (b"\x08\x00", 6, 6)


def test_brd_ors_both_halves_and_adp_grows_by_both() -> None:
    sent = frame(Datagram.device(Command.BRD, 0, 0x0130, 2))
    a_side = processed(sent, 0, b"\x02\x00", wkc=2, adp_step=2)
    b_side = processed(sent, 0, b"\x08\x00", wkc=4, adp_step=4)
    (d,) = decode_frame(merge_copies(sent, [a_side, b_side])).datagrams
    assert (d.data, d.wkc, d.adp) == (b"\x0a\x00", 6, 6)


def test_irq_fields_are_ored_and_fprd_comes_from_its_side() -> None:
    sent = frame(Datagram.device(Command.FPRD, 0x1004, 0x0110, 2),
                 Datagram.device(Command.FPRD, 0x1001, 0x0110, 2))
    a_side = processed(processed(sent, 1, b"\x30\x0a", wkc=1), 0, irq=0x0004)
    b_side = processed(sent, 0, b"\x31\x09", wkc=1, irq=0x0008)
    d0, d1 = decode_frame(merge_copies(sent, [a_side, b_side])).datagrams
    assert (d0.data, d0.wkc, d1.data, d1.wkc) == (b"\x31\x09", 1, b"\x30\x0a", 1)
    assert d0.irq == 0x000C
    assert copy_wkcs(a_side) == [0, 1] and copy_wkcs(b_side) == [1, 0]


@given(st.binary(min_size=1, max_size=64), st.integers(0, 63), st.data())
def test_disjoint_halves_merge_to_the_line_result(sent_data: bytes, cut: int, data) -> None:
    """Any split of the written bytes between the two sides merges to what one pass wrote."""
    n = len(sent_data)
    written = data.draw(st.binary(min_size=n, max_size=n))
    cut = min(cut, n)
    sent = frame(Datagram.logical(Command.LRW, 0, sent_data))
    line = processed(sent, 0, written, wkc=2)
    a = processed(sent, 0, written[:cut] + sent_data[cut:], wkc=1)
    b = processed(sent, 0, sent_data[:cut] + written[cut:], wkc=1)
    assert merge_copies(sent, [a, b]) == line


def test_copies_of_other_lengths_do_not_merge() -> None:
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    assert merge_copies(sent, [sent, sent + b"\x00"]) is None


def test_order_dependent_frames() -> None:
    assert order_dependent(frame(Datagram.positional(Command.APWR, 3, 0x10, b"\x01\x10")))
    assert order_dependent(frame(Datagram.device(Command.BRD, 0, 0, 2),
                                 Datagram.device(Command.FRMW, 0x1001, 0x0910, 8)))
    assert not order_dependent(frame(Datagram.logical(Command.LRW, 0, b"\x00" * 4),
                                     Datagram.device(Command.FPRD, 0x1001, 0x130, 2)))


# -- routing decisions ---------------------------------------------------------------


def test_a_port_is_given_up_only_after_copies_missing_in_a_row() -> None:
    red = Redundancy()
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    looped = processed(sent, 0, wkc=5, adp_step=5)
    # port B dead (its carrier unknown): only the A copy, looped at the last slave, comes
    for n in range(1, GIVE_UP_AFTER + 1):
        cs, ports = red.plan(sent)
        assert ports == [PORT_A, PORT_B] and cs.need == {PORT_A, PORT_B}
        assert red.arrived(cs, PORT_A, looped, sent)[0] == "wait"
        assert decode_frame(red.expired(cs, sent)).datagrams[0].wkc == 5
        assert cs.partial and red.misses[PORT_B] == n
        assert red.state() == ("port A only" if n == GIVE_UP_AFTER else "redundant")
        assert red.evidence(PORT_B) == ("" if n < GIVE_UP_AFTER else
                                        f"no copy back on port B in {n} frames in a row")
    # given up: still sent on both ports, but only the A copy is awaited
    cs2, ports2 = red.plan(sent)
    assert ports2 == [PORT_A, PORT_B] and cs2.need == {PORT_A}
    assert red.arrived(cs2, PORT_A, looped, sent)[0] == "done" and not cs2.partial


def test_one_late_copy_in_a_split_ring_leaves_both_ports_awaited() -> None:
    red = Redundancy()
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    a_half = processed(sent, 0, wkc=3, adp_step=3)
    b_half = mark_for_port(processed(sent, 0, wkc=2, adp_step=2), PORT_B)
    cs, _ = red.plan(sent)
    red.seen(PORT_A)
    red.arrived(cs, PORT_A, a_half, sent)
    red.expired(cs, sent)  # B's copy late: this frame is partial ...
    assert cs.partial and red.returning == {PORT_A, PORT_B} and red.misses == [0, 1]
    # ... the next one waits for both halves again
    cs, _ = red.plan(sent)
    red.seen(PORT_A)
    assert red.arrived(cs, PORT_A, a_half, sent)[0] == "wait"
    red.seen(PORT_B)
    action, reply, _ = red.arrived(cs, PORT_B, b_half, sent)
    assert action == "done" and decode_frame(reply).datagrams[0].wkc == 5
    assert red.misses == [0, 0]


def test_a_copy_looped_back_on_its_own_port_waits_for_a_port_that_came_back() -> None:
    red = Redundancy()
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    # A closed ring first: the copies keep the source MAC they were sent with (Ethernet)
    cs, _ = red.plan(sent)
    red.arrived(cs, PORT_B, processed(sent, 0, wkc=5, adp_step=5), sent)
    red.arrived(cs, PORT_A, mark_for_port(sent, PORT_B), sent)
    assert red.marks is True
    red.returning = {PORT_A}  # B was given up ...
    cs, _ = red.plan(sent)
    assert cs.need == {PORT_A}
    red.seen(PORT_B)  # ... and a frame came on B since this one was sent
    # the ring is open (A's copy looped back on A): B's half is on its way
    assert red.arrived(cs, PORT_A, processed(sent, 0, wkc=3, adp_step=3), sent)[0] == "wait"
    b_half = mark_for_port(processed(sent, 0, wkc=2, adp_step=2), PORT_B)
    assert red.arrived(cs, PORT_B, b_half, sent)[0] == "done"


def test_whether_copies_carry_the_port_they_were_sent_on_is_learnt() -> None:
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    whole = processed(sent, 0, wkc=5, adp_step=5)
    for carried in (True, False):
        # Ethernet: the copy sent on B keeps its mark (it came back on A untouched);
        # UDP: both copies come back with one synthetic source, nobody can tell
        untouched = mark_for_port(sent, PORT_B) if carried else sent
        red = Redundancy()
        cs, _ = red.plan(sent)
        assert cs.mark is None  # not known yet
        red.arrived(cs, PORT_B, whole, sent)
        assert red.arrived(cs, PORT_A, untouched, sent)[0] == "done"
        assert red.marks is carried
        cs, _ = red.plan(sent)
        req = Request(None, Datagram.device(Command.BRD, 0, 0, 2), 0)
        red.arrived(cs, PORT_B, whole, sent)
        red.arrived(cs, PORT_A, untouched, sent)
        hand_copies(cs, None, [req])
        assert req.copies is not None and set(req.copies) == {PORT_A, PORT_B}
        assert req.copies.origin == ({PORT_B: PORT_A, PORT_A: PORT_B} if carried else {})


def test_frames_with_no_copy_back_give_up_no_port() -> None:
    red = Redundancy()
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    for _ in range(5):  # a stalled host: nothing back at all
        cs, _ = red.plan(sent)
        assert red.expired(cs, sent) is None
    assert red.returning == {PORT_A, PORT_B} and red.misses == [0, 0]
    assert red.state() == "no port"
    cs, _ = red.plan(sent)
    assert cs.need == {PORT_A, PORT_B}
    red.seen(PORT_A)
    assert red.state() == "redundant"


def test_untouched_copy_while_one_port_is_awaited_waits_for_the_other() -> None:
    red = Redundancy()
    red.returning = {PORT_A}  # port B was silent
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    cs, _ = red.plan(sent)
    # the ring closed again: the B copy comes back on A untouched, the real one on B
    assert red.arrived(cs, PORT_A, sent, sent)[0] == "wait"
    action, reply, _ = red.arrived(cs, PORT_B, processed(sent, 0, wkc=5, adp_step=5), sent)
    assert action == "done" and decode_frame(reply).datagrams[0].wkc == 5
    assert red.state() == "redundant"


def test_chain_frame_back_on_its_own_port_is_passed_on_through_the_other() -> None:
    red = Redundancy()
    sent = frame(Datagram.positional(Command.APWR, 4, 0x10, b"\x05\x10"))
    cs, ports = red.plan(sent)
    assert cs.chain and ports == [PORT_A]
    half = processed(sent, 0, adp_step=3)  # three slaves before the break
    action, out, port = red.arrived(cs, PORT_A, half, sent)
    assert (action, out, port) == ("forward", half, PORT_B)
    whole = processed(half, 0, wkc=1, adp_step=3)
    assert red.arrived(cs, PORT_B, whole, sent) == ("done", whole, -1)


def test_chain_frame_with_port_b_dead_is_done_when_it_loops_back() -> None:
    red = Redundancy()
    red.returning = {PORT_A}
    sent = frame(Datagram.positional(Command.APRD, 1, 0x10, bytes(2)))
    cs, _ = red.plan(sent)
    assert red.arrived(cs, PORT_A, sent, sent)[0] == "done"


def test_chain_frame_goes_out_on_b_when_a_has_no_carrier() -> None:
    red = Redundancy()
    red.carrier = [False, True]
    sent = frame(Datagram.positional(Command.APRD, 1, 0x10, bytes(2)))
    cs, ports = red.plan(sent)
    assert ports == [PORT_B]
    assert red.arrived(cs, PORT_B, sent, sent)[0] == "done"


def test_forwarded_copy_lost_gives_the_half_that_came_back() -> None:
    red = Redundancy()
    sent = frame(Datagram.positional(Command.APRD, 0, 0x10, bytes(2)))
    half = processed(sent, 0, b"\x01\x10", wkc=1, adp_step=2)
    for n in range(1, GIVE_UP_AFTER + 1):
        cs, _ = red.plan(sent)
        assert red.arrived(cs, PORT_A, half, sent)[0] == "forward"
        assert red.expired(cs, sent) == half
        assert (PORT_B in red.returning) == (n < GIVE_UP_AFTER)
    # B given up: the next chain frame is done when it comes back on A
    cs, _ = red.plan(sent)
    assert red.arrived(cs, PORT_A, half, sent)[0] == "done"


def test_nothing_back_at_all_is_lost() -> None:
    red = Redundancy()
    sent = frame(Datagram.device(Command.BRD, 0, 0, 2))
    cs, _ = red.plan(sent)
    assert red.expired(cs, sent) is None


# -- which slaves an open ring's copies did not reach (the cycle that shows a node gone) --

SRC = bytes.fromhex("020000000001")


def lrw_copy(wkc: int, port: int) -> bytes:
    """One LRW frame from our master, as it comes back with ``wkc``, sent on ``port``."""
    sent = bytearray(encode_frame([Datagram(Command.LRW, 0, 0x10000, bytes(4))], src=SRC))
    sent[WKC_AT:WKC_AT + 2] = wkc.to_bytes(2, "little")
    return mark_for_port(bytes(sent), port)


WKC_AT = 14 + 2 + 10 + 4  # Ethernet, EtherCAT header, datagram header, 4 data bytes


def test_copy_for_port_b_is_marked_and_slaves_do_not_hide_the_mark() -> None:
    a, b = lrw_copy(0, PORT_A), lrw_copy(0, PORT_B)
    assert a[6:12] == SRC and b[6:12] != SRC and b[6:8] == SRC[:2] and b[10:12] == SRC[4:]
    assert sent_on(a, SRC) == PORT_A and sent_on(b, SRC) == PORT_B
    # The first slave sets the locally administered bit of byte 0: the mark survives.
    passed = bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6] | 0x02]) + b[7:]
    assert sent_on(passed, SRC) == PORT_B


def test_split_counts_from_copies_that_looped_back() -> None:
    # Node 2 of 5 (shares 3, 1, 3, 1, 2) gone: A side counts 4, B side 3.
    got = {PORT_A: lrw_copy(4, PORT_A), PORT_B: lrw_copy(3, PORT_B)}
    assert split_counts(got, WKC_AT, SRC) == (4, 3)
    assert ring_gap([3, 1, 3, 1, 2], 4, 3) == (2, 3)
    # The first node gone: no copy at A (no link partner), the B side counts the rest.
    assert split_counts({PORT_B: lrw_copy(7, PORT_B)}, WKC_AT, SRC) == (0, 7)
    assert ring_gap([3, 1, 3, 1, 2], 0, 7) == (0, 1)
    # The last node gone: the A side alone.
    assert ring_gap([3, 1, 3, 1, 2], 8, 0) == (4, 5)


def test_closed_ring_tells_nothing_about_who_is_missing() -> None:
    # Sent on A, back on B (round the closed ring, short by a slave not in OP); the
    # copy sent on B came back on A untouched.
    got = {PORT_B: lrw_copy(8, PORT_A), PORT_A: lrw_copy(0, PORT_B)}
    assert split_counts(got, WKC_AT, SRC) is None


def test_counts_that_fit_no_prefix_and_suffix_say_nothing() -> None:
    # A side 2 is no prefix of (3, 1, 3): a slave there counted short for another reason.
    assert ring_gap([3, 1, 3], 2, 3) is None
    assert ring_gap([3, 1, 3], 3, 2) is None
    assert ring_gap([3, 1, 3], 4, 3) == (2, 2)  # nobody missing: an empty gap
