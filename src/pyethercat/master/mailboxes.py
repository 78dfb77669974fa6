"""The mailbox service of a master: every slave's mailbox, its protocol clients, their events.

:class:`MailboxService` is what a :class:`~pyethercat.master.master.Master`
does for mailboxes across slaves:

- after a scan (:meth:`MailboxService.attach`) every slave with a mailbox gets
  its :class:`~pyethercat.master.mailbox.Mailbox` and one client of every
  registered protocol class (:mod:`pyethercat.master.clients`); all
  mailboxes share one :class:`~pyethercat.master.mailbox.MailboxPoller`, so
  concurrent transactions poll in shared frames. The service keeps them by
  position; a slave handle asks for them (``slave.mbx``,
  ``slave.client(CoeClient)``, ``slave.coe``);
- while cyclic exchange runs, each mailbox takes its SM1 status from the
  byte the cyclic frame reads into the group image (:class:`CyclicMailboxStatus`,
  the FMMU ``master.config`` maps): no poll frames;
- unsolicited messages a client reports (CoE emergencies) wait in one queue
  per protocol (``master.emergencies`` for CoE) and go to the callbacks given
  to :meth:`MailboxService.on_event`;
- as a :class:`~pyethercat.master.transitions.TransitionHook` it writes the
  mailbox sync managers before INIT -> PREOP/BOOT, forgets counters and
  messages when slaves go back to INIT, and empties SM1 of whatever an earlier
  session left there once a slave reaches PRE-OP.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

from pyethercat.master import states
from pyethercat.master.clients import MailboxClient, registered_clients
from pyethercat.master.coe import CoeClient, EmergencyEvent
from pyethercat.master.mailbox import (
    DEFAULT_MAILBOX_TIMEOUT,
    ClientContext,
    DropOldestQueue,
    Mailbox,
    MailboxPoller,
)
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.master.transitions import Step
from pyethercat.wire.al import AlState

if TYPE_CHECKING:
    from pyethercat.master.cyclic import CyclicRunner

__all__ = ["CyclicMailboxStatus", "MailboxService"]

_log = logging.getLogger("pyethercat.mailbox")
C = TypeVar("C")

#: Unsolicited events kept per protocol (oldest dropped beyond that).
EVENT_QUEUE_SIZE = 1024


class CyclicMailboxStatus:
    """``Mailbox.status_source`` of one slave: its SM1 status byte in the running cycle's image.

    The group's cyclic frame reads SM1's status register (0x080D) into the
    image through the FMMU ``master.config`` maps. A call waits until an
    exchange of the slave's group that began after the call completed (the
    next one when none is under way, else two: the byte is newer than the
    caller's last SM1 read) and returns the byte. When the group's working
    counter was off (a frame lost or a slave not answering since), it waits
    for one more exchange, up to :attr:`RETRIES` times: one lost cyclic
    frame costs a cycle, not a poll frame. None when no cyclic exchange
    runs, the slave has no status byte, nothing came within ``budget`` or
    the counter stayed off (the mailbox then polls with a frame).
    """

    #: Further exchanges awaited while the group's working counter is off.
    RETRIES = 3

    def __init__(self, runner: Callable[[], CyclicRunner | None], position: int) -> None:
        self._runner = runner
        self.position = position
        self._where: tuple[CyclicRunner, str, int] | None = None

    def _locate(self) -> tuple[CyclicRunner, str, int] | None:
        runner = self._runner()
        if runner is None or not runner.running:
            return None
        where = self._where
        if where is not None and where[0] is runner:
            return where
        sc = runner.config.slaves.get(self.position)
        if sc is None or sc.mailbox_status_offset < 0:
            return None
        if not any(g.name == sc.group for g in runner.groups):
            return None  # the runner does not exchange this slave's group
        self._where = (runner, sc.group, sc.mailbox_status_offset)
        return self._where

    def cycling(self) -> bool:
        """Whether a cyclic exchange runs and brings this slave's status byte."""
        return self._locate() is not None

    def __call__(self, budget: float) -> int | None:
        where = self._locate()
        if where is None:
            return None
        runner, group, at = where
        # Until an exchange that began after this call is done, so that its byte is newer
        # than the caller's last SM1 read: the next one when none is under way, else the
        # one after. (False from the loop thread itself.)
        if budget <= 0:  # (no time to wait: the byte as it is)
            status = runner.group_status(group)
            return status.image[at] if status.wkc_ok else None
        limit = time.monotonic() + budget
        wait = runner.exchanges_after_now()
        for _ in range(self.RETRIES + 1):
            left = limit - time.monotonic()
            if left <= 0 or not runner.wait_exchanges(group, wait, left):
                return None
            status = runner.group_status(group)
            if status.wkc_ok:
                return status.image[at]
            wait = 1  # a lost frame leaves the counter off until the next exchange completes
        return None


class MailboxService:
    """Mailboxes and protocol clients of a master's slaves (see the module text).

    ``runner`` returns the cyclic runner when one exists (its image carries
    the SM1 status bytes); ``timeout`` is the default time of one mailbox
    transaction.
    """

    def __init__(self, scheduler: Scheduler, *,
                 runner: Callable[[], CyclicRunner | None] = lambda: None,
                 timeout: float = DEFAULT_MAILBOX_TIMEOUT) -> None:
        self.scheduler = scheduler
        self.timeout = timeout
        self.poller = MailboxPoller(scheduler)
        #: Client classes made for every mailbox slave, by mailbox type (a copy of the
        #: registry when the master was made; add more with :meth:`register`).
        self.client_classes = registered_clients()
        self._runner = runner
        self._boxes: dict[int, Mailbox] = {}
        self._clients: dict[int, dict[type, Any]] = {}
        self._queues: dict[type, DropOldestQueue[Any]] = {}
        self._callbacks: list[Callable[[Any], None]] = []

    # -- clients ------------------------------------------------------------------------

    def register(self, cls: type[MailboxClient]) -> None:
        """Give every mailbox slave a ``cls`` client from the next :meth:`attach` on."""
        self.client_classes[cls.mailbox_type] = cls

    def events(self, cls: type) -> DropOldestQueue[Any]:
        """The queue of unsolicited events reported by the clients of class ``cls``."""
        q = self._queues.get(cls)
        if q is None:
            q = self._queues[cls] = DropOldestQueue(EVENT_QUEUE_SIZE)
        return q

    @property
    def emergencies(self) -> DropOldestQueue[EmergencyEvent]:
        """Emergencies of every slave (oldest dropped when 1024 are waiting)."""
        return self.events(CoeClient)

    def on_event(self, callback: Callable[[Any], None]) -> None:
        """Call ``callback(event)`` for every unsolicited event of every slave (emergencies)."""
        self._callbacks.append(callback)

    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None:
        """Call ``callback(event)`` for every CoE emergency of every slave."""

        def only_emergencies(event: object) -> None:
            if isinstance(event, EmergencyEvent):
                callback(event)

        self.on_event(only_emergencies)

    def _report(self, event: object) -> None:
        for cb in list(self._callbacks):
            try:
                cb(event)
            except Exception:  # noqa: BLE001 - never let a callback break the mailbox
                _log.exception("mailbox event callback failed")

    def attach(self, slaves: Sequence[SlaveInfo]) -> None:
        """Make the mailbox and the clients of every slave with a mailbox (after a scan)."""
        self._boxes.clear()
        self._clients.clear()
        self.add(slaves)

    def add(self, slaves: Sequence[SlaveInfo]) -> None:
        """Make the mailbox and the clients of these slaves (found after the scan: a hot
        connect group that appeared); the others' stay as they are."""
        for s in slaves:
            info = s.mailbox
            if info is None or not s.has_mailbox:
                continue
            box = Mailbox(self.scheduler, s.station_address, s.describe(),
                          rx_offset=info.rx_offset, rx_size=info.rx_size,
                          tx_offset=info.tx_offset, tx_size=info.tx_size, poller=self.poller,
                          timeout=self.timeout)
            box.status_source = CyclicMailboxStatus(self._runner, s.position)
            self._boxes[s.position] = box
            made: dict[type, Any] = {}
            for cls in self.client_classes.values():
                context = ClientContext(s.position, self.events(cls), self._report)
                made[cls] = cls.for_mailbox(box, context)
            self._clients[s.position] = made

    def mailbox_of(self, position: int) -> Mailbox | None:
        """The mailbox of the slave at ``position`` (None: it has none)."""
        return self._boxes.get(position)

    def client_of(self, position: int, kind: type[C]) -> C | None:
        """The client of class ``kind`` of the slave at ``position`` (None: no mailbox).

        Raises :class:`KeyError` naming the class when no such client class is
        registered.
        """
        made = self._clients.get(position)
        if made is None:
            return None
        client = made.get(kind)
        if client is None:
            raise KeyError(f"no mailbox client {kind.__name__} is registered "
                           f"(registered: {', '.join(c.__name__ for c in made)})")
        assert isinstance(client, kind)
        return client

    def poll(self, slaves: Sequence[SlaveInfo]) -> int:
        """Fetch whatever the slaves posted unasked (emergencies); returns how many came."""
        got = 0
        for s in slaves:
            box = self._boxes.get(s.position)
            if box is not None and box.poll():
                got += 1
        return got

    # -- the transition hook --------------------------------------------------------------

    def before_step(self, step: Step) -> None:
        """Mailbox SMs before INIT -> PREOP/BOOT; forget the exchange before INIT."""
        states.setup_mailboxes(self.scheduler, step.target, step.slaves)
        if step.target == AlState.INIT:
            for s in step.slaves:
                box = self._boxes.get(s.position)
                if box is not None:
                    box.reset()

    def after_step(self, step: Step) -> None:
        """Reset at INIT; on reaching PRE-OP from INIT/BOOT drop what SM1 holds from before."""
        for s in step.slaves:
            box = self._boxes.get(s.position)
            if box is None:
                continue
            if step.target == AlState.INIT:
                box.reset()
            elif step.target == AlState.PREOP and step.origin(s) in (AlState.INIT, AlState.BOOT):
                box.drain()  # whatever an earlier session left in SM1
