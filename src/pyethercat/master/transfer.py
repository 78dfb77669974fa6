"""What the FoE and SoE clients share: waiting for a slave's answer within a deadline.

Their sans-IO state machines (:mod:`pyethercat.wire.mailbox.foe_transfer`,
:mod:`pyethercat.wire.mailbox.soe_transfer`) keep the deadline of the answer
they wait for and turn a missed one into their own typed time-out; this
waits on the mailbox until then.
"""

from __future__ import annotations

from typing import Protocol

from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.mailbox import Accept, Mailbox, ReceivedMessage

__all__ = ["Deadlined", "answer_by_deadline"]


class Deadlined(Protocol):
    """A transfer state machine with a deadline (FoE or SoE client)."""

    @property
    def deadline(self) -> float | None: ...

    def check_deadline(self, now: float) -> None: ...


def answer_by_deadline(mbx: Mailbox, accept: Accept, what: str, sm: Deadlined,
                       span: float) -> ReceivedMessage:
    """The next message ``accept`` takes, by ``sm.deadline`` (or ``span`` from now).

    A missed deadline raises the state machine's own time-out error.
    """
    deadline = sm.deadline if sm.deadline is not None else mbx.clock() + span
    try:
        return mbx.receive(accept, what=f"answer to {what}",
                           timeout=max(0.0, deadline - mbx.clock()))
    except EcTimeoutError:
        sm.check_deadline(max(mbx.clock(), deadline))
        raise  # check_deadline raised already; kept for the type checker
