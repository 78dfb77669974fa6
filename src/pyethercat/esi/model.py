"""Typed device model of an ESI (EtherCAT Slave Information) file.

Everything here is plain, immutable data: :mod:`pyethercat.esi.parse` builds it
from XML, and the master (configuration), the simulator (device images) and
the SII/ENI generators read it. Numbers are ints, binary blobs are ``bytes``,
texts that ESI gives per language are :class:`Text` (it and the data types are
in :mod:`pyethercat.esi.basics`).

The helpers at the bottom of :class:`EsiDevice` answer the questions the master
and simulator ask most: which PDOs are assigned by default to which sync
manager, how many bits that is, and where the mailboxes are.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Literal

from pyethercat.errors import EsiError
from pyethercat.esi.basics import (
    BASE_TYPES,
    ESI_TYPE_NAMES,
    LCID_ENGLISH,
    LCID_GERMAN,
    Text,
    TypeInfo,
    type_info,
)
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import mapping_word
from pyethercat.wire.registers import (
    SM_CONTROL_DIRECTION_MASK,
    SM_CONTROL_DIRECTION_SHIFT,
    SM_CONTROL_MODE_MASK,
    SmDirection,
    SmMode,
)

__all__ = [
    "BASE_TYPES",
    "ESI_TYPE_NAMES",
    "LCID_ENGLISH",
    "LCID_GERMAN",
    "EsiCoe",
    "EsiDataType",
    "EsiDc",
    "EsiDcOpMode",
    "EsiDevice",
    "EsiDeviceInfo",
    "EsiDictionary",
    "EsiEeprom",
    "EsiEoe",
    "EsiFile",
    "EsiFlags",
    "EsiFmmu",
    "EsiGroup",
    "EsiInitCmd",
    "EsiMailbox",
    "EsiObject",
    "EsiObjectSubItem",
    "EsiOdEntry",
    "EsiPdo",
    "EsiPdoEntry",
    "EsiProfile",
    "EsiSm",
    "EsiSubItemType",
    "EsiValueInfo",
    "EsiVendor",
    "PdoDirection",
    "PdoLayout",
    "SmKind",
    "SmLayout",
    "Text",
    "TypeInfo",
    "type_info",
]


# The ESI ControlByte attribute is the SM control register byte verbatim; its
# mode and direction fields tell an SM's role when its name is not one of the
# four standard ones (e.g. "OrbitaIn").

SmKind = Literal["MBoxOut", "MBoxIn", "Outputs", "Inputs"]
PdoDirection = Literal["rx", "tx"]


# --- vendor, groups ------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiVendor:
    """``<Vendor>``: the EtherCAT vendor id and name."""

    id: int
    name: Text = field(default_factory=Text)
    file_version: int | None = None
    image: bytes | None = None  # ImageData16x14 (a BMP)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiGroup:
    """``<Group>``: a device group devices refer to by ``GroupType``."""

    type: str
    name: Text = field(default_factory=Text)
    sort_order: int | None = None
    parent: str | None = None
    image: bytes | None = None


# --- device parts --------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiSm:
    """``<Sm>``: one sync manager (its number is its position in the device)."""

    index: int
    name: str  # the element text: MBoxOut, MBoxIn, Outputs, Inputs, or a vendor word
    start_address: int | None
    control_byte: int | None
    default_size: int | None = None
    min_size: int | None = None
    max_size: int | None = None
    enable: bool = False
    virtual: bool = False
    op_only: bool = False
    line: int | None = None

    @property
    def kind(self) -> SmKind | None:
        """The SM's role: the standard name, else derived from the control byte."""
        if self.name in ("MBoxOut", "MBoxIn", "Outputs", "Inputs"):
            return self.name  # type: ignore[return-value]
        if self.control_byte is None:
            return None
        mode = self.control_byte & SM_CONTROL_MODE_MASK
        direction = (self.control_byte & SM_CONTROL_DIRECTION_MASK) >> SM_CONTROL_DIRECTION_SHIFT
        mailbox = mode == SmMode.MAILBOX
        write = direction == SmDirection.WRITE
        if mailbox:
            return "MBoxOut" if write else "MBoxIn"
        return "Outputs" if write else "Inputs"

    @property
    def is_mailbox(self) -> bool:
        """True for the two mailbox SMs."""
        return self.kind in ("MBoxOut", "MBoxIn")

    @property
    def is_output(self) -> bool:
        """True when the master writes this SM (MBoxOut, Outputs)."""
        return self.kind in ("MBoxOut", "Outputs")


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiFmmu:
    """``<Fmmu>``: an FMMU and what it is for (Outputs, Inputs, MBoxState, ...)."""

    index: int
    name: str
    sm: int | None = None
    su: int | None = None
    op_only: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiPdoEntry:
    """``<Entry>`` of a PDO: one mapped object (index 0 is a gap / padding)."""

    index: int
    subindex: int
    bit_len: int
    name: Text = field(default_factory=Text)
    data_type: str | None = None
    comment: str | None = None

    @property
    def is_padding(self) -> bool:
        """A gap entry (index 0) reserves bits but maps no object."""
        return self.index == 0

    @property
    def mapping(self) -> int:
        """The 32-bit PDO mapping value (index << 16 | subindex << 8 | bits).

        Only the low 8 bits of the length fit the word.
        """
        return mapping_word(self.index, self.subindex, self.bit_len & 0xFF)

    @property
    def type_info(self) -> TypeInfo | None:
        """CANopen code and size of ``data_type``, when it is a known base type."""
        return type_info(self.data_type) if self.data_type else None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiPdo:
    """``<RxPdo>`` / ``<TxPdo>``.

    ``sm`` is the SM the PDO is assigned to by default (``None``: optional,
    not assigned by default). ``fixed``: the mapping cannot be changed;
    ``mandatory``: it must always be assigned; ``excludes``: PDOs that cannot
    be assigned together with this one.
    """

    direction: PdoDirection
    index: int
    name: Text = field(default_factory=Text)
    entries: tuple[EsiPdoEntry, ...] = ()
    sm: int | None = None
    su: int | None = None
    fixed: bool = False
    mandatory: bool = False
    virtual: bool = False
    excludes: tuple[int, ...] = ()
    os_fac: int | None = None
    os_min: int | None = None
    os_max: int | None = None
    os_index_inc: int | None = None
    line: int | None = None

    @property
    def bit_size(self) -> int:
        """Total size of the entries in bits."""
        return sum(e.bit_len for e in self.entries)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiInitCmd:
    """``<InitCmd>`` of CoE (or SoE): a write the master does on a transition."""

    transitions: tuple[str, ...]  # "PS", "IP", "SO", ...
    index: int
    subindex: int
    data: bytes
    comment: str | None = None
    complete_access: bool = False
    fixed: bool = False
    timeout_ms: int | None = None
    line: int | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiCoe:
    """``<CoE>`` mailbox protocol and its flags."""

    sdo_info: bool = False
    pdo_assign: bool = False
    pdo_config: bool = False
    pdo_upload: bool = False
    complete_access: bool = False
    segmented_sdo: bool = True  # ESI default: segmented transfer supported
    sdo_upload_with_max_length: bool = False
    diag_history: bool = False
    #: ``DS402Channels``: CiA 402 axes the device has (SII General byte 9).
    ds402_channels: int = 0
    init_cmds: tuple[EsiInitCmd, ...] = ()
    eds_file: str | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiEoe:
    """``<EoE>``: Ethernet over EtherCAT and its optional features."""

    ip: bool = False
    mac: bool = False
    time_stamp: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiMailbox:
    """``<Mailbox>``: which protocols the device speaks."""

    protocols: tuple[str, ...] = ()  # element names in file order: CoE, EoE, FoE, SoE, AoE, VoE
    data_link_layer: bool = False
    coe: EsiCoe | None = None
    eoe: EsiEoe | None = None
    soe_init_cmds: tuple[EsiInitCmd, ...] = ()

    def supports(self, protocol: str) -> bool:
        """True when ``protocol`` (``"CoE"``, ``"FoE"``, ...; any case) is listed."""
        p = protocol.lower()
        return any(x.lower() == p for x in self.protocols)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDcOpMode:
    """``<Dc><OpMode>``: one distributed-clock operating mode.

    Times are in ns. ``cycle_time_sync0_factor`` scales the bus cycle when
    ``cycle_time_sync0`` is 0 (the usual "take the cycle time") case.
    ``sm_pdos`` lists the PDOs this mode assigns per SM, when the mode says.
    """

    name: str
    desc: str | None = None
    assign_activate: int = 0
    cycle_time_sync0: int | None = None
    cycle_time_sync0_factor: int | None = None
    shift_time_sync0: int | None = None
    shift_time_sync0_factor: int | None = None
    shift_time_sync0_input: bool = False
    cycle_time_sync1: int | None = None
    cycle_time_sync1_factor: int | None = None
    shift_time_sync1: int | None = None
    shift_time_sync1_factor: int | None = None
    sm_pdos: tuple[tuple[int, tuple[int, ...]], ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDc:
    """``<Dc>``: the DC op modes (the first is the default)."""

    op_modes: tuple[EsiDcOpMode, ...] = ()
    pdo_oversampling: bool = False

    def op_mode(self, name: str) -> EsiDcOpMode | None:
        """The op mode called ``name`` (case-insensitive), if any."""
        n = name.lower()
        return next((m for m in self.op_modes if m.name.lower() == n), None)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiEeprom:
    """``<Eeprom>``: what goes into the SII image.

    ``config_data`` are the first bytes of the SII (PDI control, PDI config,
    SYNC impulse, ...); ``bootstrap`` the 8 bytes of bootstrap mailbox
    offsets/sizes. ``categories`` are extra (number, bytes) categories.
    ``data`` is set instead when the file gives a whole image.
    """

    byte_size: int | None = None
    config_data: bytes | None = None
    bootstrap: bytes | None = None
    categories: tuple[tuple[int, bytes], ...] = ()
    data: bytes | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDeviceInfo:
    """``<Info>``: electrical and timing facts (times in ms, current in mA)."""

    ebus_current: int | None = None
    request_timeout: int | None = None
    response_timeout: int | None = None
    preop_timeout: int | None = None
    safeop_op_timeout: int | None = None
    back_to_init_timeout: int | None = None
    back_to_safeop_timeout: int | None = None
    dpram_size: int | None = None
    fmmu_count: int | None = None
    sm_count: int | None = None


# --- object dictionary ---------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiFlags:
    """``<Flags>`` of an object or sub item."""

    access: str | None = None  # "ro", "rw", "wo"
    write_restrictions: str | None = None  # "PreOP", "PreOP_SafeOP_OP", ...
    pdo_mapping: str | None = None  # "R", "T", "RT", "TR"
    category: str | None = None  # "m", "o", "c"
    backup: bool = False
    setting: bool = False

    @property
    def readable(self) -> bool:
        """True unless the access is write-only."""
        return (self.access or "ro").lower() != "wo"

    @property
    def writable(self) -> bool:
        """True for rw / wo access."""
        return (self.access or "ro").lower() in ("rw", "wo")

    @property
    def rx_mappable(self) -> bool:
        """May be mapped into an RxPDO (the master writes it)."""
        return "R" in (self.pdo_mapping or "").upper()

    @property
    def tx_mappable(self) -> bool:
        """May be mapped into a TxPDO (the device sends it)."""
        return "T" in (self.pdo_mapping or "").upper()


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiSubItemType:
    """``<DataType><SubItem>``: one member of a structured or array type."""

    subindex: int | None
    name: str
    type: str
    bit_size: int
    bit_offset: int
    flags: EsiFlags = field(default_factory=EsiFlags)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDataType:
    """``<DataType>`` of a dictionary: base, array, struct or enum type."""

    name: str
    bit_size: int
    base_type: str | None = None
    array_lbound: int | None = None
    array_elements: int | None = None
    sub_items: tuple[EsiSubItemType, ...] = ()
    enums: tuple[tuple[int, str], ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiValueInfo:
    """``<Info>`` of an object or ``<SubItem><Info>``: defaults and limits.

    ``default_data`` is the raw value bytes (ESI writes them as hex in
    transfer order, i.e. little-endian); ``default_value`` the text form.
    """

    default_data: bytes | None = None
    default_value: str | None = None
    default_string: str | None = None
    min_value: str | None = None
    max_value: str | None = None
    unit: str | None = None

    def default_bytes(self, type_name: str | None = None) -> bytes | None:
        """The default as value bytes: ``DefaultData``, else ``DefaultString`` encoded.

        ``DefaultString`` (ETG.2000, for STRING/VISIBLE_STRING objects such as
        0x1008 device name) is text: UTF-16LE for a UNICODE_STRING, else the
        text's UTF-8 bytes.
        """
        if self.default_data is not None:
            return self.default_data
        if self.default_string is None:
            return None
        if type_name is not None and type_name.upper().startswith("UNICODE_STRING"):
            return self.default_string.encode("utf-16-le")
        return self.default_string.encode("utf-8")


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiObjectSubItem:
    """``<Object><Info><SubItem>``: per-sub-item name and defaults."""

    name: str
    info: EsiValueInfo = field(default_factory=EsiValueInfo)


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiObject:
    """``<Object>`` of the dictionary."""

    index: int
    name: Text
    type: str
    bit_size: int
    info: EsiValueInfo = field(default_factory=EsiValueInfo)
    sub_items: tuple[EsiObjectSubItem, ...] = ()
    flags: EsiFlags = field(default_factory=EsiFlags)
    line: int | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiOdEntry:
    """One readable entry of the dictionary, flattened: ``index:subindex``.

    Produced by :meth:`EsiDictionary.entries`, for building a simulated object
    dictionary or checking a PDO mapping.
    """

    index: int
    subindex: int
    name: str
    type: str
    code: DataType | None
    bit_size: int
    flags: EsiFlags
    default: bytes | None


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDictionary:
    """``<Dictionary>``: data types and objects of a profile."""

    data_types: Mapping[str, EsiDataType] = field(default_factory=dict)
    objects: tuple[EsiObject, ...] = ()

    def object(self, index: int) -> EsiObject | None:
        """The object at ``index``, if defined."""
        return next((o for o in self.objects if o.index == index), None)

    def type_info(self, name: str, _depth: int = 0) -> TypeInfo | None:
        """Like :func:`type_info`, also resolving the file's own type names."""
        if _depth > 16:  # a type cycle in a broken file: give up, do not recurse forever
            return None
        known = type_info(name)
        if known is not None:
            return known
        dt = self.data_types.get(name)
        if dt is None:
            return None
        if dt.base_type:
            base = self.type_info(dt.base_type, _depth + 1)
            if base is not None:
                if dt.array_elements is not None:
                    return TypeInfo(name, base.code, dt.bit_size, dt.array_elements, base)
                return TypeInfo(name, base.code, dt.bit_size, base.count, base.element)
        if dt.array_elements is not None and dt.sub_items:
            elem = self.type_info(dt.sub_items[0].type, _depth + 1)
            if elem is not None:
                return TypeInfo(name, elem.code, dt.bit_size, dt.array_elements, elem)
        return None

    def entries(self, obj: EsiObject) -> list[EsiOdEntry]:
        """Flatten ``obj`` into its entries, one per subindex.

        A plain variable gives one entry (subindex 0). A record or array type
        gives its sub items in order; a sub item without ``SubIdx`` whose type
        is an array type (``ArrayInfo``) expands to one entry per element,
        numbered from ``LBound``. Defaults come from the object's
        ``<Info><SubItem>`` list, matched by position.
        """
        dt = self.data_types.get(obj.type)
        if dt is None or not dt.sub_items:
            info = self.type_info(obj.type)
            return [
                EsiOdEntry(
                    index=obj.index,
                    subindex=0,
                    name=str(obj.name),
                    type=obj.type,
                    code=info.code if info else None,
                    bit_size=obj.bit_size,
                    flags=obj.flags,
                    default=obj.info.default_bytes(obj.type),
                )
            ]
        flat: list[tuple[int, str, str, int, EsiFlags]] = []
        next_sub = 0
        for item in dt.sub_items:
            arr = self.data_types.get(item.type) if item.subindex is None else None
            if arr is not None and arr.array_elements and arr.base_type:
                first = arr.array_lbound if arr.array_lbound is not None else next_sub
                size = arr.bit_size // arr.array_elements
                for n in range(arr.array_elements):
                    flat.append((first + n, item.name, arr.base_type, size, item.flags))
                next_sub = first + arr.array_elements
                continue
            sub = item.subindex if item.subindex is not None else next_sub
            flat.append((sub, item.name, item.type, item.bit_size, item.flags))
            next_sub = sub + 1
        out: list[EsiOdEntry] = []
        for pos, (sub, name, type_, bits, flags) in enumerate(flat):
            info = self.type_info(type_)
            default = None
            if pos < len(obj.sub_items):
                default = obj.sub_items[pos].info.default_bytes(type_)
                name = obj.sub_items[pos].name or name
            out.append(
                EsiOdEntry(
                    index=obj.index,
                    subindex=sub,
                    name=name,
                    type=type_,
                    code=info.code if info else None,
                    bit_size=bits,
                    flags=flags,
                    default=default,
                )
            )
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiProfile:
    """``<Profile>``: profile numbers and (optionally) the object dictionary."""

    profile_no: tuple[int, ...] = ()
    add_info: int | None = None
    channel_count: int | None = None
    dictionary: EsiDictionary | None = None


# --- PDO layout ----------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class SmLayout:
    """The process-data content of one SM in a chosen PDO assignment."""

    sm: EsiSm
    pdos: tuple[EsiPdo, ...]

    @property
    def bit_size(self) -> int:
        """Sum of the assigned PDOs' sizes in bits."""
        return sum(p.bit_size for p in self.pdos)

    @property
    def byte_size(self) -> int:
        """Bytes the SM must cover (bits rounded up)."""
        return (self.bit_size + 7) // 8

    @property
    def pdo_indices(self) -> tuple[int, ...]:
        """The assignment as written to 0x1C1n."""
        return tuple(p.index for p in self.pdos)


@dataclass(frozen=True, slots=True, kw_only=True)
class PdoLayout:
    """Default (or op-mode) PDO assignment of a device, per process-data SM."""

    sms: tuple[SmLayout, ...]

    def for_sm(self, index: int) -> SmLayout | None:
        """Layout of SM ``index``, if it carries process data."""
        return next((s for s in self.sms if s.sm.index == index), None)

    @property
    def output_bits(self) -> int:
        """Total RxPDO bits (master -> device) on real (non-virtual) SMs."""
        return sum(s.bit_size for s in self.sms if s.sm.is_output and not s.sm.virtual)

    @property
    def input_bits(self) -> int:
        """Total TxPDO bits (device -> master) on real (non-virtual) SMs."""
        return sum(s.bit_size for s in self.sms if not s.sm.is_output and not s.sm.virtual)


# --- device and file -----------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiDevice:
    """``<Device>``: one device revision with everything the file says about it."""

    product_code: int
    revision: int
    type_name: str  # the text of <Type>, e.g. "EL1004"
    name: Text = field(default_factory=Text)
    physics: str | None = None
    check_revision: str | None = None  # CheckRevisionNo, e.g. "EQ_OR_G"
    group_type: str | None = None
    url: Text = field(default_factory=Text)
    hide_revisions: tuple[int, ...] = ()
    alternative_revisions: tuple[int, ...] = ()
    info: EsiDeviceInfo = field(default_factory=EsiDeviceInfo)
    fmmus: tuple[EsiFmmu, ...] = ()
    sms: tuple[EsiSm, ...] = ()
    rx_pdos: tuple[EsiPdo, ...] = ()
    tx_pdos: tuple[EsiPdo, ...] = ()
    mailbox: EsiMailbox | None = None
    dc: EsiDc | None = None
    eeprom: EsiEeprom | None = None
    profiles: tuple[EsiProfile, ...] = ()
    image: bytes | None = None
    line: int | None = None

    # -- identity

    @property
    def identity(self) -> tuple[int, int]:
        """(product code, revision)."""
        return (self.product_code, self.revision)

    def __str__(self) -> str:
        return f"{self.type_name} (0x{self.product_code:08X} rev 0x{self.revision:08X})"

    # -- lookups

    @property
    def pdos(self) -> tuple[EsiPdo, ...]:
        """All PDOs, RxPDOs first."""
        return self.rx_pdos + self.tx_pdos

    def pdo(self, index: int) -> EsiPdo | None:
        """The PDO with object index ``index``."""
        return next((p for p in self.pdos if p.index == index), None)

    @property
    def dictionary(self) -> EsiDictionary | None:
        """The object dictionary of the first profile that has one."""
        return next((p.dictionary for p in self.profiles if p.dictionary is not None), None)

    @property
    def mbox_out(self) -> EsiSm | None:
        """The master-to-device mailbox SM."""
        return next((s for s in self.sms if s.kind == "MBoxOut"), None)

    @property
    def mbox_in(self) -> EsiSm | None:
        """The device-to-master mailbox SM."""
        return next((s for s in self.sms if s.kind == "MBoxIn"), None)

    @property
    def mailbox_sizes(self) -> tuple[int, int] | None:
        """(MBoxOut size, MBoxIn size) in bytes, or None without a mailbox."""
        out, inp = self.mbox_out, self.mbox_in
        if out is None or inp is None:
            return None
        return (out.default_size or out.max_size or 0, inp.default_size or inp.max_size or 0)

    @property
    def process_sms(self) -> tuple[EsiSm, ...]:
        """SMs that carry process data (not mailbox)."""
        return tuple(s for s in self.sms if not s.is_mailbox)

    # -- PDO assignment

    def default_pdos(self, direction: PdoDirection) -> tuple[EsiPdo, ...]:
        """PDOs assigned by default: mandatory ones, then those with an ``Sm``,
        in file order, skipping any PDO excluded by one already chosen."""
        pdos = self.rx_pdos if direction == "rx" else self.tx_pdos
        chosen: list[EsiPdo] = []
        taken: set[int] = set()
        banned: set[int] = set()
        # Mandatory PDOs win over optional ones that exclude them.
        for wanted in (True, False):
            for p in pdos:
                if p.mandatory != wanted or p.index in taken:
                    continue
                if not p.mandatory and p.sm is None:
                    continue
                if p.index in banned or any(x in taken for x in p.excludes):
                    continue
                chosen.append(p)
                taken.add(p.index)
                banned.update(p.excludes)
        order = {p.index: n for n, p in enumerate(pdos)}
        return tuple(sorted(chosen, key=lambda p: order[p.index]))

    def _default_sm_for(self, direction: PdoDirection) -> int | None:
        want = "Outputs" if direction == "rx" else "Inputs"
        return next((s.index for s in self.sms if s.kind == want and not s.virtual), None)

    def pdo_layout(
        self,
        op_mode: str | None = None,
        assignment: Mapping[int, tuple[int, ...]] | None = None,
    ) -> PdoLayout:
        """PDO assignment per process-data SM and its size.

        Without arguments: the default assignment (:meth:`default_pdos`).
        ``op_mode`` names a DC op mode whose ``<Sm><Pdo>`` lists override the
        default for the SMs it names. ``assignment`` ({sm: (pdo index, ...)})
        overrides both. Raises :class:`EsiError` for unknown op modes, PDOs or
        SMs.
        """
        per_sm: dict[int, list[EsiPdo]] = {s.index: [] for s in self.process_sms}
        directions: tuple[PdoDirection, ...] = ("rx", "tx")
        for direction in directions:
            fallback = self._default_sm_for(direction)
            for p in self.default_pdos(direction):
                sm = p.sm if p.sm is not None else fallback
                if sm is None:
                    continue
                per_sm.setdefault(sm, []).append(p)
        override: dict[int, tuple[int, ...]] = {}
        if op_mode is not None:
            mode = self.dc.op_mode(op_mode) if self.dc else None
            if mode is None:
                raise EsiError(f"{self}: no DC op mode named {op_mode!r}")
            override.update(mode.sm_pdos)
        if assignment is not None:
            override.update(assignment)
        for sm_index, indices in override.items():
            if not 0 <= sm_index < len(self.sms):
                raise EsiError(f"{self}: PDO assignment names SM{sm_index}, which does not exist")
            chosen: list[EsiPdo] = []
            for idx in indices:
                found = self.pdo(idx)
                if found is None:
                    raise EsiError(
                        f"{self}: PDO assignment names PDO 0x{idx:04X}, which does not exist"
                    )
                chosen.append(found)
            per_sm[sm_index] = chosen
        sm_by_index = {s.index: s for s in self.sms}
        return PdoLayout(
            sms=tuple(
                SmLayout(sm=sm_by_index[i], pdos=tuple(per_sm[i]))
                for i in sorted(per_sm)
                if i in sm_by_index
            )
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class EsiFile:
    """A whole ESI file: vendor, groups and every device (revision) in it."""

    source: str
    vendor: EsiVendor
    version: str | None = None
    groups: tuple[EsiGroup, ...] = ()
    devices: tuple[EsiDevice, ...] = ()

    def __iter__(self) -> Iterator[EsiDevice]:
        return iter(self.devices)

    def __len__(self) -> int:
        return len(self.devices)

    def group(self, type_: str) -> EsiGroup | None:
        """The group whose ``Type`` is ``type_``."""
        return next((g for g in self.groups if g.type == type_), None)

    def devices_for(self, product_code: int) -> tuple[EsiDevice, ...]:
        """All revisions of ``product_code``, in file order."""
        return tuple(d for d in self.devices if d.product_code == product_code)

    def find_device(self, product_code: int, revision: int | None = None) -> EsiDevice:
        """The device with this product code (and revision).

        ``revision=None`` picks the highest revision. Raises :class:`EsiError`
        when there is no such device.
        """
        found = self.devices_for(product_code)
        if revision is not None:
            found = tuple(d for d in found if d.revision == revision)
        if not found:
            rev = "" if revision is None else f" revision 0x{revision:08X}"
            raise EsiError(f"no device with product code 0x{product_code:08X}{rev}", self.source)
        return max(found, key=lambda d: d.revision)
