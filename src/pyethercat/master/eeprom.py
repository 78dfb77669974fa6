"""The SII EEPROM of a master's slaves: read it again, write an image, set the alias.

:class:`SiiService` (``master.sii``) reaches a scanned slave by its station
address and an unscanned one by its ring position (the tools that repair a
segment whose scan fails). The write itself, with checksum, backup, identity
check and read-back, is :func:`~pyethercat.master.sii_write.write_sii_image`.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from pathlib import Path

from pyethercat.errors import WorkingCounterError
from pyethercat.master import scan as scanning
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.sii_write import SiiWriteReport, WriteTiming, with_alias, write_sii_image
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.registers import SII_CONTROL, STATION_ALIAS, SiiControl
from pyethercat.wire.sii import SII_DEFAULT_MAX_BYTES

__all__ = ["SiiService", "SiiTarget"]

#: A scanned slave, or the ring position of a slave no scan has addressed.
SiiTarget = SlaveInfo | int
#: Where the old content is saved before a write (a file, or a function choosing one).
Backup = Path | Callable[[bytes], Path]


class SiiService:
    """SII access of one master (see the module text); ``lock`` serialises the sequences."""

    def __init__(self, scheduler: Scheduler, lock: threading.RLock) -> None:
        self.scheduler = scheduler
        self._lock = lock

    def _access(self, target: SiiTarget) -> scanning.SiiAccess:
        if isinstance(target, SlaveInfo):
            return scanning.SiiAccess.of(target)
        access = scanning.SiiAccess.at_position(target)
        reply = self.scheduler.transact_one(
            Datagram.positional(Command.APRD, target, SII_CONTROL, 2))
        if reply.wkc != 1:
            raise WorkingCounterError(f"slave {target}: reading the SII interface at "
                                      f"0x{SII_CONTROL:04X}", 1, reply.wkc)
        access.read_8 = bool(struct.unpack("<H", reply.data)[0] & SiiControl.READ_8_BYTES)
        return access

    def _timing(self) -> WriteTiming:
        # In virtual time the simulated EEPROM's clock moves with the frames only.
        return WriteTiming.for_virtual_time() if self.scheduler.virtual else WriteTiming()

    def _refresh_alias(self, target: SiiTarget) -> None:
        if isinstance(target, SlaveInfo):
            reply = self.scheduler.transact_one(
                Datagram.device(Command.FPRD, target.station_address, STATION_ALIAS, 2))
            if reply.wkc == 1:
                target.alias = struct.unpack("<H", reply.data)[0]

    def read(self, target: SiiTarget, *, max_bytes: int = SII_DEFAULT_MAX_BYTES) -> bytes:
        """The slave's SII again, from word 0 to the category end marker."""
        with self._lock:
            result = scanning.read_sii_batch(self.scheduler, [self._access(target)],
                                             max_bytes=max_bytes)[0]
            if isinstance(result, Exception):
                raise result
            return result

    def write(self, target: SiiTarget, image: bytes, *, reload: bool = True,
              only_changed: bool = True, force: bool = False, backup: Backup | None = None,
              progress: scanning.Progress | None = None) -> SiiWriteReport:
        """Write an SII image into the slave's EEPROM, safely (see ``Master.sii_write``)."""
        with self._lock:
            access = self._access(target)
            report = write_sii_image(self.scheduler, access, image, force=force,
                                     only_changed=only_changed, reload=reload, backup=backup,
                                     timing=self._timing(), sleep=self.scheduler.sleep,
                                     now=self.scheduler.now, progress=progress)
            if reload:
                self._refresh_alias(target)
            return report

    def set_alias(self, target: SiiTarget, alias: int, *, backup: Backup | None = None,
                  force: bool = False) -> SiiWriteReport:
        """Write the station alias (SII word 4, with a new checksum) and reload it."""
        with self._lock:
            access = self._access(target)
            current = scanning.read_sii_batch(self.scheduler, [access])[0]
            if isinstance(current, Exception) or len(current) < 16:
                current = scanning.read_sii_batch(self.scheduler, [access], length=16)[0]
                if isinstance(current, Exception):
                    raise current
            report = write_sii_image(self.scheduler, access, with_alias(current, alias),
                                     force=force, backup=backup, timing=self._timing(),
                                     sleep=self.scheduler.sleep, now=self.scheduler.now)
            self._refresh_alias(target)
            return report
