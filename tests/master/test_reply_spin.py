"""The cyclic thread polls the link for a prepared frame's reply before it blocks.

A scripted link answers each frame only after a number of receive calls and
records the timeout of every call: with ``reply_spin`` the first calls are
polls (timeout 0) and the reply is taken by one of them; without it the first
call already blocks; a reply that never comes still ends as a lost frame
after the frame timeout (polling does not turn into an endless busy loop);
replies that wait in the link past their frames' deadlines are taken, not lost.
"""

from __future__ import annotations

from collections import deque

from pyethercat.link.base import Link
from pyethercat.master.scheduler import DEFAULT_REPLY_SPIN, Scheduler
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import LOCALLY_ADMINISTERED_BIT

#: What one poll (a receive with timeout 0) costs on the link's clock.
POLL_NS = 100_000


class LinkClock:
    """A clock that moves only when the scripted link says time has passed."""

    def __init__(self) -> None:
        self.t = 1_000_000_000

    def now_ns(self) -> int:
        return self.t

    def sleep_until(self, deadline_ns: int) -> None:
        self.t = max(self.t, deadline_ns)


class ScriptedLink(Link):
    """Answers a sent frame (LA bit set, WKC 1) at the ``answer_after``-th receive call."""

    def __init__(self, answer_after: int | None) -> None:
        super().__init__("scripted")
        self.clock = LinkClock()
        self.answer_after = answer_after
        self.timeouts: list[float | None] = []
        self._pending: deque[bytes] = deque()
        self._calls = 0

    def send(self, frame: bytes) -> None:
        reply = bytearray(frame)
        reply[6] |= LOCALLY_ADMINISTERED_BIT
        # One datagram: its WKC is the last two bytes of the EtherCAT payload.
        end = 14 + 2 + 10 + (reply[14 + 2 + 6] | (reply[14 + 2 + 7] & 0x07) << 8)
        reply[end:end + 2] = b"\x01\x00"
        self._pending.append(bytes(reply))
        self._calls = 0

    def recv(self, timeout: float | None = None) -> bytes | None:
        self.timeouts.append(timeout)
        self._calls += 1
        if self.answer_after is not None and self._pending and self._calls >= self.answer_after:
            self.clock.t += POLL_NS
            return self._pending.popleft()
        # Nothing comes: a poll costs its turn, a blocking receive waits out its timeout.
        self.clock.t += POLL_NS if not timeout else round(timeout * 1e9)
        return None


def template(s: Scheduler):  # noqa: ANN201 - CyclicTemplate
    return s.prepare_cyclic([Datagram.device(Command.LRW, 0, 0x10000, bytes(4))])


def test_reply_is_polled_for_before_blocking() -> None:
    link = ScriptedLink(answer_after=5)
    s = Scheduler(link, timeout=0.5, clock=link.clock)
    assert s.reply_spin in (DEFAULT_REPLY_SPIN, 0.0)
    s.reply_spin = 0.5
    tpl = template(s)
    raw = s.exchange_prepared(tpl)
    assert raw is not None and tpl.wkc(raw, 0) == 1
    assert link.timeouts == [0.0] * 5
    assert s.stats.frames_received == 1 and s.stats.frames_lost == 0


def test_without_spin_the_first_receive_blocks() -> None:
    link = ScriptedLink(answer_after=1)
    s = Scheduler(link, timeout=0.5, clock=link.clock)
    s.reply_spin = 0.0
    tpl = template(s)
    assert s.exchange_prepared(tpl) is not None
    assert len(link.timeouts) == 1
    first = link.timeouts[0]
    assert first is not None and first > 0.4


def test_a_missing_reply_is_a_lost_frame_after_the_timeout_even_while_polling() -> None:
    link = ScriptedLink(answer_after=None)
    s = Scheduler(link, timeout=0.02, clock=link.clock)
    s.reply_spin = 0.005
    tpl = template(s)
    assert s.exchange_prepared(tpl) is None
    # Polled for a while (this link answers a poll at once, so many polls),
    # then receives that block up to the frame's deadline.
    first_block = next(i for i, t in enumerate(link.timeouts) if t)
    assert first_block > 10 and set(link.timeouts[:first_block]) == {0.0}
    assert 0.005 < (link.timeouts[first_block] or 0) < 0.02
    assert s.stats.frames_lost == 1


def test_replies_waiting_past_their_deadline_are_taken_not_lost() -> None:
    """A thread kept off the CPU past the frames' deadlines finds both replies waiting."""
    link = ScriptedLink(answer_after=1)
    s = Scheduler(link, timeout=0.02, clock=link.clock)
    s.reply_spin = 0.0
    first, second = s.send_prepared(template(s)), s.send_prepared(template(s))
    link.clock.t += 1_000_000_000  # a second later, both replies are in the queue
    assert first.wait_raw() is not None and second.wait_raw() is not None
    assert s.stats.frames_lost == 0 and s.stats.frames_received == 2
