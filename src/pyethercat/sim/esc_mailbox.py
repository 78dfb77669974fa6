"""The mailbox sync managers of a simulated ESC and the firmware's side of them.

SM0 (master -> slave) and SM1 (slave -> master) in mailbox (one-buffer) mode
(ESC datasheet section I, "SyncManager", mailbox mode; SOES ``soes/esc.c``
``ESC_readmbx``/``ESC_writembx``): a write of the last byte by the writing side makes the
mailbox full, a read of the last byte by the reading side empties it.

The firmware side follows SOES (``soes/esc.c``): what the master wrote is
handed to the device application (``DeviceApp.on_mailbox``) and then read
out of SM0 unless the application declares ``mailbox_auto_read = False``;
replies are posted into SM1. The repeat request (SM1 activate bit 1 toggled; SOEM
``src/ec_main.c`` ``ecx_mbxreceive``) posts the mailbox the master read last once more;
a newer mailbox already posted but not yet read is taken back and posted
again right after the repeated one was read (SOES ``ESC_sm_act_event``).
Entering INIT stops the mailbox: SOES deactivates SM0/SM1 through PDI control
there, which drops their buffer state.
"""

from __future__ import annotations

import numpy as np

from pyethercat.sim.access import EscRegisters, SmView
from pyethercat.sim.device import DeviceApp
from pyethercat.wire import registers as R

__all__ = ["MailboxSms"]

_SM_MODE_MAILBOX = int(R.SmMode.MAILBOX)


class MailboxSms:
    """State of the mailbox SMs of one ESC (see the module docstring)."""

    def __init__(self, regs: EscRegisters, app: DeviceApp | None) -> None:
        self.regs = regs
        self.app = app
        #: The last mailbox the firmware posted into SM1.
        self.last_in = b""
        #: The mailbox the master read last (what a repeat request brings back).
        self.backup = b""
        #: A newer mailbox a repeat request took back out of SM1 (posted again
        #: once the repeated one is read).
        self.again = b""
        #: SM1 holds the repeated mailbox right now.
        self._repeat_posted = False

    def power_on(self) -> None:
        self.backup = self.again = b""  # the firmware restarts too
        self._repeat_posted = False

    # --- EtherCAT side --------------------------------------------------------

    def read_complete(self, s: SmView) -> int:
        """The master read the last byte of mailbox SM ``s``; the new status byte."""
        status = int(s.status)
        if not s.ecat_writes:
            # What the master has read is what a repeat request brings back.
            self.backup = self.regs.row[s.start: s.end].tobytes()
            self._repeat_posted = False
            status &= ~(R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
        return status | R.SM_STATUS_READ_EVENT

    def after_read(self, s: SmView) -> None:
        """After the read event: a withdrawn mailbox goes out, the application hears of it."""
        if self.again:
            # The mailbox a repeat request withdrew goes out before anything newer.
            again, self.again = self.again, b""
            self.post_again(s.n, again)
        if self.app is not None:
            # (the firmware hears of it through the PDI, after the frame)
            self.regs.host.after_frame(self.app.on_mailbox_read)

    def write_complete(self, s: SmView) -> None:
        """The master wrote the last byte of SM0: full, handed to the firmware."""
        regs = self.regs
        row = regs.row
        row[R.sm_address(s.n) + R.SM_STATUS] = (
            (s.status | R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
            & ~R.SM_STATUS_READ_EVENT & 0xFF)
        if s.control & R.SM_CONTROL_AL_EVENT:
            regs.set_al_event(R.al_event_sm(s.n))
        data = row[s.start: s.end].tobytes()
        app = self.app
        if app is None:
            self.pdi_consumed(s.n)
            return
        n = s.n

        def firmware() -> None:
            # The firmware reads the request through the PDI once the frame has passed.
            app.on_mailbox(data)
            if app.mailbox_auto_read:
                self.pdi_consumed(n)

        self.regs.host.after_frame(firmware)

    def repeat(self, n: int) -> None:
        """Repeat request toggled on SM ``n``: post the mailbox the master read last once more."""
        regs = self.regs
        s = regs.sm(n)
        if self.backup:
            if s.status & R.SM_STATUS_MAILBOX_FULL and not self._repeat_posted:
                self.again = regs.row[s.start: s.end].tobytes()
            self.post_again(n, self.backup)
            self._repeat_posted = True
        repeat = s.activate & R.SM_ACTIVATE_REPEAT
        pdi = int(regs.row[R.sm_address(n) + R.SM_PDI_CONTROL])
        regs.row[R.sm_address(n) + R.SM_PDI_CONTROL] = (pdi & ~R.SM_PDI_REPEAT_ACK) | (
            R.SM_PDI_REPEAT_ACK if repeat else 0)

    def stop(self) -> None:
        """The firmware stops the mailbox on entering INIT (see the module docstring).

        Modelled as the deactivation's effect: a request or reply left unread
        does not survive into the next session, even when the master then
        writes the same SM configuration again. The SMs stay enabled to the
        master (the firmware re-enables them when the mailbox starts, before
        the INIT -> PREOP checks).
        """
        regs = self.regs
        for n in range(min(2, regs.profile.sm_count)):
            if regs.sm(n).mode == _SM_MODE_MAILBOX:
                regs.set_sm_status(n, 0)
        self.backup = self.again = b""
        self._repeat_posted = False

    # --- PDI side -------------------------------------------------------------

    def pdi_consumed(self, n: int) -> None:
        """The firmware read the master's mailbox: SM ``n`` is empty again."""
        regs = self.regs
        row = regs.row
        base = R.sm_address(n)
        # (status and control straight from the registers: no SmView decode per message)
        status = int(row[base + R.SM_STATUS])
        row[base + R.SM_STATUS] = ((status & ~(R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT))
                                   | R.SM_STATUS_READ_EVENT) & 0xFF
        if row[base + R.SM_CONTROL] & R.SM_CONTROL_ECAT_EVENT:
            regs.set_ecat_event(R.ecat_event_sm(n))

    def posted(self, s: SmView, data: bytes | None = None) -> None:
        """The firmware wrote the last byte of SM1: the mailbox is full for the master.

        ``data``: the bytes just written there, when the caller has them.
        """
        self._repeat_posted = False
        regs = self.regs
        row = regs.row
        self.last_in = row[s.start: s.end].tobytes() if data is None else data
        row[R.sm_address(s.n) + R.SM_STATUS] = (
            (s.status | R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
            & ~R.SM_STATUS_READ_EVENT & 0xFF)
        if s.control & R.SM_CONTROL_ECAT_EVENT:
            regs.set_ecat_event(R.ecat_event_sm(s.n))

    def post_again(self, n: int, data: bytes) -> None:
        """Write a repeated or withdrawn mailbox into SM ``n`` and mark it full."""
        regs = self.regs
        s = regs.sm(n)
        payload = data[: s.length].ljust(s.length, b"\x00")
        regs.row[s.start: s.end] = np.frombuffer(payload, np.uint8)
        self.posted(s, payload)

    def post(self, data: bytes) -> bool:
        """Put a reply into SM1; False when SM1 is not a running send mailbox or still full."""
        regs = self.regs
        s = regs.sm(1) if regs.profile.sm_count > 1 else None
        if s is None or not s.enabled or s.mode != _SM_MODE_MAILBOX or s.ecat_writes:
            return False
        if s.status & R.SM_STATUS_MAILBOX_FULL:
            return False
        payload = bytes(data[: s.length]).ljust(s.length, b"\x00")
        regs.row[s.start: s.end] = np.frombuffer(payload, np.uint8)
        self.posted(s, payload)
        return True
