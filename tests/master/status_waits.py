"""Checks shared by the tests of the mailbox status taken from the cyclic image.

:func:`count_status_waits` records how many exchanges each status wait asked
for; :func:`assert_no_stale_status` compares a mailbox's counters before and
after a run of transfers: a status byte older than the mailbox's last SM1
read would show as a fetch that found nothing, a repeat request, a poll
frame, a stale or duplicate message.
"""

from __future__ import annotations

from typing import Any

from pyethercat.master.mailbox_inbox import MailboxStats


def count_status_waits(runner: Any) -> list[int]:  # noqa: ANN401 - any runner
    """Record the ``count`` of every ``runner.wait_exchanges`` call (in the list returned)."""
    waits: list[int] = []
    wait = runner.wait_exchanges

    def counted(name: str, count: int, timeout: float) -> bool:
        waits.append(count)
        return bool(wait(name, count, timeout))

    runner.wait_exchanges = counted
    return waits


def lost_frames(master: Any, runner: Any) -> int:  # noqa: ANN401 - any master and runner
    """Frames lost so far: the master's own and the cyclic loop's."""
    return int(master.scheduler.stats.frames_lost) + int(runner.stats.lost_frames)


def assert_no_stale_status(before: MailboxStats, after: MailboxStats, lost: int = 0) -> None:
    """No sign of a stale status byte between the two snapshots of one mailbox's stats.

    ``lost``: frames lost meanwhile (:func:`lost_frames`, after minus before). A lost
    SM1 read is recovered with a repeat request and a lost cyclic frame makes the
    mailbox poll: the same counters move for a reason the status byte has no part
    in, so nothing is asserted then (a loaded machine may stall the simulator past
    the frame timeout).
    """
    if lost:
        return
    assert after.repeat_requests == before.repeat_requests
    assert after.duplicates == before.duplicates and after.stale == before.stale
    assert after.status_polls == before.status_polls
    assert after.fetches - before.fetches == after.received - before.received
