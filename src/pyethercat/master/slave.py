"""``Slave``: one scanned slave and the I/O a user does with it.

A :class:`Slave` is the data the master knows about the slave
(:class:`~pyethercat.master.slave_info.SlaveInfo`: address, identity, SII,
ports, AL state, process-data layout) bound to its master's services
(ethercrab's ``SubDeviceRef``): the protocol clients of its mailbox, its
process-image views, PDO mapping over CoE::

    s = master.slaves[1]
    s.sdo_read(0x1018, 1, "uint32")          # CoE through the slave's CoE client
    s.outputs["Output 1"] = 1                # its view into the group image
    s.client(CoeClient).od[0x1018]           # any registered mailbox protocol client

The handle keeps nothing of the services itself; it asks them by position
(:class:`SlaveServices`), so a new scan or configuration is seen at once and
nobody sets attributes on slaves from outside. A ``Slave`` made without
services (a test, a listing of data read elsewhere) has the data and raises
:class:`~pyethercat.errors.ConfigError` for I/O.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Protocol, TypeVar

from pyethercat.errors import ConfigError
from pyethercat.master.coe import CoeClient, DTypeLike, ObjectDictionary, PdoSpec
from pyethercat.master.config import MappedPdo
from pyethercat.master.image import SlaveIO
from pyethercat.master.mailbox import Mailbox
from pyethercat.master.slave_info import (
    PORT_ORDER,
    EscInfo,
    Identity,
    MailboxInfo,
    Port,
    SlaveInfo,
)

if TYPE_CHECKING:
    from pyethercat.wire.mailbox.datatypes import Value

__all__ = [
    "PORT_ORDER",
    "EscInfo",
    "Identity",
    "MailboxInfo",
    "Port",
    "Slave",
    "SlaveInfo",
    "SlaveServices",
]

C = TypeVar("C")


class SlaveServices(Protocol):
    """What a :class:`Slave` handle asks its master for (the master's services implement it)."""

    def mailbox_of(self, position: int) -> Mailbox | None:
        """The mailbox transport of the slave at ``position`` (None: it has none)."""
        ...

    def client_of(self, position: int, kind: type[C]) -> C | None:
        """The slave's client of protocol class ``kind`` (None: no mailbox)."""
        ...

    def io_of(self, slave: SlaveInfo, outputs: bool) -> SlaveIO:
        """The slave's view of its group image (ConfigError before a configuration)."""
        ...

    def map_pdos(self, slave: SlaveInfo,
                 mapping: Mapping[int, Sequence[PdoSpec]]) -> dict[int, list[MappedPdo]]:
        """Write a PDO assignment over CoE (see :meth:`Slave.set_pdo_mapping`)."""
        ...


class Slave(SlaveInfo):
    """A scanned slave bound to its master (see the module text)."""

    def __init__(self, position: int, station_address: int,
                 services: SlaveServices | None = None) -> None:
        super().__init__(position, station_address)
        self._services = services

    def _need(self, what: str) -> SlaveServices:
        if self._services is None:
            raise ConfigError(f"{self.describe()} was not scanned by a master: no {what}")
        return self._services

    # -- mailbox ----------------------------------------------------------------------

    @property
    def mbx(self) -> Mailbox | None:
        """The mailbox transport (None: no mailbox, or no master)."""
        return None if self._services is None else self._services.mailbox_of(self.position)

    def client(self, kind: type[C]) -> C:
        """The slave's client of mailbox protocol ``kind`` (``slave.client(CoeClient)``).

        Raises :class:`ConfigError` when the slave has no mailbox.
        """
        got = self._need("mailbox").client_of(self.position, kind)
        if got is None:
            raise ConfigError(f"{self.describe()} has no mailbox: no {kind.__name__}")
        return got

    @property
    def coe(self) -> CoeClient | None:
        """The CoE client (None: no mailbox, or no master)."""
        services = self._services
        return None if services is None else services.client_of(self.position, CoeClient)

    def _coe_client(self) -> CoeClient:
        client = self.coe
        if client is None:
            raise ConfigError(f"{self.describe()} has no mailbox (or was not scanned by a "
                              "master): no CoE")
        return client

    def sdo_read(self, index: int, subindex: int = 0, dtype: DTypeLike | None = None, *,
                 complete_access: bool = False, timeout: float | None = None) -> Value:
        """SDO upload: raw bytes, or a value of ``dtype`` ("uint16", ``DataType.REAL32``...)."""
        return self._coe_client().read(index, subindex, dtype, complete_access=complete_access,
                                       timeout=timeout)

    def sdo_write(self, index: int, subindex: int, value: Value,
                  dtype: DTypeLike | None = None, *, complete_access: bool = False,
                  timeout: float | None = None) -> None:
        """SDO download of raw bytes, or of ``value`` encoded as ``dtype``."""
        self._coe_client().write(index, subindex, value, dtype, complete_access=complete_access,
                                 timeout=timeout)

    @property
    def od(self) -> ObjectDictionary:
        """The object dictionary (SDO information service, fetched lazily)."""
        return self._coe_client().od

    def set_pdo_mapping(self, mapping: Mapping[int, Sequence[PdoSpec]]
                        ) -> dict[int, list[MappedPdo]]:
        """Write a new PDO assignment (and mappings) in PRE-OP; the next start uses it.

        ``mapping`` keys are sync managers (2, 3) or assignment objects
        (0x1C12, 0x1C13); values list PDO indices (their mapping kept) or
        ``(pdo_index, [(index, subindex, bits), ...])`` to rewrite a mapping
        object too. The writes are also kept as PS start-up commands, so they
        are done again whenever the slave passes PRE-OP -> SAFE-OP.
        """
        return self._need("CoE").map_pdos(self, mapping)

    # -- process data ------------------------------------------------------------------

    @property
    def inputs(self) -> SlaveIO:
        """The slave's input PDO entries by name (``slave.inputs["Input 1"]``), read-only.

        There after ``master.configure()``; before that :class:`ConfigError`.
        """
        return self._need("process image").io_of(self, False)

    @property
    def outputs(self) -> SlaveIO:
        """The slave's output PDO entries by name (``slave.outputs["Output 1"] = 1``).

        There after ``master.configure()``; before that :class:`ConfigError`.
        """
        return self._need("process image").io_of(self, True)
