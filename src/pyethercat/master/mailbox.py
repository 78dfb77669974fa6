"""Mailbox transport, master side: SM0/SM1 handshake, counters, polling, repeat requests.

One :class:`Mailbox` per slave carries mailbox messages of any protocol
(CoE, FoE, EoE, SoE) to and from that slave (ETG.1000.4 mailbox; SM0/SM1 in
mailbox mode as the ET1100 datasheet section II "SyncManager" describes):

- **Send**: the message gets the next counter (1..7, then 1 again), is padded
  to the whole SM0 length and written with one FPWR (the ESC flips SM0 to
  "full" only when the last byte is written). A refused write (working
  counter 0: SM0 still full, the slave has not read the previous message) is
  tried again until the timeout. The same frame carries a speculative FPRD of
  the whole SM1: a fast slave (or a simulator) has the answer ready at once
  and the transaction costs one round trip; an empty SM1 simply refuses the
  read (working counter 0), which changes nothing in the ESC. That frame is
  encoded once per mailbox and only refilled per message (the scheduler's
  prepared frames): the path every step of a segmented transfer takes.
- **Poll**: while a reply is awaited, SM1's status byte (0x080D, bit 3
  "mailbox full") is polled. Without cyclic exchange the polls of all waiting
  mailboxes are batched: one frame reads the status of every slave that has
  a transaction in progress (:class:`MailboxPoller`). When cyclic exchange
  runs and the status byte is mapped into the cyclic frame by a read FMMU
  (``master.config`` does it for every mailbox slave of a group),
  ``Mailbox.status_source`` takes it from the process image instead: the
  mailbox waits for a cycle that began after its last SM1 read and looks at
  the byte; no poll frames while the group's working counter comes right
  (a lost cyclic frame costs a cycle's wait).
- **Fetch**: FPRD of the whole SM1; reading the last byte empties it.
- **Repeat request** (SOEM ``ec_main.c`` ``ecx_mbxreceive``, SOES ``esc.c``
  ``ESC_mbxprocess``): when a fetch may have emptied SM1 but its
  reply frame was lost (the scheduler had to send the read again and the
  retry came back with working counter 0), or when the status said "full"
  and the read found nothing, the master toggles SM1 activate bit 1, waits
  for the slave to echo it in PDI control bit 1 (repeat acknowledge), and
  reads the re-posted message.
- **Take-over**: a slave drops a request whose counter repeats the last one
  it took (ETG.1000.4, mailbox header "Cnt"), and a slave that another
  master (SOEM, IgH, an earlier session) left in PREOP may remember any
  counter 1..7, so our first request (counter 1) may be dropped without a
  word. Until the first answer came since the master took the mailbox over
  (a new master, a reset at INIT, a drain, a repeat request),
  :meth:`Mailbox.transact` therefore sends a request that got no answer
  within half its timeout once more, with the next counter, which the slave
  cannot have taken last. Every request that expects an answer goes through
  it (CoE, FoE packets, SoE requests, EoE, the mailbox gateway); plain
  :meth:`Mailbox.send` is for messages nothing answers (an abort, an FoE
  read's last ACK, the leading fragments of an SoE write). Once an answer came the counters are in sync and
  a request is never sent twice: a slow slave (writing flash for 0x1010)
  would execute it twice and answer twice. Before the first request,
  whatever an earlier master left in SM1 (a reply it never read) is read and
  dropped (:meth:`Mailbox.drain`), so it cannot pass for the answer; a late
  answer that arrives during a later transaction is recognised by the
  client's ``stale`` test (CoE: service, command, index, subindex, toggle)
  and dropped too.
- **Check**: length word against the SM size, duplicate counters (a message
  with the same non-zero counter as the previous one is a repetition and is
  dropped), mailbox error replies (type 0) raise
  :class:`~pyethercat.errors.MailboxErrorReply`, unsolicited messages (CoE
  emergencies) go to registered handlers, everything else waits in an inbox
  until the protocol client that wants it takes it.

Transactions to different slaves run concurrently: each mailbox has its own
lock (protocol clients hold ``Mailbox.lock`` for a whole transfer, such as a
segmented SDO upload), and no global lock is held while waiting; the
scheduler packs the datagrams of concurrent transactions into shared frames.

The mailbox keeps the counters, the take-over rule, polling and the repeat
request; two parts do the rest: :class:`~pyethercat.master.mailbox_inbox.MailboxInbox`
(``Mailbox.inbox``: the check, the handlers and the queue of what SM1 brought)
and :class:`~pyethercat.master.mailbox_frame.MailboxFrame` (``Mailbox.frame``:
the prepared ``[SM0 write, SM1 read]`` frame, the hot path of every step).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from pyethercat.errors import (
    EtherCATError,
    MailboxError,
    MailboxErrorReply,
    WorkingCounterError,
)
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.mailbox_frame import MAILBOX_HEADER, MailboxFrame
from pyethercat.master.mailbox_inbox import (
    Accept,
    MailboxInbox,
    MailboxStats,
    ReceivedMessage,
    named_error,
)
from pyethercat.master.scheduler import Scheduler
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE, MailboxType, next_counter

__all__ = [
    "DEFAULT_MAILBOX_TIMEOUT",
    "ClientContext",
    "DropOldestQueue",
    "Mailbox",
    "ReceivedMessage",
    "MailboxPoller",
    "MailboxStats",
    "StatusSource",
    "UnsolicitedHandler",
    "Accept",
]

_log = logging.getLogger("pyethercat.mailbox")

#: Seconds a mailbox transaction may take by default (SOEM uses 0.7 s, IgH 1 s).
DEFAULT_MAILBOX_TIMEOUT = 1.0
#: Polls go back to back this long; then with growing pauses (real links only).
_BUSY_POLL = 0.002
_MAX_POLL_PAUSE = 0.001


_T = TypeVar("_T")


class DropOldestQueue(queue.Queue[_T]):
    """A :class:`queue.Queue` whose ``put`` never blocks: when full, the oldest item goes.

    Unsolicited messages (CoE emergencies) must not stall the thread that read
    them (a mailbox transaction) and the newest ones matter most.
    """

    def put(self, item: _T, block: bool = True, timeout: float | None = None) -> None:
        """Append ``item``, dropping the oldest one first when the queue is full."""
        with self.not_full:
            if 0 < self.maxsize <= self._qsize():
                self._get()
            self._put(item)
            self.unfinished_tasks += 1
            self.not_empty.notify()

    def put_nowait(self, item: _T) -> None:
        """Same as :meth:`put` (it never blocks)."""
        self.put(item)


@dataclass(frozen=True, slots=True)
class ClientContext:
    """What a mailbox protocol client gets from the master when it is made for a slave.

    ``position`` is the slave's ring position; ``events`` the master's queue
    for the unsolicited messages of this protocol (shared by the clients of
    every slave: ``master.emergencies`` for CoE); ``report`` passes such an
    event to the master's callbacks.
    """

    position: int
    events: DropOldestQueue[Any]
    report: Callable[[Any], None]


#: Called with every message read from a slave; returns True when it took the message.
UnsolicitedHandler = Callable[["Mailbox", ReceivedMessage], bool]
class StatusSource(Protocol):
    """Where a mailbox takes its SM1 status byte from instead of a poll frame: the
    cyclic image (``master.mailboxes.CyclicMailboxStatus``)."""

    def __call__(self, budget: float) -> int | None:
        """The byte, read by a cycle that began after the call, waiting up to ``budget``
        seconds (0: the last one read). None: no cyclic exchange carries it now (or not
        in time, or its working counter was off): poll."""
        ...

    def cycling(self) -> bool:
        """Whether a cyclic exchange carries the byte now."""
        ...


class MailboxPoller:
    """Batches SM1 status polls of concurrent transactions into shared frames.

    A caller that needs a fresh status joins the next poll round; the first
    caller to find no round running performs it for everybody waiting (one
    FPRD of 0x080D per slave, all in the same frames) and hands out the
    results. No lock is held while the frame is on the wire.
    """

    def __init__(self, scheduler: Scheduler) -> None:
        self.scheduler = scheduler
        self._cond = threading.Condition()
        self._pending: dict[Mailbox, None] = {}
        self._results: dict[Mailbox, int | None | EtherCATError] = {}
        self._busy = False
        #: Poll rounds performed and statuses read (for tests and statistics).
        self.rounds = 0
        self.polled = 0

    def status(self, mailbox: Mailbox) -> int | None:
        """SM1 status byte of ``mailbox`` read by a round that started after this call.

        ``None`` when the slave did not answer the read.
        """
        with self._cond:
            self._pending[mailbox] = None
            while True:
                if mailbox in self._results and mailbox not in self._pending:
                    return self._take(mailbox)
                if not self._busy:
                    break
                self._cond.wait(0.05)
            self._busy = True
            batch = list(self._pending)
            self._pending.clear()
        results: dict[Mailbox, int | None | EtherCATError] = {}
        try:
            dgs = [Datagram.device(Command.FPRD, m.station, m.status_address, 1) for m in batch]
            replies = self.scheduler.transact(dgs)
            for m, r in zip(batch, replies, strict=True):
                results[m] = r.data[0] if r.wkc == 1 else None
        except EtherCATError as exc:
            for m in batch:
                results[m] = exc
        with self._cond:
            self.rounds += 1
            self.polled += len(batch)
            self._results.update(results)
            self._busy = False
            self._cond.notify_all()
            return self._take(mailbox)

    def _take(self, mailbox: Mailbox) -> int | None:
        got = self._results.pop(mailbox)
        if isinstance(got, EtherCATError):
            raise got
        return got


class Mailbox:
    """The mailbox of one slave (see the module text).

    ``station`` is the slave's configured address, ``label`` how messages
    name the slave (``slave 3 (0x1004, EL6751)``). ``rx_*`` describe SM
    ``rx_sm`` (master -> slave, usually SM0), ``tx_*`` SM ``tx_sm`` (slave
    -> master, usually SM1).
    """

    def __init__(self, scheduler: Scheduler, station: int, label: str, *,
                 rx_offset: int, rx_size: int, tx_offset: int, tx_size: int,
                 rx_sm: int = 0, tx_sm: int = 1, poller: MailboxPoller | None = None,
                 timeout: float = DEFAULT_MAILBOX_TIMEOUT,
                 clock: Callable[[], float] | None = None,
                 sleep: Callable[[float], None] | None = None) -> None:
        for name, size in (("receive (SM0)", rx_size), ("send (SM1)", tx_size)):
            if size < MAILBOX_HEADER_SIZE + 2:
                raise MailboxError(f"{label}: {name} mailbox of {size} bytes is too small")
        self.scheduler = scheduler
        self.station = station
        self.label = label
        self.rx_offset = rx_offset
        self.rx_size = rx_size
        self.tx_offset = tx_offset
        self.tx_size = tx_size
        self.rx_sm = rx_sm
        self.tx_sm = tx_sm
        self.poller = poller if poller is not None else MailboxPoller(scheduler)
        self.timeout = timeout
        # The scheduler's time by default (virtual time moves on instead of sleeping).
        self.clock = scheduler.now if clock is None else clock
        self._sleep = scheduler.sleep if sleep is None else sleep
        #: Held by a protocol client for a whole transaction (re-entrant).
        self.lock = threading.RLock()
        self._counter = 0
        # Whether SM1 was emptied of what an earlier session left there.
        self._drained = False
        # Whether an answer came since the master took the mailbox over: the
        # slave's counter is then ours, and a request is never sent twice.
        self.synced = False
        #: SM1's status byte from the cyclic process image (None: poll with frames).
        self.status_source: StatusSource | None = None
        self.stats = MailboxStats()
        #: What SM1 brought: checks, handlers, the queue (``master.mailbox_inbox``).
        self.inbox: MailboxInbox[Mailbox] = MailboxInbox(self, label, tx_sm, self.stats)
        #: The prepared [SM0 write, SM1 read] frame (``master.mailbox_frame``).
        self.frame = MailboxFrame(scheduler, self.inbox, station, rx_offset=rx_offset,
                                  rx_size=rx_size, tx_offset=tx_offset, tx_size=tx_size)
        # The SM1 read, one object for every read (the scheduler copies it into each frame).
        self._read = self.frame.read

    # -- addresses -------------------------------------------------------------------

    @property
    def status_address(self) -> int:
        """SM1 status register (0x080D for SM1)."""
        return reg.sm_address(self.tx_sm) + reg.SM_STATUS

    @property
    def activate_address(self) -> int:
        return reg.sm_address(self.tx_sm) + reg.SM_ACTIVATE

    @property
    def pdi_control_address(self) -> int:
        return reg.sm_address(self.tx_sm) + reg.SM_PDI_CONTROL

    @property
    def max_payload(self) -> int:
        """Largest payload one message to the slave can carry."""
        return self.rx_size - MAILBOX_HEADER_SIZE

    # -- handlers ---------------------------------------------------------------------

    def add_handler(self, handler: UnsolicitedHandler) -> None:
        """Offer every message read from the slave to ``handler`` first (emergencies)."""
        self.inbox.add_handler(handler)

    def remove_handler(self, handler: UnsolicitedHandler) -> None:
        self.inbox.remove_handler(handler)

    def reset(self) -> None:
        """Forget counters and queued messages (after the slave went back to INIT)."""
        inbox = self.inbox
        with inbox.lock:
            self._counter = 0
            inbox.last_in = 0
            inbox.clear()
            inbox.lost = False
            self._drained = False
            self.synced = False

    def drain(self, limit: int = 4) -> int:
        """Read and discard what SM1 holds from before (another master, an earlier session).

        Emergencies among it still reach the handlers. Returns the number of
        stale messages dropped. Transactions do this once by themselves.
        """
        dropped = 0
        for _ in range(limit):
            if not self.fetch():
                break
        inbox = self.inbox
        with inbox.lock:
            dropped = inbox.clear()
            inbox.lost = False
            self._drained = True
            self.synced = False
        if dropped:
            _log.info("%s: %d stale mailbox message%s dropped", self.label, dropped,
                      "s" if dropped != 1 else "")
        return dropped

    def next_counter(self) -> int:
        """The counter of the next message (1..7, wrapping to 1)."""
        self._counter = next_counter(self._counter)
        return self._counter

    # -- sending ------------------------------------------------------------------------

    def send(self, mtype: MailboxType | int, payload: bytes, *, what: str = "mailbox message",
             timeout: float | None = None, fetch: bool = True, counter: int | None = None,
             ) -> int:
        """Write one message into SM0 (whole SM length); returns the counter used.

        ``fetch`` adds the speculative SM1 read to the same frame. Raises
        :class:`~pyethercat.errors.TimeoutError` when SM0 stays full. A message
        that expects an answer goes through :meth:`transact` instead (the
        take-over rule, see the module text).
        """
        return self._send(mtype, payload, what, timeout, fetch, counter, None)[0]

    def _send(self, mtype: MailboxType | int, payload: bytes, what: str,
              timeout: float | None, fetch: bool, counter: int | None,
              take: Accept | None) -> tuple[int, ReceivedMessage | None]:
        if len(payload) > self.max_payload:
            raise MailboxError(f"{self.label}: {what} needs {len(payload)} bytes, the mailbox "
                               f"carries {self.max_payload}")
        if not self._drained:
            self.drain()
        cnt = self.next_counter() if counter is None else counter
        if not 0 <= cnt <= 7:
            raise MailboxError(f"{self.label}: mailbox counter {cnt} out of range 0..7")
        # mailbox header (ETG.1000.4) type and counter byte: the hot path of every
        # transfer step writes header and payload straight into the prepared frame
        kind = (int(mtype) & 0x0F) | (cnt << 4)
        limit = self.clock() + (self.timeout if timeout is None else timeout)
        waited = 0.0
        prepared = self.frame
        template = prepared.prepared() if fetch else None
        write = None
        if template is None:
            frame = (MAILBOX_HEADER.pack(len(payload), 0, 0, kind) + payload
                     ).ljust(self.rx_size, b"\x00")
            write = Datagram(Command.FPWR, 0, prepared.rx_address, frame)
        taken = None
        while True:
            if template is not None:
                wkc, taken = prepared.write_and_read(template, payload, kind, what, take)
            else:
                assert write is not None
                dgs = [write, self._read] if fetch else [write]
                reqs = self.scheduler.submit(dgs)
                self.scheduler.wait(reqs)
                sent = reqs[0]
                if fetch:
                    self.inbox.take_read(reqs[1], early=True)
                if sent.error is not None:
                    raise named_error(sent.error, f"{self.label}: sending {what}")
                assert sent.reply is not None
                wkc = sent.reply.wkc
            if wkc == 1:
                self.stats.sent += 1
                return cnt, taken
            self.stats.write_refused += 1
            now = self.clock()
            if now >= limit:
                raise EcTimeoutError(f"{self.label}: mailbox (SM{self.rx_sm}) still full, "
                                     f"{what} not taken within "
                                     f"{(self.timeout if timeout is None else timeout):g} s")
            waited = self._pause(waited)

    # -- receiving ------------------------------------------------------------------------

    def receive(self, accept: Accept | None = None, *, what: str = "mailbox reply",
                timeout: float | None = None, stale: Accept | None = None,
                ) -> ReceivedMessage:
        """Wait for a message ``accept`` takes (any message when None).

        Messages ``stale`` takes and ``accept`` does not (late answers to an
        earlier request) are dropped; other messages nobody wants stay in the
        inbox for other clients. A mailbox error reply raises
        :class:`~pyethercat.errors.MailboxErrorReply`; no message in time
        raises :class:`~pyethercat.errors.TimeoutError`.
        """
        span = self.timeout if timeout is None else timeout
        limit = self.clock() + span
        waited = 0.0
        inbox = self.inbox
        # A fast slave's answer is there by the frame after the request's: read SM1 at once
        # (an empty mailbox reads with WKC 0 and stays as it is), then poll its status. (Not
        # while the cyclic frames bring the status byte: the next cycle tells.)
        source = self.status_source
        direct = source is None or not source.cycling()
        while True:
            got = inbox.take(accept, what, stale)
            if got is not None:
                return got
            if inbox.lost:
                inbox.lost = False
                self.repeat_request(limit)
                continue
            now = self.clock()
            if now >= limit:
                raise EcTimeoutError(f"{self.label}: no {what} within {span:.3g} s")
            if direct:
                direct = False
                if self.fetch():
                    continue
            status, cyclic = self._status(limit - now)
            if status is not None and status & reg.SM_STATUS_MAILBOX_FULL:
                if not self.fetch() and not inbox.lost:
                    # Full a moment ago, empty now: somebody's read got it and lost it.
                    inbox.lost = True
                waited = 0.0
                continue
            if not cyclic:  # (waiting for the cycle was the pause)
                waited = self._pause(waited)

    def transact(self, mtype: MailboxType | int, payload: bytes, accept: Accept | None = None,
                 *, what: str = "mailbox request", timeout: float | None = None,
                 stale: Accept | None = None) -> ReceivedMessage:
        """Send a request and wait for the message ``accept`` takes as its answer.

        While the mailbox is not yet in sync (:attr:`synced`), a request
        unanswered within half of ``timeout`` is sent once more with the
        next counter (see the module text: the slave may have dropped it as
        a repetition of another master's last counter). Once in sync it is
        sent once and no answer in time raises
        :class:`~pyethercat.errors.TimeoutError`: the slave took the request
        (SM0 write accepted) and may still be executing it. ``stale`` names
        the late answers to earlier requests, dropped while waiting.
        """
        span = self.timeout if timeout is None else timeout
        clock = self.clock
        limit = clock() + span
        answer = f"reply to {what}"
        with self.lock:
            got = self._send(mtype, payload, what, span, True, None,
                             _any if accept is None else accept)[1]
            if got is not None:
                self.synced = True  # (the answer came in the frame that carried the request)
                return got
            if self.synced:
                try:
                    return self._answer(accept, answer, limit - clock(), stale)
                except EcTimeoutError:
                    raise EcTimeoutError(f"{self.label}: no {answer} within {span:.3g} s "
                                         "(the slave took the request; not sent again)"
                                         ) from None
            try:
                return self._answer(accept, answer, limit - span / 2 - clock(), stale)
            except EcTimeoutError:
                pass
            self.stats.resent += 1
            _log.info("%s: no %s, %s sent again with the next counter", self.label, answer,
                      what)
            self.send(mtype, payload, what=what, timeout=max(0.0, limit - clock()))
            try:
                return self._answer(accept, answer, limit - clock(), stale)
            except EcTimeoutError:
                raise EcTimeoutError(f"{self.label}: no {answer} within {span:.3g} s (sent "
                                     "twice, with two counters)") from None

    def _answer(self, accept: Accept | None, what: str, budget: float,
                stale: Accept | None) -> ReceivedMessage:
        """The answer to the request just sent; the mailbox is in sync once one came."""
        try:
            got = self.receive(accept, what=what, timeout=max(0.0, budget), stale=stale)
        except MailboxErrorReply:
            self.synced = True  # an error reply answers the request too
            raise
        self.synced = True
        return got

    def fetch(self) -> bool:
        """Read SM1 once; True when a message came (it is dispatched or queued)."""
        req = self.scheduler.submit([self._read])[0]
        self.scheduler.wait([req])
        self.stats.fetches += 1
        return self.inbox.take_read(req)

    def deliver(self, raw: bytes) -> None:
        """Dispatch an SM1 image read by someone else (the EoE service's own reads):
        duplicate check, error replies, handlers, inbox, as a fetch does."""
        self.stats.fetches += 1
        self.inbox.deliver(raw)

    def poll(self) -> bool:
        """Fetch whatever the slave posted, without waiting; True when something came.

        Nothing while another thread's transaction holds :attr:`lock`: that
        transaction reads SM1 itself (emergencies reach the handlers through
        it). A second reader would race it: its fetch may come back after a
        later one of the transaction's, so fragments reach the inbox out of
        order, and a status byte seen "full" before the other read empties
        SM1 makes the transaction ask for a repeat it did not need.
        """
        if not self.lock.acquire(blocking=False):
            return False
        try:
            status, _cyclic = self._status(0.0)
            if status is not None and status & reg.SM_STATUS_MAILBOX_FULL:
                return self.fetch()
            return False
        finally:
            self.lock.release()

    def drop(self, accept: Accept) -> int:
        """Throw away queued messages ``accept`` takes (late answers); returns how many."""
        return self.inbox.drop(accept)

    def pending(self) -> list[ReceivedMessage]:
        """Take every queued message (those no transaction asked for)."""
        return self.inbox.pending()

    # -- repeat ---------------------------------------------------------------------------

    def repeat_request(self, limit: float | None = None) -> None:
        """Ask the slave to post its last message again (the repeat request, see the module text).

        Toggles SM1 activate bit 1, waits for the repeat acknowledge (PDI
        control bit 1 equal to it); the caller then polls and reads as usual.
        """
        if limit is None:
            limit = self.clock() + self.timeout
        self.stats.repeat_requests += 1
        self.synced = False  # what comes next may be the answer to an older request
        act = self._read_register(self.activate_address, 1, "SM activate")[0]
        new = act ^ reg.SM_ACTIVATE_REPEAT
        reply = self.scheduler.transact_one(
            Datagram.device(Command.FPWR, self.station, self.activate_address, bytes([new])))
        if reply.wkc != 1:
            raise WorkingCounterError(f"{self.label}: repeat request (SM{self.tx_sm} activate)",
                                      1, reply.wkc)
        _log.info("%s: mailbox reply lost, repeat requested", self.label)
        want = bool(new & reg.SM_ACTIVATE_REPEAT)
        waited = 0.0
        while True:
            pdi = self._read_register(self.pdi_control_address, 1, "SM PDI control")[0]
            if bool(pdi & reg.SM_PDI_REPEAT_ACK) == want:
                return
            if self.clock() >= limit:
                raise EcTimeoutError(f"{self.label}: no repeat acknowledge from the slave "
                                     f"(SM{self.tx_sm} PDI control)")
            waited = self._pause(waited)

    # -- internals --------------------------------------------------------------------------

    def _read_register(self, address: int, size: int, what: str) -> bytes:
        reply = self.scheduler.transact_one(
            Datagram.device(Command.FPRD, self.station, address, size))
        if reply.wkc != 1:
            raise WorkingCounterError(f"{self.label}: reading {what} at 0x{address:04X}", 1,
                                      reply.wkc)
        return bytes(reply.data)

    def _pause(self, waited: float) -> float:
        """Pause between polls: none at first, then growing."""
        pause = 0.0 if waited < _BUSY_POLL else min(_MAX_POLL_PAUSE, max(0.0001, waited / 8))
        if pause:
            self._sleep(pause)
        return waited + max(pause, 0.0001)

    def _status(self, budget: float) -> tuple[int | None, bool]:
        """SM1 status read after this call (cyclic image or a poll frame); whether cyclic."""
        source = self.status_source
        if source is not None:
            status = source(budget)
            if status is not None:
                self.stats.cyclic_status += 1
                return status, True
        self.stats.status_polls += 1
        return self.poller.status(self), False

    def __repr__(self) -> str:
        return (f"<Mailbox {self.label} SM{self.rx_sm} 0x{self.rx_offset:04X}+{self.rx_size} "
                f"SM{self.tx_sm} 0x{self.tx_offset:04X}+{self.tx_size}>")


def _any(msg: ReceivedMessage) -> bool:
    return True
