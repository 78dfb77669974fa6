"""What the FoE and SoE clients share: a request and its answer within a transfer's deadline.

Their sans-IO state machines (:mod:`pyethercat.wire.mailbox.foe_transfer`,
:mod:`pyethercat.wire.mailbox.soe_transfer`) keep the deadline of the answer
they wait for and turn a missed one into their own typed time-out; these
send and wait on the mailbox until then. A message that expects an answer
goes through :meth:`~pyethercat.master.mailbox.Mailbox.transact`, so the
mailbox's take-over rule applies to FoE and SoE as to CoE: until the first
answer since the master took the mailbox over, an unanswered request is sent
once more with the next counter (the slave drops a request whose counter
repeats the last one it took, maybe an earlier session's).
"""

from __future__ import annotations

from typing import Protocol

from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.mailbox import Accept, Mailbox, ReceivedMessage
from pyethercat.wire.mailbox.header import MailboxType

__all__ = ["Deadlined", "answer_by_deadline", "request_by_deadline"]


class Deadlined(Protocol):
    """A transfer state machine with a deadline (FoE or SoE client)."""

    @property
    def deadline(self) -> float | None: ...

    def check_deadline(self, now: float) -> None: ...


def request_by_deadline(mbx: Mailbox, mtype: MailboxType, payload: bytes, accept: Accept,
                        what: str, sm: Deadlined, span: float) -> ReceivedMessage:
    """Send ``payload`` and return the answer ``accept`` takes, by ``sm.deadline``
    (or ``span`` from now), with the take-over rule (see the module text).

    A missed deadline raises the state machine's own time-out error; a
    failure before it (the link, SM0 refusing the message) raises as it came.
    """
    deadline = sm.deadline if sm.deadline is not None else mbx.clock() + span
    try:
        return mbx.transact(mtype, payload, accept, what=what,
                            timeout=max(0.0, deadline - mbx.clock()))
    except EcTimeoutError:
        sm.check_deadline(mbx.clock())
        raise


def answer_by_deadline(mbx: Mailbox, accept: Accept, what: str, sm: Deadlined,
                       span: float) -> ReceivedMessage:
    """The next message ``accept`` takes, by ``sm.deadline`` (or ``span`` from now).

    For the answers that follow the first one (fragments, a slave's next
    packet after BUSY). A missed deadline raises the state machine's own
    time-out error.
    """
    deadline = sm.deadline if sm.deadline is not None else mbx.clock() + span
    try:
        return mbx.receive(accept, what=f"answer to {what}",
                           timeout=max(0.0, deadline - mbx.clock()))
    except EcTimeoutError:
        sm.check_deadline(max(mbx.clock(), deadline))
        raise  # check_deadline raised already; kept for the type checker
