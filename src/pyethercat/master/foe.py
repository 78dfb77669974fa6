"""FoE client (master side): read and write files of a slave through its mailbox.

:class:`FoeClient` drives the sans-IO state machines of
:mod:`pyethercat.wire.mailbox.foe_transfer` over one slave's
:class:`~pyethercat.master.mailbox.Mailbox`:

- files of any size, packets numbered from 1, each DATA acknowledged, the end
  marked by a short (or 0-byte) packet; numbers beyond 65535 and slaves that
  wrap at 256 are understood;
- BUSY answers make it send the packet again; their progress words reach
  the progress callback;
- every FoE error the slave sends is raised as its own
  :class:`~pyethercat.errors.FoeAbort` subclass with the slave's text; a
  protocol violation by the slave is answered with an FoE ERR and raised the
  same way (``by_master`` set);
- a packet without answer within ``packet_timeout`` raises
  :class:`~pyethercat.errors.FoeTimeoutError` (and the slave gets an ERR so it
  forgets the transfer). A reply frame lost on the wire is recovered by the
  mailbox transport (repeat request), not by the FoE layer;
- the first packet after the master took the mailbox over (a new session
  on a slave an earlier one left in PRE-OP) is sent again with the next
  counter when unanswered, as every mailbox request (``Mailbox.transact``):
  the slave drops a packet whose counter repeats the last one it took.

The client holds ``Mailbox.lock`` for the whole transfer, so nothing else
interleaves within that slave's mailbox.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Self

from pyethercat.errors import EtherCATError, FoeAbort, FoeTimeoutError, MailboxError
from pyethercat.master.mailbox import ClientContext, Mailbox, ReceivedMessage
from pyethercat.master.transfer import answer_by_deadline, request_by_deadline
from pyethercat.wire.mailbox.foe import FoeMessage, decode_foe
from pyethercat.wire.mailbox.foe_transfer import (
    DEFAULT_PACKET_TIMEOUT,
    FoeProgress,
    FoeReadClient,
    FoeWriteClient,
)
from pyethercat.wire.mailbox.header import MailboxType

__all__ = ["DEFAULT_PACKET_TIMEOUT", "FoeClient", "FoeProgress", "FoeStats", "ProgressCallback"]

_log = logging.getLogger("pyethercat.foe")

#: Called after every packet with where the transfer stands.
ProgressCallback = Callable[[FoeProgress], None]


@dataclass
class FoeStats:
    """Figures of the last transfer of a client."""

    name: str = ""
    bytes: int = 0
    packets: int = 0
    busy: int = 0
    seconds: float = 0.0

    @property
    def rate(self) -> float:
        """Bytes per second."""
        return self.bytes / self.seconds if self.seconds > 0 else 0.0


def _is_foe(msg: ReceivedMessage) -> bool:
    return bool(msg.header.type == MailboxType.FOE)


class FoeClient:
    """FoE services of one slave (see the module text).

    ``packet_timeout`` is the time each packet may wait for its answer (IgH
    uses 3 s); methods take their own to override it.
    """

    #: The mailbox type this client speaks (the registry key, see ``master.clients``).
    mailbox_type: ClassVar[MailboxType] = MailboxType.FOE

    @classmethod
    def for_mailbox(cls, mailbox: Mailbox, context: ClientContext) -> Self:
        """The client a master makes for a slave's mailbox (FoE has no unsolicited messages)."""
        return cls(mailbox)

    def __init__(self, mailbox: Mailbox, *,
                 packet_timeout: float = DEFAULT_PACKET_TIMEOUT) -> None:
        self.mailbox = mailbox
        self.label = mailbox.label
        self.packet_timeout = packet_timeout
        #: Figures of the last transfer.
        self.stats = FoeStats()

    def write(self, name: str, data: bytes, *, password: int = 0,
              progress: ProgressCallback | None = None, packet_timeout: float | None = None,
              wrap: int = 1 << 32) -> None:
        """Write ``data`` as file ``name`` (``wrap=256`` for slaves that wrap their numbers)."""
        sm = FoeWriteClient(name, bytes(data), mailbox_size=self.mailbox.rx_size,
                            password=password, wrap=wrap,
                            packet_timeout=packet_timeout or self.packet_timeout)
        self._run(sm, name, progress, f"FoE write of {name!r}")
        self.stats.bytes = len(data)

    def read(self, name: str, *, password: int = 0, max_size: int | None = None,
             progress: ProgressCallback | None = None,
             packet_timeout: float | None = None) -> bytes:
        """Read file ``name``; ``max_size`` refuses a longer one (FoE 0x8003 to the slave)."""
        sm = FoeReadClient(name, mailbox_size=self.mailbox.tx_size, password=password,
                           max_size=max_size,
                           packet_timeout=packet_timeout or self.packet_timeout)
        self._run(sm, name, progress, f"FoE read of {name!r}")
        self.stats.bytes = len(sm.data)
        return sm.data

    # -- the loop ---------------------------------------------------------------------------

    def _run(self, sm: FoeWriteClient | FoeReadClient, name: str,
             progress: ProgressCallback | None, what: str) -> None:
        mbx = self.mailbox
        clock = mbx.clock
        self.stats = FoeStats(name)
        started = clock()
        packets = 0
        with mbx.lock:
            stale = mbx.drop(_is_foe)
            if stale:
                _log.info("%s: %d stale FoE message(s) dropped", self.label, stale)
            msg: FoeMessage | None = sm.start(clock())
            try:
                while True:
                    if msg is None:  # (a BUSY answered the write request: wait on)
                        reply = answer_by_deadline(mbx, _is_foe, what, sm, sm.packet_timeout)
                    elif sm.done:
                        # The ACK of a read's last packet: nothing answers it.
                        mbx.send(MailboxType.FOE, msg.encode(), what=what,
                                 timeout=sm.packet_timeout)
                        packets += 1
                        break
                    else:
                        # (the answer usually comes in the frame that carried the packet)
                        reply = request_by_deadline(mbx, MailboxType.FOE, msg.encode(),
                                                    _is_foe, what, sm, sm.packet_timeout)
                        packets += 1
                    msg = sm.receive(decode_foe(reply.payload), clock())
                    if progress is not None:
                        progress(sm.progress)
                    if sm.done and msg is None:
                        break
            except (FoeAbort, FoeTimeoutError, MailboxError) as exc:
                self._send_abort(sm)
                if isinstance(exc, (FoeAbort, FoeTimeoutError)):
                    exc.args = (f"{self.label}: {what}: {exc}",)
                raise
            finally:
                self.stats.packets = packets
                self.stats.busy = sm.busy_count
                self.stats.seconds = clock() - started

    def _send_abort(self, sm: FoeWriteClient | FoeReadClient) -> None:
        """Tell the slave we gave up (best effort: the link may be what failed)."""
        if sm.abort_request is None:
            return
        try:
            self.mailbox.send(MailboxType.FOE, sm.abort_request.encode(), what="FoE abort",
                              timeout=min(0.5, sm.packet_timeout))
        except EtherCATError as exc:
            _log.info("%s: FoE abort not delivered: %s", self.label, exc)
