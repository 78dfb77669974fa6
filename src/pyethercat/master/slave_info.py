"""What the master knows about one slave: address, identity, SII, ports, state, layout.

:class:`SlaveInfo` is data only (ethercrab's ``SubDevice``): the scan
(:mod:`pyethercat.master.scan`) fills the address, identity, SII and ports,
the state machine the AL state, the configuration the process-data layout
and the PDO mapping. The I/O methods a user calls on a slave (SDO access,
``inputs``/``outputs``) live on the handle :class:`~pyethercat.master.slave.Slave`,
which is a ``SlaveInfo`` bound to its master's services.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from pyethercat.wire.al import AlState, al_status_code_name, state_name
from pyethercat.wire.registers import (
    AL_ERROR_FLAG,
    EscConfig,
    EscFeaturesMixin,
    PortType,
    dl_status_com,
    dl_status_link,
    dl_status_loop,
    port_types,
)
from pyethercat.wire.ring import PORT_CYCLE
from pyethercat.wire.sii.model import GeneralFlags, MailboxProtocol, SiiInfo

if TYPE_CHECKING:
    from pyethercat.esi.eni import EniDc
    from pyethercat.esi.model import EsiDcOpMode
    from pyethercat.master.config import MappedPdo, SlaveConfig

__all__ = ["Identity", "EscInfo", "Port", "MailboxInfo", "SlaveInfo", "PORT_ORDER"]

#: Order in which an ESC passes a frame through its ports (``wire.ring.PORT_CYCLE``).
PORT_ORDER = PORT_CYCLE


@dataclass(frozen=True, slots=True)
class Identity:
    """Vendor ID, product code, revision and serial number (SII words 0x08-0x0F).

    ``serial`` and ``revision`` may be ``None`` in an *expected* identity,
    meaning "any".
    """

    vendor_id: int
    product_code: int
    revision: int | None = None
    serial: int | None = None

    def matches(self, found: Identity) -> bool:
        """Whether ``found`` satisfies this (expected) identity."""
        return (self.vendor_id == found.vendor_id and self.product_code == found.product_code
                and (self.revision is None or self.revision == found.revision)
                and (self.serial is None or self.serial == found.serial))

    def __str__(self) -> str:
        text = f"vendor 0x{self.vendor_id:08X} product 0x{self.product_code:08X}"
        if self.revision is not None:
            text += f" revision 0x{self.revision:08X}"
        if self.serial is not None:
            text += f" serial {self.serial}"
        return text


@dataclass(frozen=True, slots=True)
class EscInfo(EscFeaturesMixin):
    """ESC identification registers 0x0000-0x0009 (``dc_supported`` etc. decode 0x0008)."""

    type: int = 0
    revision: int = 0
    build: int = 0
    fmmu_count: int = 0
    sm_count: int = 0
    ram_kib: int = 0
    port_descriptor: int = 0
    features: int = 0

    @property
    def port_types(self) -> list[PortType]:
        """Types of ports 0-3 from the port descriptor 0x0007."""
        return port_types(self.port_descriptor)


@dataclass(slots=True)
class Port:
    """One ESC port: its type, DL status bits and what hangs on it."""

    number: int
    type: PortType = PortType.NOT_IMPLEMENTED
    link: bool = False
    loop_closed: bool = True
    communication: bool = False
    #: The slave joined to this port (port 0: the parent side; None: the master or nothing).
    peer: SlaveInfo | None = field(default=None, repr=False)

    @property
    def implemented(self) -> bool:
        return self.type.implemented

    @property
    def active(self) -> bool:
        """Open with communication: frames leave and come back through it (SOEM's rule)."""
        return self.communication and not self.loop_closed

    @property
    def status_text(self) -> str:
        """``up``/``down`` plus loop state, for listings."""
        if not self.implemented:
            return "-"
        state = "up" if self.link else "down"
        loop = "closed" if self.loop_closed else "open"
        return f"{state}/{loop}"

    @classmethod
    def from_registers(cls, number: int, descriptor: int, dl_status: int) -> Port:
        return cls(number, port_types(descriptor)[number],
                   bool(dl_status & dl_status_link(number)),
                   bool(dl_status & dl_status_loop(number)),
                   bool(dl_status & dl_status_com(number)))


@dataclass(frozen=True, slots=True)
class MailboxInfo:
    """Standard and bootstrap mailboxes from the SII fixed area (words 0x14-0x1C)."""

    rx_offset: int  # master -> slave (SM0)
    rx_size: int
    tx_offset: int  # slave -> master (SM1)
    tx_size: int
    protocols: int
    boot_rx_offset: int = 0
    boot_rx_size: int = 0
    boot_tx_offset: int = 0
    boot_tx_size: int = 0

    @property
    def protocol_names(self) -> list[str]:
        """Names of the supported mailbox protocols (AoE, EoE, CoE, FoE, SoE, VoE)."""
        names = ["AoE", "EoE", "CoE", "FoE", "SoE", "VoE"]
        return [n for bit, n in enumerate(names) if self.protocols & (1 << bit)]


class SlaveInfo:
    """One slave of the segment as found by the scan (data only, see the module text).

    ``position`` is the ring position (0 = next to the master);
    ``station_address`` the configured address the master gave it;
    ``alias`` the station alias (register 0x0012, loaded from SII word 4).
    ``parent``/``parent_port`` say where it hangs (``None`` for the first
    slave: the master), ``children`` maps port numbers to the slaves on them.
    """

    def __init__(self, position: int, station_address: int) -> None:
        self.position = position
        self.station_address = station_address
        self.alias = 0
        self.identity = Identity(0, 0, 0, 0)
        self.name = ""
        self.sii: SiiInfo | None = None
        #: Raw SII bytes as read (from word 0).
        self.sii_image: bytes = b""
        #: Why the SII could not be read or parsed, if it could not.
        self.sii_error: str | None = None
        #: The SII interface delivers 8 bytes per read (0x0502 bit 6).
        self.sii_read_8 = False
        self.esc = EscInfo()
        #: ESC configuration register 0x0141 as the scan read it (loaded from SII word 0).
        self.esc_config: int | None = None
        self.ports: list[Port] = [Port(n) for n in range(4)]
        self.dl_status = 0
        self.parent: SlaveInfo | None = None
        self.parent_port: int | None = None
        self.children: dict[int, SlaveInfo] = {}
        self.al_state = AlState.NONE
        self.al_error = False
        self.al_status_code = 0
        self.mailbox: MailboxInfo | None = None
        #: PDOs per sync manager read (or written) over CoE or taken from an ESI/ENI;
        #: None: the SII's PDOs apply.
        self.pdo_mapping: dict[int, list[MappedPdo]] | None = None
        #: Process-data configuration of this slave (set by ``master.configure()``).
        self.config: SlaveConfig | None = None
        #: The DC op mode an ESI/ENI chose for the slave (None: take the SII's).
        self.dc_op_mode: EniDc | None = None
        #: The same op mode as the ESI describes it (cycle and shift rules).
        self.dc_op_mode_esi: EsiDcOpMode | None = None

    # -- derived -------------------------------------------------------------------

    @property
    def dc_supported(self) -> bool:
        """The ESC has distributed-clock receive times (0x0008 bit 2)."""
        return self.esc.dc_supported

    @property
    def lrw_supported(self) -> bool:
        """LRW works: the ESC supports it and the SII does not forbid it."""
        if not self.esc.lrw_supported:
            return False
        gen = self.sii.general if self.sii is not None else None
        return not (gen is not None and gen.flags & GeneralFlags.NOT_LRW)

    @property
    def has_mailbox(self) -> bool:
        return self.mailbox is not None and self.mailbox.rx_size > 0 and self.mailbox.tx_size > 0

    @property
    def active_ports(self) -> list[int]:
        """Ports with communication and an open loop, in port-number order."""
        return [p.number for p in self.ports if p.active]

    @property
    def topology_kind(self) -> str:
        """``end``, ``line``, ``fork`` or ``cross`` from the number of active ports."""
        n = len(self.active_ports)
        return {0: "alone", 1: "end", 2: "line", 3: "fork"}.get(n, "cross")

    @property
    def device_emulation(self) -> bool:
        """The ESC runs without firmware (ESC configuration 0x0141 bit 0, SII word 0 bit 8).

        Such a chip (EK1100, simple EL terminals) copies AL control bits 4:0
        into AL status, so an error acknowledge reads back as the error flag
        until the state is written again without it. Taken from the register
        the scan read, else from the SII; ``False`` when neither is known
        (treated as a firmware slave).
        """
        if self.esc_config is not None:
            return bool(self.esc_config & EscConfig.DEVICE_EMULATION)
        if self.sii is None:
            return False
        return bool((self.sii.pdi_control >> 8) & EscConfig.DEVICE_EMULATION)

    @property
    def al_state_name(self) -> str:
        """State as IgH prints it, with ``+ERR`` when the error flag is set."""
        return state_name(int(self.al_state) | (AL_ERROR_FLAG if self.al_error else 0))

    @property
    def al_status_text(self) -> str:
        """``0x001D Invalid output configuration`` (or ``""`` without error)."""
        if not self.al_status_code:
            return ""
        return f"0x{self.al_status_code:04X} {al_status_code_name(self.al_status_code)}"

    @property
    def address_text(self) -> str:
        """``0x1001`` or ``0x1001/alias 7`` for listings."""
        text = f"0x{self.station_address:04X}"
        return f"{text}/alias {self.alias}" if self.alias else text

    @property
    def has_coe(self) -> bool:
        """The SII announces CoE among the mailbox protocols."""
        return self.mailbox is not None and bool(self.mailbox.protocols & MailboxProtocol.COE)

    def describe(self) -> str:
        """``slave 3 (0x1004, EL2004)``: how errors name a slave."""
        name = f", {self.name}" if self.name else ""
        return f"slave {self.position} (0x{self.station_address:04X}{name})"

    def __repr__(self) -> str:
        return (f"<{type(self).__name__} {self.position} 0x{self.station_address:04X} {self.name!r} "
                f"{self.al_state_name}>")
