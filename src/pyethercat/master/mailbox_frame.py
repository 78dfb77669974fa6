"""The prepared mailbox frame: one SM0 write and the speculative SM1 read, encoded once.

Part of :class:`~pyethercat.master.mailbox.Mailbox` (see ``master.mailbox``).
Every step of a transaction (an SDO segment, an FoE packet) sends the
frame ``[FPWR SM0 (whole length), FPRD SM1 (whole length)]``: a slave that
answers at once has the answer ready in the same round trip, and an empty
SM1 refuses the read (working counter 0) without changing anything in the
ESC. The frame is built once per mailbox (the scheduler's prepared frames);
per message only the header and payload are written into it and the frame
index patched, and the reply is read at known offsets.
"""

from __future__ import annotations

import struct
import threading
from typing import Any

from pyethercat.errors import FrameTooLargeError
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.mailbox_inbox import Accept, MailboxInbox, ReceivedMessage, named_error
from pyethercat.master.scheduler import CyclicTemplate, Scheduler
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.mailbox.header import MAILBOX_HEADER_SIZE

__all__ = ["MAILBOX_HEADER", "MailboxFrame"]

#: Mailbox header (ETG.1000.4): length, address, channel/priority, type and counter.
MAILBOX_HEADER = struct.Struct("<HHBB")


class MailboxFrame:
    """The prepared ``[SM0 write, SM1 read]`` frame of one mailbox (see the module text).

    What the read brings goes to ``inbox`` (whose ``label`` names the slave in errors).
    """

    def __init__(self, scheduler: Scheduler, inbox: MailboxInbox[Any], station: int, *,
                 rx_offset: int, rx_size: int, tx_offset: int, tx_size: int) -> None:
        self.scheduler = scheduler
        self.inbox = inbox
        self.rx_offset = rx_offset
        self.rx_size = rx_size
        self.tx_offset = tx_offset
        self.tx_size = tx_size
        #: The address field of the SM0 write (station, offset).
        self.rx_address = (station & 0xFFFF) | ((rx_offset & 0xFFFF) << 16)
        #: The SM1 read: one object for every read (the scheduler copies it into each frame).
        self.read = Datagram.device(Command.FPRD, station, tx_offset, tx_size)
        self._template: CyclicTemplate | None = None
        self._no_template = False
        # The lock of the template's bytes.
        self._tx = threading.Lock()
        # Payload bytes of the message last written into the template (the rest is zero).
        self._tail = 0

    @property
    def template(self) -> CyclicTemplate | None:
        """The encoded frame once built (None before, or when the two do not fit a frame)."""
        return self._template

    def prepared(self) -> CyclicTemplate | None:
        """The frame [FPWR SM0, FPRD SM1], encoded once (None: the two do not fit a frame)."""
        template = self._template
        if template is None and not self._no_template:
            try:
                template = self.scheduler.prepare_cyclic(
                    [Datagram(Command.FPWR, 0, self.rx_address, bytes(self.rx_size)),
                     self.read])
            except FrameTooLargeError:
                self._no_template = True
                return None
            self._template = template
        return template

    def write_and_read(self, template: CyclicTemplate, payload: bytes, kind: int, what: str,
                       take: Accept | None = None) -> tuple[int, ReceivedMessage | None]:
        """Send the SM0 write and the speculative SM1 read as one prepared frame.

        The hot path of every transaction step: header and payload go into
        the template in place (the bytes behind a shorter message than the
        last are zeroed: the whole SM length is written), only the frame index
        is patched, the reply is read at known offsets (no datagram objects,
        no frame decode). ``kind`` is the header's type and counter byte. A
        lost frame is sent again (the repeated write carries the same
        counter, so a slave that got the first one drops it); when an attempt
        may have emptied SM1 on its lost way back, the inbox notes it
        (:attr:`MailboxInbox.lost`: a repeat request follows). Returns the
        write's working counter, and the message read when ``take`` accepts
        it as the answer (only when the write was taken); anything else the
        read brought goes to the inbox.
        """
        sched = self.scheduler
        at = template.data_offsets[0]
        attempts = 0
        n = len(payload)
        body = at + MAILBOX_HEADER_SIZE
        while True:
            attempts += 1
            with self._tx:
                buf = template.frame
                MAILBOX_HEADER.pack_into(buf, at, n, 0, 0, kind)
                buf[body:body + n] = payload
                tail = self._tail
                if tail > n:
                    buf[body + n:body + tail] = bytes(tail - n)
                self._tail = n
                ticket = sched.send_prepared(template)
            raw = ticket.wait_raw()
            if raw is not None:
                break
            if ticket.error is not None:
                raise named_error(ticket.error, f"{self.inbox.label}: sending {what}")
            if attempts > sched.retries:
                self.inbox.lost = True
                raise EcTimeoutError(
                    f"{self.inbox.label}: sending {what}: no reply to the mailbox frame (FPWR "
                    f"0x{self.rx_offset:04X} + FPRD 0x{self.tx_offset:04X}) after {attempts} "
                    f"attempts on {sched.link.name}")
        wkc = template.wkc(raw, 0)
        taken = None
        if template.wkc(raw, 1) == 1:
            inbox = self.inbox
            inbox.stats.early_replies += 1
            start = template.data_offsets[1]
            taken = inbox.deliver(raw[start:start + self.tx_size], take if wkc == 1 else None)
        elif attempts > 1:
            # An earlier attempt may have read (and emptied) SM1; its frame was lost.
            self.inbox.lost = True
        return wkc, taken
