"""Auto-close (loop control 1) port re-opened by a valid frame arriving at it (facts 3.4).

The case arises in our trees when only one side of a cable is in auto-close:
after a link loss and its return the auto port of the parent opens again, so
frames reach the child's port 0, still closed ("closed wait"). The frame that
arrives is handled with the port closed (it turns at the closed port 0 and is
destroyed by the circulating-frame rule on its second pass); once its FCS
checked out the port opens, and the next frame passes normally. A frame that
arrives with a CRC error re-opens nothing.
"""

from __future__ import annotations

from simhelp import line, one

from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame

AUTO_CLOSE_PORT0 = bytes([R.LoopControl.AUTO_CLOSE])
BRD = encode_frame([Datagram.device(Command.BRD, 0, R.TYPE, 1)])


def _latched() -> Segment:
    seg = line(3, profile="ET1200")
    one(seg, Datagram.positional(Command.APWR, 1, R.DL_CONTROL_LOOP, AUTO_CLOSE_PORT0))
    seg.break_link(0, 1)
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 1
    seg.restore_link(0, 1)
    assert not seg.route.returned  # (walked again: DL status follows the topology)
    return seg


def _port0_loop(seg: Segment, i: int) -> int:
    return (seg.slaves[i].u16(R.DL_STATUS) >> 8) & 3


def test_valid_frame_at_the_closed_port_reopens_it() -> None:
    seg = _latched()
    assert _port0_loop(seg, 1) == 3  # closed, with link: 'closed wait'
    assert seg.process(BRD) is None  # arrives at the closed port 0, circulates, destroyed
    reply = one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1))
    assert reply.wkc == 3
    assert _port0_loop(seg, 1) == 2  # open with communication
    # the port stays open: later frames pass as usual
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 3


def test_corrupted_frame_at_the_closed_port_reopens_nothing() -> None:
    seg = _latched()
    seg.corrupt_frames(1, 0)
    assert seg.process(BRD) is None
    assert _port0_loop(seg, 1) == 3
    assert seg.process(BRD) is None  # this one arrived valid: the port opens after it
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 3


def test_no_frame_reaches_a_port_whose_peer_is_closed_too() -> None:
    # both sides in auto-close: the parent's port stays closed after the link
    # returns, no frame crosses the cable, only a loop-control write opens it
    seg = line(2, profile="ET1200")
    one(seg, Datagram.device(Command.BWR, 0, R.DL_CONTROL_LOOP,
                             bytes([R.LoopControl.AUTO_CLOSE | R.LoopControl.AUTO_CLOSE << 2])))
    seg.break_link(0, 1)
    one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1))
    seg.restore_link(0, 1)
    for _ in range(3):
        assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 1
    assert _port0_loop(seg, 1) == 3
    one(seg, Datagram.positional(Command.APWR, 0, R.DL_CONTROL_LOOP,
                                 bytes([R.LoopControl.AUTO_CLOSE | R.LoopControl.AUTO_CLOSE << 2])))
    # slave 0's port 1 opens; slave 1's port 0 then gets a valid frame and opens too
    assert seg.process(BRD) is None
    assert one(seg, Datagram.device(Command.BRD, 0, R.TYPE, 1)).wkc == 2
