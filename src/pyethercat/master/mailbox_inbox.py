"""The slave -> master side of one mailbox: what SM1 brought, checked, dispatched and queued.

Part of :class:`~pyethercat.master.mailbox.Mailbox` (see ``master.mailbox``
for the whole handshake). Every message read from SM1, by a fetch, by the
speculative read of the prepared frame or by someone else's read (the EoE
service), goes through :meth:`MailboxInbox.deliver`:

- the length word is checked against the bytes SM1 holds;
- a message with the same non-zero counter as the previous one is a
  repetition (ETG.1000.4, mailbox header "Cnt") and is dropped;
- a mailbox error reply (type 0) is queued as a
  :class:`~pyethercat.errors.MailboxErrorReply` for the transaction waiting;
- unsolicited-message handlers (CoE emergencies) see every message first;
- the rest waits in the queue until a protocol client takes it
  (:meth:`MailboxInbox.take`), unless the caller takes it at once.

:attr:`MailboxInbox.lost` records that a read may have emptied SM1 without
its reply reaching the master (the repeat request then gets the message
back).
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from pyethercat.errors import EtherCATError, FrameError, MailboxError, MailboxErrorReply
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.pdu import Request
from pyethercat.wire.mailbox.header import (
    MAILBOX_HEADER_SIZE,
    MailboxHeader,
    MailboxType,
    decode_mailbox_error,
    is_repeated_counter,
)

__all__ = ["Accept", "MailboxInbox", "MailboxStats", "ReceivedMessage", "named_error"]

_log = logging.getLogger("pyethercat.mailbox")

#: The mailbox the handlers are called with (``master.mailbox.Mailbox``).
_Owner = TypeVar("_Owner")


@dataclass(frozen=True, slots=True)
class ReceivedMessage:
    """A message read from SM1: its header and payload (exactly ``header.length`` bytes).

    ``after`` holds the first bytes of SM1 behind the payload: a client may
    look there when a slave's length word came out short (see ``CoeClient``).
    """

    header: MailboxHeader
    payload: bytes
    after: bytes = b""

    @property
    def type(self) -> MailboxType | int:
        return self.header.type


#: Decides whether a message answers the transaction in progress.
Accept = Callable[[ReceivedMessage], bool]


@dataclass
class MailboxStats:
    """Counters of one mailbox (monotonic)."""

    sent: int = 0
    received: int = 0
    #: SM0 writes refused because the slave had not read the previous message yet.
    write_refused: int = 0
    status_polls: int = 0
    #: Status bytes taken from the cyclic process image instead of a poll frame.
    cyclic_status: int = 0
    fetches: int = 0
    #: Speculative SM1 reads that found the answer already there.
    early_replies: int = 0
    repeat_requests: int = 0
    #: Requests sent again with the next counter after getting no answer.
    resent: int = 0
    #: Replies dropped because they answered an earlier request (late or stale).
    stale: int = 0
    #: Messages dropped because they repeated the previous counter.
    duplicates: int = 0
    error_replies: int = 0
    unsolicited: int = 0


class MailboxInbox(Generic[_Owner]):
    """Messages from one slave (see the module text).

    ``owner`` is passed to the handlers with each message (the mailbox);
    ``label`` names the slave in errors; ``tx_sm`` is the SM the messages
    come from (SM1 usually).
    """

    def __init__(self, owner: _Owner, label: str, tx_sm: int, stats: MailboxStats) -> None:
        self.owner = owner
        self.label = label
        self.tx_sm = tx_sm
        self.stats = stats
        #: Serialises deliveries and queue access between threads (re-entrant).
        self.lock = threading.RLock()
        #: The counter of the last message taken (0: none since the last reset).
        self.last_in = 0
        #: A read may have emptied SM1 without its reply reaching us.
        self.lost = False
        self._queue: deque[ReceivedMessage | MailboxErrorReply] = deque(maxlen=64)
        self._handlers: list[Callable[[_Owner, ReceivedMessage], bool]] = []
        # Snapshot of the handlers (replaced, never changed in place, so no copy per message).
        self._handler_list: tuple[Callable[[_Owner, ReceivedMessage], bool], ...] = ()

    # -- handlers ---------------------------------------------------------------------------

    def add_handler(self, handler: Callable[[_Owner, ReceivedMessage], bool]) -> None:
        """Offer every message to ``handler`` first; it returns True when it took it."""
        self._handlers.append(handler)
        self._handler_list = tuple(self._handlers)

    def remove_handler(self, handler: Callable[[_Owner, ReceivedMessage], bool]) -> None:
        if handler in self._handlers:
            self._handlers.remove(handler)
        self._handler_list = tuple(self._handlers)

    # -- the queue --------------------------------------------------------------------------

    def clear(self) -> int:
        """Empty the queue (error replies too); returns how many items it held."""
        with self.lock:
            n = len(self._queue)
            self._queue.clear()
            return n

    def take(self, accept: Accept | None, what: str,
             stale: Accept | None = None) -> ReceivedMessage | None:
        """The oldest queued message ``accept`` takes (any when None), or None.

        A queued error reply raises it (it answers the transaction in
        progress); messages ``stale`` takes are dropped on the way.
        """
        if not self._queue:
            return None
        with self.lock:
            queue = self._queue
            for item in list(queue):
                if isinstance(item, MailboxErrorReply):
                    queue.remove(item)
                    err = MailboxErrorReply(item.code, item.name)
                    err.args = (f"{self.label}: {err} (answering {what})",)
                    raise err
                if accept is None or accept(item):
                    queue.remove(item)
                    return item
                if stale is not None and stale(item):
                    # A late answer to an earlier request (a slow slave, another
                    # master's request): not ours, and no error either.
                    queue.remove(item)
                    self.stats.stale += 1
                    _log.debug("%s: stale mailbox message (counter %d) dropped while "
                               "waiting for the %s", self.label, item.header.counter, what)
        return None

    def drop(self, accept: Accept) -> int:
        """Throw away queued messages ``accept`` takes (late answers); returns how many."""
        with self.lock:
            stale = [m for m in self._queue if isinstance(m, ReceivedMessage) and accept(m)]
            for m in stale:
                self._queue.remove(m)
            return len(stale)

    def pending(self) -> list[ReceivedMessage]:
        """Take every queued message (those no transaction asked for)."""
        with self.lock:
            out = [m for m in self._queue if isinstance(m, ReceivedMessage)]
            self._queue.clear()
            return out

    # -- arrivals ---------------------------------------------------------------------------

    def deliver(self, raw: bytes, take: Accept | None = None) -> ReceivedMessage | None:
        """Check and dispatch a message read from SM1; returns it instead of queueing it
        when ``take`` accepts it and the queue is empty (older messages go first)."""
        try:
            header = MailboxHeader.decode(raw)
        except MailboxError as exc:
            raise MailboxError(f"{self.label}: {exc}") from None
        if header.length > len(raw) - MAILBOX_HEADER_SIZE:
            raise MailboxError(f"{self.label}: mailbox length {header.length} exceeds the "
                               f"{len(raw) - MAILBOX_HEADER_SIZE} bytes of SM{self.tx_sm}")
        stats = self.stats
        with self.lock:
            if is_repeated_counter(self.last_in, header.counter):
                stats.duplicates += 1
                _log.debug("%s: mailbox counter %d repeated, dropped", self.label,
                           header.counter)
                return None
            self.last_in = header.counter
            stats.received += 1
            end = MAILBOX_HEADER_SIZE + header.length
            msg = ReceivedMessage(header, raw[MAILBOX_HEADER_SIZE:end], raw[end:end + 8])
            if header.type == MailboxType.ERR:
                stats.error_replies += 1
                try:
                    err = decode_mailbox_error(msg.payload)
                except MailboxError as exc:
                    err = MailboxErrorReply(0, f"malformed error reply ({exc})")
                self._queue.append(err)
                return None
            owner = self.owner
            for handler in self._handler_list:
                if handler(owner, msg):
                    stats.unsolicited += 1
                    return None
            if take is not None and not self._queue and take(msg):
                return msg
            self._queue.append(msg)
            return None

    def take_read(self, req: Request, early: bool = False) -> bool:
        """Handle a finished SM1 read: deliver the message or note a possible loss.

        True when a message came. ``early``: the read rode with an SM0 write.
        """
        if req.error is not None:
            if isinstance(req.error, EcTimeoutError):
                # One of the attempts may have emptied SM1 on its way.
                self.lost = True
                return False
            raise named_error(req.error, f"{self.label}: reading the mailbox")
        reply = req.reply
        assert reply is not None
        if reply.wkc != 1:
            if req.attempts > 1:
                # An earlier attempt may have read (and emptied) SM1; its frame was lost.
                self.lost = True
            return False
        if early:
            self.stats.early_replies += 1
        self.deliver(bytes(reply.data))
        return True


def named_error(error: EtherCATError, where: str) -> EtherCATError:
    """An error like ``error`` with ``where`` in front of its message.

    A new object: the scheduler may hand one error to every request of a frame.
    """
    if isinstance(error, EcTimeoutError):
        return EcTimeoutError(f"{where}: {error}")
    if isinstance(error, FrameError):
        return FrameError(f"{where}: {error}")
    return error
