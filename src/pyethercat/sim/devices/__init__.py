"""Device applications of simulated slaves, and the built-in device catalogue.

:func:`make_app` picks the application for a slave from what it is: a
built-in device or an SII image. Plain IO terminals need no Python on the
cyclic path (their inputs come from wiring or from the PDI); devices with a
mailbox but no protocol engine get :class:`MailboxErrorApp`, which answers
every mailbox request with "mailbox protocol not supported", as a real slave
without that protocol would.
"""

from __future__ import annotations

from pyethercat.errors import MailboxError
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.devices.builtin import BUILTINS, VENDOR_ID, BuiltinDevice, get_builtin
from pyethercat.sim.devices.coe_io import coe_builtins
from pyethercat.wire.mailbox.header import (
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
    encode_mailbox_error,
)
from pyethercat.wire.sii import SiiInfo

__all__ = [
    "BUILTINS",
    "VENDOR_ID",
    "BuiltinDevice",
    "IoTerminal",
    "MailboxErrorApp",
    "get_builtin",
    "make_app",
]


class IoTerminal(DeviceApp):
    """A plain IO terminal: no per-frame work; inputs come from wiring or the PDI."""


class MailboxErrorApp(IoTerminal):
    """An IO device with a mailbox but no mailbox protocol.

    Every request the master writes into SM0 is answered in SM1 with a mailbox
    error reply (type 0): code 0x0002 "protocol not supported" for a well-formed
    header, 0x0001 "syntax" when even the header is unreadable.
    """

    def on_mailbox(self, data: bytes) -> None:
        if self.pdi is None:
            return
        try:
            header = MailboxHeader.decode(data)
        except MailboxError:
            code, counter, address = MailboxErrorCode.SYNTAX, 0, 0
        else:
            code, counter, address = (
                MailboxErrorCode.UNSUPPORTED_PROTOCOL,
                header.counter,
                header.address,
            )
        reply = encode_mailbox(
            MailboxType.ERR, encode_mailbox_error(code), counter=counter, address=address
        )
        # If SM1 is still full the master has not fetched the last reply; a
        # real slave would drop the new one too.
        self.pdi.post_mailbox(reply)


# CoE built-ins (coe-io, seed002-drive) join the catalogue.
BUILTINS.update(coe_builtins())


def make_app(builtin: BuiltinDevice | None, info: SiiInfo) -> DeviceApp:
    """The device application for a slave (built-in device or SII image)."""
    if builtin is not None and builtin.app_factory is not None:
        return builtin.app_factory(info)
    if builtin is not None:
        return MailboxErrorApp() if builtin.mailbox is not None else IoTerminal()
    if info.rx_mailbox_size and info.tx_mailbox_size:
        return MailboxErrorApp()
    return IoTerminal()
