"""Process-data configuration computed from each slave's SII (no I/O here).

Input: what the master learned about each slave during the scan (``SlaveDescription``:
position, station address, parsed SII, ESC features). Output
(``ProcessDataConfig``): for every slave the sync manager and FMMU register
values to write, and for every process-data group its logical base address,
its image layout (every PDO entry at a bit offset) and the cyclic datagrams
(LRW, or LWR + LRD) with the working counter each one must come back with.

Layout decisions (documented in docs/master.md):

- A group's image is ``[outputs][inputs]``: all outputs first, then all
  inputs from the next byte on. One LRW covers both (SOEM does the same); the
  write FMMUs take the output part, the read FMMUs fill the input part.
- ``layout="packed"`` (the default, as TwinCAT and SOEM do): a sync manager
  block of fewer than 8 bits (a 2-bit or 4-bit terminal) is mapped bitwise
  into the next free bits of the current byte, so four 2-bit terminals share
  one byte (an FMMU maps bit by bit: ET1100 datasheet section II, "FMMU"). A block that does not fit
  the rest of the current byte starts a new byte: a block never straddles a
  byte boundary. Blocks of 8 bits or more always start on a byte. Slaves whose
  ESC maps only bytewise (feature bit 0) are never packed.
  ``layout="byte"``: every block starts on a byte.
- Adjacent sync managers of one direction whose RAM is contiguous share one
  FMMU (EL2889: SM0 0x0F00 and SM1 0x0F01).
- A group whose data exceeds one datagram (1486 bytes) is split into several
  datagrams, at slave block boundaries where possible.
- A group that holds a slave without LRW support (ESC feature bit 9, or SII
  General flag "not LRW") is exchanged with LWR (outputs) + LRD (inputs).
- Expected working counter per datagram: +2 per slave with a write FMMU in
  range plus +1 per slave with a read FMMU in range for LRW; +1 per slave for
  LWR and LRD (ETG.1000.4 command table; SOEM ``ecx_config_map_group`` counts
  the expected working counter the same way).

- Mailbox status (``mailbox_status=True``, the default, as SOEM does): every
  slave of a group with a send mailbox (SM1) gets one byte after the group's
  inputs, filled by a read FMMU on its SM1 status register (0x080D; bit 3 =
  mailbox full), so the cyclic frame tells the master when a mailbox reply
  is waiting and no poll frames are needed while cyclic exchange runs. The
  FMMU the SII reserves for "SyncM status" is used when it declares one,
  else a free one; a slave with no FMMU left is polled with frames (warning).
  The image is then ``[outputs][inputs][mailbox status]``; the read FMMUs
  count in the expected working counter like any other.
- CoE PDO mapping: set ``SlaveDescription.pdo_mapping`` (sync manager index ->
  PDOs), e.g. read from 0x1C12/0x1C13; it replaces the SII PDOs.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from pyethercat.errors import ConfigError
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import MAX_DATA, Command
from pyethercat.wire.sii.model import (
    SM_NOT_ASSIGNED,
    FmmuUsage,
    GeneralFlags,
    SiiInfo,
    SiiPdo,
    SyncManagerEnable,
    SyncManagerType,
)

__all__ = [
    "DEFAULT_LOGICAL_BASE",
    "GROUP_ALIGNMENT",
    "CrossLink",
    "CyclicDatagram",
    "PdoDirection",
    "FmmuRegisters",
    "GroupConfig",
    "GroupSpec",
    "Layout",
    "MappedPdo",
    "MappedPdoEntry",
    "PdoVariable",
    "ProcessDataConfig",
    "SlaveConfig",
    "SlaveDescription",
    "SyncManagerConfig",
    "configure",
    "expected_wkc",
    "wkc_share",
    "pdos_from_sii",
]

#: Logical address of the first group (SOEM and IgH start at 0x00010000 too).
DEFAULT_LOGICAL_BASE = 0x0001_0000
#: Each further group starts at the next multiple of this after the previous one.
GROUP_ALIGNMENT = 0x0001_0000



class PdoDirection(enum.Enum):
    """Process-data direction as seen from the master."""

    OUTPUTS = "outputs"  # master -> slave, RxPDOs, write FMMUs
    INPUTS = "inputs"  # slave -> master, TxPDOs, read FMMUs


class Layout(enum.Enum):
    """How sub-byte blocks are placed in a group image."""

    PACKED = "packed"
    BYTE = "byte"


# --- PDO description (SII or, later, CoE) -------------------------------------


@dataclass(frozen=True, slots=True)
class MappedPdoEntry:
    """One entry of a PDO: an object (index 0 = padding gap) of ``bit_length`` bits."""

    index: int
    subindex: int
    bit_length: int
    data_type: int = 0
    name: str = ""


@dataclass(frozen=True, slots=True)
class MappedPdo:
    """A PDO assigned to a sync manager."""

    index: int
    name: str
    entries: tuple[MappedPdoEntry, ...]
    direction: PdoDirection
    sync_manager: int

    @property
    def bit_length(self) -> int:
        return sum(e.bit_length for e in self.entries)


def _pdo_from_sii(sii: SiiInfo, pdo: SiiPdo, direction: PdoDirection) -> MappedPdo:
    entries = tuple(
        MappedPdoEntry(e.index, e.subindex, e.bit_length, e.data_type, sii.pdo_name(e) or "")
        for e in pdo.entries
    )
    return MappedPdo(pdo.index, sii.pdo_name(pdo) or "", entries, direction, pdo.sync_manager)


def pdos_from_sii(sii: SiiInfo) -> dict[int, list[MappedPdo]]:
    """The PDOs the SII assigns to sync managers, keyed by sync manager index.

    PDOs with sync manager ``SM_NOT_ASSIGNED`` (0xFF, none by default) are left out.
    """
    out: dict[int, list[MappedPdo]] = {}
    for direction, pdos in ((PdoDirection.OUTPUTS, sii.rx_pdos), (PdoDirection.INPUTS, sii.tx_pdos)):
        for p in pdos:
            if p.sync_manager == SM_NOT_ASSIGNED:
                continue
            out.setdefault(p.sync_manager, []).append(_pdo_from_sii(sii, p, direction))
    return out


# --- inputs ------------------------------------------------------------------------


@dataclass
class SlaveDescription(reg.EscFeaturesMixin):
    """What the configuration needs to know about one scanned slave.

    ``lrw_supported``, ``bitwise_fmmu`` ... decode ``features`` (register 0x0008).
    """

    position: int
    station_address: int
    sii: SiiInfo
    #: ESC features register 0x0008.
    features: int = 0
    #: FMMUs / sync managers the ESC has (registers 0x0004 / 0x0005).
    fmmu_count: int = 8
    sm_count: int = 8
    name: str = ""
    #: PDOs per sync manager from another source (CoE 0x1C12/0x1C13); None: use the SII.
    pdo_mapping: Mapping[int, Sequence[MappedPdo]] | None = None

    @property
    def supports_lrw(self) -> bool:
        """False when the ESC (feature bit 9) or the SII (General flag) rules LRW out."""
        if not self.lrw_supported:
            return False
        gen = self.sii.general
        return not (gen is not None and gen.flags & GeneralFlags.NOT_LRW)


@dataclass
class GroupSpec:
    """A process-data group to build: which slaves, which layout, at which logical base."""

    name: str
    #: Slave positions in this group; None: every slave no other group claims.
    slaves: Sequence[int] | None = None
    layout: Layout | str = Layout.PACKED
    #: Logical start address; None: after the previous group (DEFAULT_LOGICAL_BASE first).
    logical_base: int | None = None
    #: Cycle time in seconds this group is meant to run at (None: the master's cycle).
    cycle: float | None = None


# --- outputs -------------------------------------------------------------------------


@dataclass
class SyncManagerConfig:
    """Register values of one sync manager (0x0800 + 8 n)."""

    index: int
    start: int
    length: int
    control: int
    activate: int
    sm_type: int
    pdos: tuple[MappedPdo, ...] = ()

    @property
    def address(self) -> int:
        return reg.sm_address(self.index)

    @property
    def is_mailbox(self) -> bool:
        return self.sm_type in (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN)

    @property
    def is_process_data(self) -> bool:
        return self.sm_type in (SyncManagerType.OUTPUTS, SyncManagerType.INPUTS)

    def encode(self) -> bytes:
        """The 8 register bytes (status and PDI control are written as 0; the ESC owns them)."""
        return reg.SM_STRUCT.pack(self.start, self.length, self.control, 0, self.activate, 0)


@dataclass
class FmmuRegisters:
    """Register values of one FMMU (0x0600 + 16 n), as the master writes them."""

    index: int
    logical_start: int
    length: int
    logical_start_bit: int
    logical_stop_bit: int
    physical_start: int
    physical_start_bit: int
    fmmu_type: reg.FmmuType
    activate: int = 1

    @property
    def address(self) -> int:
        return reg.fmmu_address(self.index)

    @property
    def bit_length(self) -> int:
        """Mapped bits: 8 * length - start bit - (7 - stop bit) (ET1100 datasheet, FMMU 0x0600+)."""
        return 8 * self.length - self.logical_start_bit - (7 - self.logical_stop_bit)

    @property
    def logical_end(self) -> int:
        """First logical byte after the mapping."""
        return self.logical_start + self.length

    def encode(self) -> bytes:
        """The 16 register bytes."""
        return reg.FMMU_STRUCT.pack(
            self.logical_start, self.length, self.logical_start_bit, self.logical_stop_bit,
            self.physical_start, self.physical_start_bit, int(self.fmmu_type), self.activate)


@dataclass(frozen=True, slots=True)
class PdoVariable:
    """One PDO entry placed in a group image.

    ``bit_offset`` counts from the start of the group buffer (bit 0 of byte 0).
    """

    name: str
    pdo_name: str
    pdo_index: int
    index: int
    subindex: int
    bit_offset: int
    bit_length: int
    data_type: int
    direction: PdoDirection
    position: int

    @property
    def byte_offset(self) -> int:
        return self.bit_offset // 8

    @property
    def qualified_name(self) -> str:
        """``"PDO name.entry name"`` (unique where entry names repeat across PDOs)."""
        return f"{self.pdo_name}.{self.name}" if self.pdo_name else self.name


@dataclass
class SlaveConfig:
    """Everything configured for one slave."""

    position: int
    station_address: int
    name: str
    group: str
    sync_managers: list[SyncManagerConfig]
    fmmus: list[FmmuRegisters]
    variables: list[PdoVariable]
    output_bits: int
    input_bits: int
    supports_lrw: bool
    #: Bit offset of the slave's first output / input block in its group image (-1: none).
    output_bit_offset: int = -1
    input_bit_offset: int = -1
    warnings: list[str] = field(default_factory=list)
    #: Byte of the group image holding the slave's SM1 status (-1: not mapped).
    mailbox_status_offset: int = -1

    @property
    def output_bytes(self) -> int:
        return (self.output_bits + 7) // 8

    @property
    def input_bytes(self) -> int:
        return (self.input_bits + 7) // 8

    @property
    def mailbox_sync_managers(self) -> list[SyncManagerConfig]:
        return [s for s in self.sync_managers if s.is_mailbox]

    @property
    def process_data_sync_managers(self) -> list[SyncManagerConfig]:
        return [s for s in self.sync_managers if s.is_process_data]

    def process_data_writes(self) -> list[tuple[int, bytes]]:
        """(register address, bytes) to write before requesting SAFE-OP.

        Process-data sync managers and all FMMUs; the mailbox sync managers
        are written earlier, on the way to PRE-OP.
        """
        writes = [(s.address, s.encode()) for s in self.process_data_sync_managers]
        writes += [(f.address, f.encode()) for f in self.fmmus]
        return writes

    def mailbox_writes(self) -> list[tuple[int, bytes]]:
        """(register address, bytes) of the mailbox sync managers (before PRE-OP)."""
        return [(s.address, s.encode()) for s in self.mailbox_sync_managers]


@dataclass(frozen=True, slots=True)
class CyclicDatagram:
    """One datagram of a group's cycle.

    ``offset``/``length`` locate its data in the group buffer; the reply's bytes
    ``[copy_start, copy_end)`` (buffer offsets, inside the datagram) are copied
    back into the buffer: only the inputs, so an output the application writes
    while the frame is on the wire is not overwritten by the echo.
    """

    command: Command
    logical_address: int
    offset: int
    length: int
    expected_wkc: int
    copy_start: int
    copy_end: int
    positions: tuple[int, ...]


@dataclass(frozen=True)
class CrossLink:
    """Cross traffic (``master.cross``): ``bits`` of the producer's inputs (from
    ``producer_bit``) drive the consumer's outputs (from ``consumer_bit``) in the frame;
    ``bits`` None: all the consumer's output bits."""

    producer: int
    consumer: int
    bits: int | None = None
    producer_bit: int = 0
    consumer_bit: int = 0


@dataclass
class GroupConfig:
    """A process-data group: one image buffer, its datagrams and its slaves."""

    name: str
    logical_base: int
    layout: Layout
    output_bytes: int
    input_bytes: int
    slaves: list[SlaveConfig]
    datagrams: list[CyclicDatagram]
    uses_lrw: bool
    cycle: float | None = None
    #: Mailbox status bytes after the inputs (one per slave whose SM1 status is mapped).
    status_bytes: int = 0
    #: Slaves whose inputs drive later slaves' outputs in the frame (``master.cross``).
    cross: tuple[CrossLink, ...] = ()

    @property
    def size(self) -> int:
        """Bytes of the image (outputs, inputs, mailbox status bytes)."""
        return self.output_bytes + self.input_bytes + self.status_bytes

    @property
    def status_offset(self) -> int:
        """Offset of the mailbox status bytes inside the image."""
        return self.output_bytes + self.input_bytes

    @property
    def input_offset(self) -> int:
        """Offset of the inputs inside the image."""
        return self.output_bytes

    @property
    def expected_wkc(self) -> int:
        return sum(d.expected_wkc for d in self.datagrams)

    @property
    def logical_end(self) -> int:
        return self.logical_base + self.size

    @property
    def variables(self) -> list[PdoVariable]:
        return [v for s in self.slaves for v in s.variables]


@dataclass
class ProcessDataConfig:
    """The whole configuration: groups, and every slave's configuration by position."""

    groups: list[GroupConfig]
    slaves: dict[int, SlaveConfig]

    def group(self, name: str) -> GroupConfig:
        for g in self.groups:
            if g.name == name:
                return g
        raise ConfigError(f"no process-data group named {name!r} "
                          f"(groups: {', '.join(g.name for g in self.groups) or 'none'})")


# --- computing -------------------------------------------------------------------------


@dataclass
class _Block:
    """Contiguous sync managers of one direction of one slave, mapped by one FMMU."""

    direction: PdoDirection
    sms: list[SyncManagerConfig]
    bits: int
    # filled when placed
    bit_offset: int = 0
    #: Bits the FMMU maps: ``bits`` when packed, whole bytes otherwise.
    mapped_bits: int = 0


def _sm_direction(sm_type: int, control: int) -> PdoDirection | None:
    if sm_type == SyncManagerType.OUTPUTS:
        return PdoDirection.OUTPUTS
    if sm_type == SyncManagerType.INPUTS:
        return PdoDirection.INPUTS
    if sm_type == SyncManagerType.UNUSED and control & reg.SM_CONTROL_MODE_MASK == reg.SmMode.BUFFERED:
        direction = (control & reg.SM_CONTROL_DIRECTION_MASK) >> reg.SM_CONTROL_DIRECTION_SHIFT
        return PdoDirection.OUTPUTS if direction == reg.SmDirection.WRITE else PdoDirection.INPUTS
    return None


def _slave_sync_managers(spec: SlaveDescription, warnings: list[str]) -> list[SyncManagerConfig]:
    """Sync manager register values for one slave from its SII (and PDO mapping)."""
    sii = spec.sii
    mapping: Mapping[int, Sequence[MappedPdo]] = (
        spec.pdo_mapping if spec.pdo_mapping is not None else pdos_from_sii(sii))
    sii_sms = sii.sync_managers
    out: list[SyncManagerConfig] = []
    for n, sm in enumerate(sii_sms):
        if sm.enable & SyncManagerEnable.VIRTUAL:
            continue
        if sm.sm_type in (SyncManagerType.MAILBOX_OUT, SyncManagerType.MAILBOX_IN):
            start, length = sm.start, sm.length
            if length == 0:  # fall back to the fixed-area mailbox words
                rx, tx = sii.mailbox_layout()
                start, length = rx if sm.sm_type == SyncManagerType.MAILBOX_OUT else tx
            out.append(SyncManagerConfig(n, start, length, sm.control,
                                         reg.SM_ACTIVATE_ENABLE if length else 0, sm.sm_type))
            continue
        direction = _sm_direction(sm.sm_type, sm.control)
        if direction is None:
            continue
        pdos: list[MappedPdo] = []
        for p in mapping.get(n, ()):
            if p.direction is not direction:
                warnings.append(
                    f"slave {spec.position}: PDO 0x{p.index:04X} ({p.direction.value}) assigned "
                    f"to SM{n} which carries {direction.value}: left out")
                continue
            pdos.append(p)
        bits = sum(p.bit_length for p in pdos)
        length = (bits + 7) // 8
        sm_type = (SyncManagerType.OUTPUTS if direction is PdoDirection.OUTPUTS
                   else SyncManagerType.INPUTS)
        out.append(SyncManagerConfig(n, sm.start, length, sm.control,
                                     reg.SM_ACTIVATE_ENABLE if length else 0, sm_type,
                                     tuple(pdos)))
    for n in mapping:
        if not any(s.index == n for s in out) and any(p.bit_length for p in mapping[n]):
            warnings.append(f"slave {spec.position}: PDOs assigned to SM{n}, which the SII "
                            "does not describe as a process-data sync manager: left out")
    if len(out) and max(s.index for s in out) >= spec.sm_count:
        raise ConfigError(f"slave {spec.position}: SII describes SM{max(s.index for s in out)} "
                          f"but the ESC has {spec.sm_count} sync managers")
    return out


def _sm_bits(sm: SyncManagerConfig) -> int:
    return sum(p.bit_length for p in sm.pdos)


def _blocks(spec: SlaveDescription, sms: list[SyncManagerConfig], direction: PdoDirection) -> list[_Block]:
    """Group the slave's process-data SMs of one direction into FMMU blocks."""
    blocks: list[_Block] = []
    want = SyncManagerType.OUTPUTS if direction is PdoDirection.OUTPUTS else SyncManagerType.INPUTS
    for sm in sms:
        if sm.sm_type != want or sm.length == 0:
            continue
        prev = blocks[-1] if blocks else None
        last = prev.sms[-1] if prev is not None else None
        if (prev is not None and last is not None and last.start + last.length == sm.start
                and _sm_bits(last) == 8 * last.length):
            # contiguous RAM and the previous SM is full: one FMMU maps both
            prev.sms.append(sm)
            prev.bits = 8 * (sm.start - prev.sms[0].start) + _sm_bits(sm)
            continue
        blocks.append(_Block(direction, [sm], _sm_bits(sm)))
    return blocks


class _FmmuAllocator:
    """Hands out FMMU indices: the SII's choice for a direction first, then free ones."""

    def __init__(self, spec: SlaveDescription) -> None:
        self.spec = spec
        self.usages = list(spec.sii.fmmus)
        self.used: set[int] = set()

    def take(self, direction: PdoDirection) -> int:
        want = FmmuUsage.OUTPUTS if direction is PdoDirection.OUTPUTS else FmmuUsage.INPUTS
        count = self.spec.fmmu_count
        for n, usage in enumerate(self.usages):
            if usage == want and n not in self.used and n < count:
                self.used.add(n)
                return n
        if self.spec.fixed_fmmu_sm:
            fixed = 0 if direction is PdoDirection.OUTPUTS else 1
            if fixed not in self.used:
                self.used.add(fixed)
                return fixed
        # Any FMMU the SII does not reserve for something else (mailbox status).
        for n in range(count):
            usage = self.usages[n] if n < len(self.usages) else FmmuUsage.UNUSED
            if n in self.used or usage == FmmuUsage.MAILBOX_STATE:
                continue
            if usage in (FmmuUsage.OUTPUTS, FmmuUsage.INPUTS) and usage != want:
                continue
            self.used.add(n)
            return n
        raise ConfigError(f"slave {self.spec.position}: not enough FMMUs for its "
                          f"{direction.value} ({count} available)")

    def take_status(self) -> int | None:
        """An FMMU for the mailbox status byte: the SII's "SyncM status" one, else a free one.

        None when every FMMU is taken (the mailbox is then polled with frames).
        """
        count = self.spec.fmmu_count
        for n, usage in enumerate(self.usages):
            if usage == FmmuUsage.MAILBOX_STATE and n not in self.used and n < count:
                self.used.add(n)
                return n
        # Free ones the SII does not reserve first, then reserved but unused ones
        # (the hardware FMMUs are all alike).
        for reserved_ok in (False, True):
            for n in range(count):
                usage = self.usages[n] if n < len(self.usages) else FmmuUsage.UNUSED
                if n in self.used or (usage in (FmmuUsage.OUTPUTS, FmmuUsage.INPUTS)
                                      and not reserved_ok):
                    continue
                self.used.add(n)
                return n
        return None


def _mailbox_in(sms: Sequence[SyncManagerConfig]) -> SyncManagerConfig | None:
    """The slave's send mailbox sync manager (SM1), if it has one."""
    for sm in sms:
        if sm.sm_type == SyncManagerType.MAILBOX_IN and sm.length:
            return sm
    return None


def _variables(spec: SlaveDescription, block: _Block) -> list[PdoVariable]:
    out: list[PdoVariable] = []
    first = block.sms[0].start
    for sm in block.sms:
        bit = block.bit_offset + 8 * (sm.start - first)
        for pdo in sm.pdos:
            for e in pdo.entries:
                if e.index != 0 and e.bit_length:
                    name = e.name or f"0x{e.index:04X}:{e.subindex:02X}"
                    out.append(PdoVariable(name, pdo.name, pdo.index, e.index, e.subindex, bit,
                                           e.bit_length, e.data_type, block.direction,
                                           spec.position))
                bit += e.bit_length
    return out


def _place(blocks: list[tuple[SlaveDescription, _Block]], layout: Layout, start_bit: int) -> int:
    """Give each block its bit offset; return the bit after the last one."""
    cursor = start_bit
    for spec, block in blocks:
        packable = layout is Layout.PACKED and block.bits < 8 and spec.bitwise_fmmu
        if packable:
            if cursor % 8 + block.bits > 8:
                cursor = (cursor + 7) // 8 * 8
        else:
            cursor = (cursor + 7) // 8 * 8
        block.bit_offset = cursor
        block.mapped_bits = block.bits if packable else 8 * ((block.bits + 7) // 8)
        cursor += block.mapped_bits
    return cursor


def _fmmu(index: int, base: int, block: _Block) -> FmmuRegisters:
    start_bit = block.bit_offset % 8
    last_bit = block.bit_offset + block.mapped_bits - 1
    length = last_bit // 8 - block.bit_offset // 8 + 1
    ftype = reg.FmmuType.WRITE if block.direction is PdoDirection.OUTPUTS else reg.FmmuType.READ
    return FmmuRegisters(index, base + block.bit_offset // 8, length, start_bit, last_bit % 8,
                      block.sms[0].start, 0, ftype)


def _split(total: int, boundaries: Iterable[int], limit: int) -> list[tuple[int, int]]:
    """Cut [0, total) into pieces of at most ``limit`` bytes, at boundaries where possible."""
    cuts = sorted({b for b in boundaries if 0 < b < total})
    pieces: list[tuple[int, int]] = []
    start = 0
    while start < total:
        end = min(total, start + limit)
        if end < total:
            fits = [c for c in cuts if start < c <= end]
            if fits:
                end = fits[-1]
        pieces.append((start, end))
        start = end
    return pieces


def _expected_wkc(command: Command, lo: int, hi: int, fmmus: list[tuple[int, FmmuRegisters]]) -> tuple[int, tuple[int, ...]]:
    reads: set[int] = set()
    writes: set[int] = set()
    for position, f in fmmus:
        if f.logical_start < hi and f.logical_end > lo:
            (writes if f.fmmu_type & reg.FmmuType.WRITE else reads).add(position)
    if command is Command.LRW:
        wkc = 2 * len(writes) + len(reads)
        who = writes | reads
    elif command is Command.LWR:
        wkc, who = len(writes), writes
    else:
        wkc, who = len(reads), reads
    return wkc, tuple(sorted(who))


def expected_wkc(command: Command, lo: int, hi: int, fmmus: list[tuple[int, FmmuRegisters]]
                 ) -> tuple[int, tuple[int, ...]]:
    """The working counter a logical datagram over [lo, hi) expects from these FMMUs, and the
    slaves (positions) that add to it."""
    return _expected_wkc(command, lo, hi, fmmus)


def wkc_share(datagram: CyclicDatagram, slaves: Iterable[SlaveConfig]) -> int:
    """What ``slaves`` add to ``datagram``'s working counter (their FMMUs in its range)."""
    lo = datagram.logical_address
    return _expected_wkc(datagram.command, lo, lo + datagram.length,
                         [(s.position, f) for s in slaves for f in s.fmmus])[0]


def bus_shares(datagram: CyclicDatagram, slaves: Mapping[int, SlaveConfig]) -> list[tuple[int, int]]:
    """(position, share of ``datagram``'s working counter) of each of its slaves, in bus order.

    ``slaves``: by position (``ProcessDataConfig.slaves``)."""
    return [(p, wkc_share(datagram, [slaves[p]])) for p in sorted(datagram.positions)]


def _datagrams(base: int, out_bytes: int, in_bytes: int, lrw: bool,
               blocks: list[tuple[SlaveDescription, _Block]], fmmus: list[tuple[int, FmmuRegisters]],
               limit: int) -> list[CyclicDatagram]:
    total = out_bytes + in_bytes
    boundaries = [b.bit_offset // 8 for _, b in blocks] + [out_bytes]
    out: list[CyclicDatagram] = []

    def add(command: Command, lo: int, hi: int) -> None:
        for a, b in _split(hi - lo, (x - lo for x in boundaries), limit):
            start, end = lo + a, lo + b
            wkc, who = _expected_wkc(command, base + start, base + end, fmmus)
            copy_start = max(start, out_bytes)
            copy_end = end if end > copy_start else copy_start
            if command is Command.LWR:
                copy_start = copy_end = start
            out.append(CyclicDatagram(command, base + start, start, end - start, wkc,
                                      copy_start, copy_end, who))

    if total == 0:
        return out
    if lrw:
        add(Command.LRW, 0, total)
    else:
        if out_bytes:
            add(Command.LWR, 0, out_bytes)
        if in_bytes:
            add(Command.LRD, out_bytes, total)
    return out


def configure(slaves: Sequence[SlaveDescription], groups: Sequence[GroupSpec] | None = None,
              max_datagram: int = MAX_DATA, *, mailbox_status: bool = True,
              ) -> ProcessDataConfig:
    """Compute sync managers, FMMUs, group layouts and cyclic datagrams.

    ``groups`` default to one group ``"main"`` holding every slave. Slaves
    not claimed by any group with an explicit list go to the first group with
    ``slaves=None``; a slave claimed twice or by nobody raises
    :class:`ConfigError` (a slave with no process data may stay out).
    ``mailbox_status`` maps each group member's SM1 status byte after the
    group's inputs (see the module text).
    """
    if max_datagram < 1 or max_datagram > MAX_DATA:
        raise ConfigError(f"max_datagram must be 1..{MAX_DATA}, got {max_datagram}")
    by_pos = {s.position: s for s in slaves}
    if len(by_pos) != len(slaves):
        raise ConfigError("two slaves share one position")
    specs = list(groups) if groups else [GroupSpec("main")]
    if len({g.name for g in specs}) != len(specs):
        raise ConfigError("two process-data groups share one name")
    claimed: dict[int, str] = {}
    members: dict[str, list[int]] = {}
    for g in specs:
        if g.slaves is None:
            continue
        for p in g.slaves:
            if p not in by_pos:
                raise ConfigError(f"group {g.name!r} names slave {p}, which does not exist")
            if p in claimed:
                raise ConfigError(f"slave {p} is in groups {claimed[p]!r} and {g.name!r}")
            claimed[p] = g.name
        members[g.name] = list(g.slaves)
    rest = [s.position for s in slaves if s.position not in claimed]
    catch_all = next((g for g in specs if g.slaves is None), None)
    if catch_all is not None:
        members[catch_all.name] = rest
        rest = []
    for g in specs:
        members.setdefault(g.name, [])

    slave_configs: dict[int, SlaveConfig] = {}
    group_configs: list[GroupConfig] = []
    next_base = DEFAULT_LOGICAL_BASE
    for g in specs:
        try:
            layout = Layout(g.layout)
        except ValueError:
            raise ConfigError(f"group {g.name!r}: layout must be 'packed' or 'byte', "
                              f"got {g.layout!r}") from None
        base = next_base if g.logical_base is None else g.logical_base
        if not 0 <= base <= 0xFFFF_FFFF:
            raise ConfigError(f"group {g.name!r}: logical base 0x{base:X} out of range")
        positions = sorted(members[g.name])
        out_blocks: list[tuple[SlaveDescription, _Block]] = []
        in_blocks: list[tuple[SlaveDescription, _Block]] = []
        per_slave: dict[int, tuple[list[SyncManagerConfig], list[_Block], list[_Block], list[str]]] = {}
        for p in positions:
            spec = by_pos[p]
            warnings: list[str] = []
            sms = _slave_sync_managers(spec, warnings)
            ob = _blocks(spec, sms, PdoDirection.OUTPUTS)
            ib = _blocks(spec, sms, PdoDirection.INPUTS)
            out_blocks += [(spec, b) for b in ob]
            in_blocks += [(spec, b) for b in ib]
            per_slave[p] = (sms, ob, ib, warnings)
        out_end = _place(out_blocks, layout, 0)
        out_bytes = (out_end + 7) // 8
        in_end = _place(in_blocks, layout, 8 * out_bytes)
        in_bytes = (in_end + 7) // 8 - out_bytes
        all_fmmus: list[tuple[int, FmmuRegisters]] = []
        gslaves: list[SlaveConfig] = []
        lrw = True
        status_at = out_bytes + in_bytes
        for p in positions:
            spec = by_pos[p]
            sms, ob, ib, warnings = per_slave[p]
            alloc = _FmmuAllocator(spec)
            fmmus = [_fmmu(alloc.take(b.direction), base, b) for b in ob + ib]
            status_offset = -1
            mbx_in = _mailbox_in(sms) if mailbox_status else None
            if mbx_in is not None:
                n = alloc.take_status()
                if n is None:
                    warnings.append(f"slave {p}: no FMMU left for the mailbox status; its "
                                    "mailbox is polled with frames")
                else:
                    status_offset = status_at
                    status_at += 1
                    fmmus.append(FmmuRegisters(n, base + status_offset, 1, 0, 7,
                                            mbx_in.address + reg.SM_STATUS, 0,
                                            reg.FmmuType.READ))
                    if not spec.supports_lrw:
                        lrw = False
            fmmus.sort(key=lambda f: f.index)
            all_fmmus += [(p, f) for f in fmmus]
            variables = [v for b in ob + ib for v in _variables(spec, b)]
            if (ob or ib) and not spec.supports_lrw:
                lrw = False
            sc = SlaveConfig(
                p, spec.station_address, spec.name or spec.sii.device_name or f"slave {p}",
                g.name, sms, fmmus, variables,
                sum(b.bits for b in ob), sum(b.bits for b in ib), spec.supports_lrw,
                ob[0].bit_offset if ob else -1, ib[0].bit_offset if ib else -1, warnings,
                status_offset)
            slave_configs[p] = sc
            gslaves.append(sc)
        status_bytes = status_at - out_bytes - in_bytes
        dgrams = _datagrams(base, out_bytes, in_bytes + status_bytes, lrw, out_blocks + in_blocks,
                            all_fmmus, max_datagram)
        gc = GroupConfig(g.name, base, layout, out_bytes, in_bytes, gslaves, dgrams, lrw, g.cycle,
                         status_bytes)
        for other in group_configs:
            if gc.size and other.size and gc.logical_base < other.logical_end \
                    and other.logical_base < gc.logical_end:
                raise ConfigError(f"groups {other.name!r} and {g.name!r} overlap in logical space")
        group_configs.append(gc)
        end = max(base + gc.size, base + 1)
        next_base = (end + GROUP_ALIGNMENT - 1) // GROUP_ALIGNMENT * GROUP_ALIGNMENT
    for p in rest:  # slaves no group took: still get their mailbox SMs
        spec = by_pos[p]
        warnings = []
        sms = _slave_sync_managers(spec, warnings)
        if any(s.length for s in sms if s.is_process_data):
            raise ConfigError(f"slave {p} has process data but belongs to no group")
        slave_configs[p] = SlaveConfig(p, spec.station_address, spec.name or f"slave {p}", "",
                                       sms, [], [], 0, 0, spec.supports_lrw, warnings=warnings)
    return ProcessDataConfig(group_configs, slave_configs)
