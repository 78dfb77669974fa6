"""The control operations every master serves: slaves, states, registers, SII, CoE, process data.

Each request names its reply type (see :mod:`pyethercat.master.control.protocol`).
Positions are ring positions; ``None`` for a list of positions means every
slave. Protocols added later (FoE, SoE, EoE) define their requests in their
own modules the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pyethercat.master.config import ProcessDataConfig
from pyethercat.master.control.protocol import ControlRequest, Reply, request
from pyethercat.master.slave import EscInfo

__all__ = [
    "Done", "Data", "Hello", "HelloReply", "Roster", "RosterReply",
    "SlaveSnapshot", "ListSlaves", "SlaveList", "SlaveState", "StateList", "ReadStates",
    "RequestState", "AckErrors", "Positions", "RegRead", "RegWrite", "SiiRead", "SiiWrite", "SetAlias",
    "SiiWriteResult", "SdoUpload", "SdoDownload", "SdoEntryType", "EntryType", "SdoList",
    "SdoObjectInfo", "SdoEntryInfo", "SdoObjects", "ErrorCounters", "CounterItem",
    "EoeHandler", "EoeHandlers", "EoeList", "EoeIp", "EoeGetIp", "EoeSetIp",
    "CounterList", "MasterInfoRequest", "RateSet", "MasterInfo", "Domains", "DomainFmmu",
    "DomainInfo", "DomainList", "GetConfig", "StartupSdo", "ConfigReply", "Rescan",
    "RescanReply", "FoeRead", "FoeWrite", "SoeRead", "SoeWrite",
]


@dataclass(frozen=True)
class Done(Reply):
    """The request was carried out (nothing to return)."""


@dataclass(frozen=True)
class Data(Reply):
    """Bytes read (registers, SII, an SDO, process data)."""

    data: bytes = b""


# --- who is there ----------------------------------------------------------------------


@dataclass(frozen=True)
class HelloReply(Reply):
    """The running master: package version, process, link and what it does."""

    version: str
    protocol: int
    pid: int
    link: str
    slaves: int
    cycling: bool
    started: float


@request("hello", HelloReply)
@dataclass(frozen=True)
class Hello(ControlRequest):
    """First request of a client: is this the master it wants, and can we talk."""


@dataclass(frozen=True)
class RosterReply(Reply):
    """The alias of every slave by ring position (what slave selection needs)."""

    aliases: list[int]


@request("roster", RosterReply)
@dataclass(frozen=True)
class Roster(ControlRequest):
    """Count the slaves and read their aliases (no SII read, no scan)."""


@dataclass(frozen=True)
class SlaveSnapshot:
    """What a scan found about one slave, in the registers' and the SII's own terms.

    The client rebuilds :class:`~pyethercat.master.slave.Slave` objects from
    it with the scan's own code (:func:`pyethercat.master.control.snapshot.rebuild`).
    """

    position: int
    station_address: int
    alias: int
    esc: EscInfo
    esc_config: int | None
    dl_status: int
    al_state: int
    al_error: bool
    al_status_code: int
    sii_read_8: bool
    sii_image: bytes
    sii_error: str | None


@dataclass(frozen=True)
class SlaveList(Reply):
    """Every scanned slave; ``consistent``: the ports explained the ring."""

    slaves: list[SlaveSnapshot]
    consistent: bool = True


@request("slaves", SlaveList)
@dataclass(frozen=True)
class ListSlaves(ControlRequest):
    """The scanned slaves with their current AL state."""


@dataclass(frozen=True)
class SlaveState:
    """AL status of one slave (``answered`` False: no reply)."""

    position: int
    station_address: int
    state: int
    error: bool
    code: int
    answered: bool = True


@dataclass(frozen=True)
class StateList(Reply):
    items: list[SlaveState]


@request("states", StateList)
@dataclass(frozen=True)
class ReadStates(ControlRequest):
    positions: list[int] | None = None


@request("request_state", StateList)
@dataclass(frozen=True)
class RequestState(ControlRequest):
    """Take the slaves to ``state`` (the master's path, mailbox and process-data set-up).

    With ``wait`` the reply comes when every slave is there (or the
    transition failed); without, once the last step was requested.
    """

    state: int
    positions: list[int] | None = None
    wait: bool = False
    timeout: float = 5.0


@dataclass(frozen=True)
class Positions(Reply):
    positions: list[int]


@request("ack_errors", Positions)
@dataclass(frozen=True)
class AckErrors(ControlRequest):
    """Acknowledge AL error flags; the reply lists the slaves that had one."""

    positions: list[int] | None = None


# --- registers and SII -------------------------------------------------------------------


@request("reg_read", Data)
@dataclass(frozen=True)
class RegRead(ControlRequest):
    position: int
    address: int
    size: int


@request("reg_write", Done)
@dataclass(frozen=True)
class RegWrite(ControlRequest):
    position: int
    address: int
    data: bytes


@request("sii_read", Data)
@dataclass(frozen=True)
class SiiRead(ControlRequest):
    position: int


@dataclass(frozen=True)
class SiiWriteResult(Reply):
    """What an SII write did (see :class:`pyethercat.master.sii_write.SiiWriteReport`)."""

    words: int
    written: list[int]
    checksum: int
    checksum_fixed: bool
    backup: str | None
    identity_changes: list[str]
    retries: int
    #: The station alias register after the reload.
    alias: int


@request("sii_write", SiiWriteResult)
@dataclass(frozen=True)
class SiiWrite(ControlRequest):
    """Write an SII image (``backup``: file for the old content, written by the master)."""

    position: int
    image: bytes
    force: bool = False
    only_changed: bool = True
    backup: str | None = None


@request("alias", SiiWriteResult)
@dataclass(frozen=True)
class SetAlias(ControlRequest):
    position: int
    alias: int
    force: bool = False
    backup: str | None = None


# --- CoE ------------------------------------------------------------------------------------


@request("sdo_upload", Data)
@dataclass(frozen=True)
class SdoUpload(ControlRequest):
    position: int
    index: int
    subindex: int
    complete_access: bool = False


@request("sdo_download", Done)
@dataclass(frozen=True)
class SdoDownload(ControlRequest):
    position: int
    index: int
    subindex: int
    data: bytes
    complete_access: bool = False


@dataclass(frozen=True)
class EntryType(Reply):
    """The CANopen data type the slave describes an entry with (None: not described)."""

    data_type: int | None


@request("sdo_type", EntryType)
@dataclass(frozen=True)
class SdoEntryType(ControlRequest):
    position: int
    index: int
    subindex: int


@dataclass(frozen=True)
class SdoEntryInfo:
    subindex: int
    access_text: str
    data_type: int
    bit_length: int
    name: str


@dataclass(frozen=True)
class SdoObjectInfo:
    index: int
    name: str
    entries: list[SdoEntryInfo] = field(default_factory=list)
    #: Why the object could not be described (its name and entries are then empty),
    #: or, with a name, which of its entries could not be (the others are listed).
    error: str | None = None


@dataclass(frozen=True)
class SdoObjects(Reply):
    objects: list[SdoObjectInfo]


@request("sdo_list", SdoObjects)
@dataclass(frozen=True)
class SdoList(ControlRequest):
    """The object dictionary of one slave (SDO information service)."""

    position: int
    entries: bool = True


# --- diagnostics ----------------------------------------------------------------------------


@dataclass(frozen=True)
class CounterItem:
    """Error counters 0x0300-0x0313 of one slave as read (``ok`` False: no answer)."""

    position: int
    station_address: int
    ok: bool
    data: bytes


@dataclass(frozen=True)
class CounterList(Reply):
    items: list[CounterItem]


@request("error_counters", CounterList)
@dataclass(frozen=True)
class ErrorCounters(ControlRequest):
    """Read (and with ``clear`` then clear) every slave's error counters."""

    clear: bool = False


@dataclass(frozen=True)
class RateSet:
    """Frames per second over the last 10 s, 1 min and 5 min (or since the start)."""

    tx: list[float]
    rx: list[float]
    lost: list[float]


@dataclass(frozen=True)
class MasterInfo(Reply):
    """The master as IgH's ``ethercat master`` shows it, plus the cyclic loop."""

    link: str
    mac: str
    pid: int
    running: bool
    slaves: int
    frames_sent: int
    frames_received: int
    frames_lost: int
    timeouts: int
    retries: int
    stale: int
    rates: RateSet
    uptime: float
    cycling: bool = False
    cycle_us: float = 0.0
    cycles: int = 0
    wkc_errors: int = 0
    cycle_lost_frames: int = 0
    late_cycles: int = 0


@request("master", MasterInfo)
@dataclass(frozen=True)
class MasterInfoRequest(ControlRequest):
    pass


@dataclass(frozen=True)
class DomainFmmu:
    """One slave's block in a domain (IgH: a slave configuration's FMMU)."""

    position: int
    alias: int
    relative_position: int
    sync_manager: int
    output: bool
    logical_address: int
    size: int


@dataclass(frozen=True)
class DomainInfo:
    """A process-data group, IgH's domain."""

    index: int
    name: str
    logical_base: int
    size: int
    wkc: int
    expected_wkc: int
    exchanges: int
    fmmus: list[DomainFmmu]
    data: bytes | None = None


@dataclass(frozen=True)
class DomainList(Reply):
    domains: list[DomainInfo]
    #: False: no process data exchanged (no running cyclic loop).
    cycling: bool = False


@request("domains", DomainList)
@dataclass(frozen=True)
class Domains(ControlRequest):
    """The groups being exchanged; ``data`` includes each group's process image."""

    data: bool = False


@dataclass(frozen=True)
class StartupSdo:
    """A CoE start-up command (IgH: an SDO configuration entry)."""

    position: int
    transition: str
    index: int
    subindex: int
    data: bytes
    complete_access: bool


@dataclass(frozen=True)
class ConfigReply(Reply):
    """The process-data configuration (None: the master has not configured one)."""

    config: ProcessDataConfig | None
    startup: list[StartupSdo]
    states: list[SlaveState]


@request("config", ConfigReply)
@dataclass(frozen=True)
class GetConfig(ControlRequest):
    """The configuration in use; ``compute``: configure from SII/CoE if there is none."""

    compute: bool = False


@dataclass(frozen=True)
class RescanReply(Reply):
    slaves: int


@request("rescan", RescanReply)
@dataclass(frozen=True)
class Rescan(ControlRequest):
    """Scan the segment again (refused while process data are exchanged)."""


# --- EoE ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EoeHandler:
    """One EoE handler as ``ethercat eoe`` lists it (rates in byte/s)."""

    interface: str
    slave: int
    state: str
    rx_bytes: int
    rx_rate: int
    tx_bytes: int
    tx_rate: int
    tx_queue: str
    rx_frames: int
    tx_frames: int
    dropped: int


@dataclass(frozen=True)
class EoeHandlers(Reply):
    handlers: list[EoeHandler]


@request("eoe_list", EoeHandlers)
@dataclass(frozen=True)
class EoeList(ControlRequest):
    pass


@dataclass(frozen=True)
class EoeIp(Reply):
    """IP parameters of an EoE slave (None: not set / not included)."""

    mac: bytes | None = None
    ip: str | None = None
    subnet: str | None = None
    gateway: str | None = None
    dns_server: str | None = None
    dns_name: str | None = None


@request("eoe_get_ip", EoeIp)
@dataclass(frozen=True)
class EoeGetIp(ControlRequest):
    position: int


@request("eoe_set_ip", Done)
@dataclass(frozen=True)
class EoeSetIp(ControlRequest):
    position: int
    params: EoeIp


# --- FoE and SoE ---------------------------------------------------------------------------


@request("foe_read", Data)
@dataclass(frozen=True)
class FoeRead(ControlRequest):
    """Read file ``name`` over FoE (through the bootstrap mailbox when the slave is in BOOT)."""

    position: int
    name: str
    password: int = 0
    max_size: int | None = None


@request("foe_write", Done)
@dataclass(frozen=True)
class FoeWrite(ControlRequest):
    """Write ``data`` as file ``name`` over FoE; ``boot``: firmware update through BOOT."""

    position: int
    name: str
    data: bytes
    password: int = 0
    boot: bool = False


@request("soe_read", Data)
@dataclass(frozen=True)
class SoeRead(ControlRequest):
    """Read elements ``elements`` (SoE element flags) of IDN ``idn`` of drive ``drive``."""

    position: int
    idn: int
    elements: int = 0x40
    drive: int = 0


@request("soe_write", Done)
@dataclass(frozen=True)
class SoeWrite(ControlRequest):
    """Write raw ``data`` to elements ``elements`` of IDN ``idn`` of drive ``drive``."""

    position: int
    idn: int
    data: bytes
    elements: int = 0x40
    drive: int = 0
