"""Firmware update through the bootstrap mailbox: INIT -> BOOT, FoE write, BOOT -> INIT.

The sequence SOEM's ``firm_update`` sample and IgH's ``foe_write --boot``-less
flow (state BOOT first, then ``foe_write``) run, in one call:

1. the slave goes to INIT, then to BOOT; before the BOOT request SM0/SM1 are
   programmed with the bootstrap mailbox of the SII (words 0x0014/0x0015
   receive, 0x0016/0x0017 send). A slave whose SII has no bootstrap mailbox is
   refused before anything is written (:class:`~pyethercat.errors.ConfigError`);
   a slave that refuses BOOT raises
   :class:`~pyethercat.errors.BootstrapNotSupportedError` (AL status 0x0013) or
   :class:`~pyethercat.errors.BootMailboxConfigError` (0x0015);
2. the firmware file goes over FoE through that mailbox;
3. the slave goes back to INIT, where it starts the new firmware (many
   devices flash it then: SOEM issue 76).

The master's view of the slave (its SII and identity) is the old one until the
next scan reads the EEPROM again.
"""

from __future__ import annotations

import logging
from typing import Protocol

from pyethercat.errors import ConfigError
from pyethercat.master import states
from pyethercat.master.foe import FoeClient, ProgressCallback
from pyethercat.master.mailbox import DEFAULT_MAILBOX_TIMEOUT, Mailbox
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState

__all__ = ["BootMaster", "boot_mailbox", "bootstrap_update", "foe_client"]

_log = logging.getLogger("pyethercat.foe")


class BootMaster(Protocol):
    """What the update needs of a master."""

    scheduler: Scheduler

    def slave(self, ref: Slave | int) -> Slave: ...
    def set_state(self, state: AlState | int | str, slaves: list[Slave] | None = None,
                  timeout: float = ...) -> None: ...


def boot_mailbox(slave: Slave) -> tuple[int, int, int, int]:
    """(receive offset, size, send offset, size) of the slave's bootstrap mailbox.

    :class:`ConfigError` when its SII has none (BOOT is then refused up front).
    """
    sii = slave.sii
    if sii is None:
        raise ConfigError(f"{slave.describe()}: SII not read, its bootstrap mailbox is unknown")
    (rx_off, rx_size), (tx_off, tx_size) = sii.mailbox_layout(boot=True)
    if not rx_size or not tx_size:
        raise ConfigError(f"{slave.describe()}: no bootstrap mailbox in the SII (words "
                          "0x0014-0x0017 are zero): BOOT refused")
    return rx_off, rx_size, tx_off, tx_size


def bootstrap_update(master: BootMaster, slave: Slave | int, firmware: bytes, *,
                     name: str = "firmware", password: int = 0,
                     progress: ProgressCallback | None = None,
                     packet_timeout: float | None = None,
                     state_timeout: float = states.DEFAULT_STATE_TIMEOUT,
                     back_to_init: bool = True) -> None:
    """Write ``firmware`` to ``slave`` in BOOT and bring it back to INIT (see the module text)."""
    s = master.slave(slave)
    rx_off, rx_size, tx_off, tx_size = boot_mailbox(s)
    master.set_state(AlState.INIT, [s], timeout=state_timeout)
    master.set_state(AlState.BOOT, [s], timeout=state_timeout)
    _log.info("%s: in BOOT, writing %d bytes of firmware as %r", s.describe(), len(firmware),
              name)
    box = Mailbox(master.scheduler, s.station_address, s.describe(), rx_offset=rx_off,
                  rx_size=rx_size, tx_offset=tx_off, tx_size=tx_size,
                  timeout=DEFAULT_MAILBOX_TIMEOUT)
    client = FoeClient(box)
    if packet_timeout is not None:
        client.packet_timeout = packet_timeout
    client.write(name, firmware, password=password, progress=progress)
    if back_to_init:
        master.set_state(AlState.INIT, [s], timeout=state_timeout)


def foe_client(scheduler: Scheduler, slave: Slave) -> FoeClient:
    """The FoE client of ``slave`` as its state allows: the bootstrap mailbox in BOOT.

    Outside BOOT the slave's standard mailbox (it must be in PRE-OP or above).
    """
    if slave.al_state == AlState.BOOT:
        rx_off, rx_size, tx_off, tx_size = boot_mailbox(slave)
        return FoeClient(Mailbox(scheduler, slave.station_address, slave.describe(),
                                 rx_offset=rx_off, rx_size=rx_size, tx_offset=tx_off,
                                 tx_size=tx_size))
    return slave.client(FoeClient)
