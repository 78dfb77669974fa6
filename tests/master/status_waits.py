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


def assert_no_stale_status(before: MailboxStats, after: MailboxStats) -> None:
    """No sign of a stale status byte between the two snapshots of one mailbox's stats."""
    assert after.repeat_requests == before.repeat_requests
    assert after.duplicates == before.duplicates and after.stale == before.stale
    assert after.status_polls == before.status_polls
    assert after.fetches - before.fetches == after.received - before.received
