"""Typed model of an SII (slave information interface) EEPROM image.

The image is a fixed area of 64 words (0x00-0x3F) followed by a chain of
categories (IEC 61158-6-12:2019 5.4, ETG.1000.6; ETG.2010 for the categories). The model keeps every byte it read, so an
image parsed and rebuilt comes back the same: reserved words of the fixed area,
categories nobody here understands (vendor categories, FMMUX, SyncUnit) and
any bytes left over inside a known category after its structured content.

Categories are kept in image order in ``SiiInfo.categories``; the properties of
``SiiInfo`` (``strings``, ``general``, ``tx_pdos`` ...) give flat views for
readers that do not care about the order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

__all__ = [
    "CRC_COVERED_BYTES",
    "DC_MODE_SIZE",
    "END_MARKER",
    "FIXED_AREA_BYTES",
    "GENERAL_SIZE",
    "PDO_ENTRY_SIZE",
    "PDO_HEADER_SIZE",
    "SM_NOT_ASSIGNED",
    "SYNC_MANAGER_SIZE",
    "VENDOR_CATEGORY_FLAG",
    "WORD_ALIAS",
    "WORD_BOOT_RX_MAILBOX",
    "WORD_CHECKSUM",
    "WORD_EEPROM_SIZE",
    "WORD_FIRST_CATEGORY",
    "WORD_MAILBOX_PROTOCOLS",
    "WORD_PDI_CONFIG",
    "WORD_PDI_CONFIG2",
    "WORD_PDI_CONTROL",
    "WORD_PRODUCT_CODE",
    "WORD_REVISION",
    "WORD_SERIAL",
    "WORD_STD_RX_MAILBOX",
    "WORD_SYNC_IMPULSE",
    "WORD_VENDOR_ID",
    "WORD_VERSION",
    "CategoryType",
    "CoeDetails",
    "FmmuUsage",
    "GeneralFlags",
    "MailboxProtocol",
    "SiiCategory",
    "SiiDc",
    "SiiDcMode",
    "SiiFmmus",
    "SiiGeneral",
    "SiiInfo",
    "SiiPdo",
    "SiiPdoEntry",
    "SiiPdoFlags",
    "SiiPdos",
    "SiiPortType",
    "SiiRawCategory",
    "SiiStrings",
    "SiiSyncManager",
    "SiiSyncManagers",
    "SyncManagerEnable",
    "SyncManagerType",
    "category_name",
]

# Word addresses of the fixed area (ETG.2010; SOEM ec_type.h ECT_SII_*, siitool sii.h).
# Byte offset = 2 * word.
WORD_PDI_CONTROL = 0x00
WORD_PDI_CONFIG = 0x01
WORD_SYNC_IMPULSE = 0x02
WORD_PDI_CONFIG2 = 0x03
WORD_ALIAS = 0x04
WORD_CHECKSUM = 0x07
WORD_VENDOR_ID = 0x08
WORD_PRODUCT_CODE = 0x0A
WORD_REVISION = 0x0C
WORD_SERIAL = 0x0E
WORD_BOOT_RX_MAILBOX = 0x14
WORD_STD_RX_MAILBOX = 0x18
WORD_MAILBOX_PROTOCOLS = 0x1C
WORD_EEPROM_SIZE = 0x3E
WORD_VERSION = 0x3F
WORD_FIRST_CATEGORY = 0x40

FIXED_AREA_BYTES = 2 * WORD_FIRST_CATEGORY  # 128
CRC_COVERED_BYTES = 2 * WORD_CHECKSUM  # bytes 0-13
END_MARKER = 0xFFFF
VENDOR_CATEGORY_FLAG = 0x8000

GENERAL_SIZE = 32
SYNC_MANAGER_SIZE = 8
PDO_HEADER_SIZE = 8
PDO_ENTRY_SIZE = 8
DC_MODE_SIZE = 24

#: ``SiiPdo.sync_manager`` of a PDO that is not assigned to any sync manager.
SM_NOT_ASSIGNED = 0xFF


class CategoryType(IntEnum):
    """Category type codes (ETG.2010; siitool ``sii.h`` ``eSection``).

    Bit 15 of the type word marks vendor categories.
    """

    NOP = 0
    STRINGS = 10
    DATA_TYPES = 20
    GENERAL = 30
    FMMU = 40
    SYNCM = 41
    # 42/43 are named after ethercrab's category list; their bodies are kept raw.
    FMMU_EX = 42
    SYNC_UNIT = 43
    TXPDO = 50
    RXPDO = 51
    DC = 60
    END = 0xFFFF


def category_name(ctype: int) -> str:
    """Readable name of a category type code (``"0x0800"`` for unknown ones)."""
    try:
        return CategoryType(ctype).name
    except ValueError:
        return f"0x{ctype:04X}"


class MailboxProtocol(IntFlag):
    """Supported mailbox protocols, word 0x1C (IEC 61158-6-12:2019 5.4 Table 18)."""

    NONE = 0
    AOE = 0x0001
    EOE = 0x0002
    COE = 0x0004
    FOE = 0x0008
    SOE = 0x0010
    VOE = 0x0020


class CoeDetails(IntFlag):
    """General category byte 0x05."""

    NONE = 0
    SDO = 0x01
    SDO_INFO = 0x02
    PDO_ASSIGN = 0x04
    PDO_CONFIG = 0x08
    UPLOAD_AT_STARTUP = 0x10
    SDO_COMPLETE_ACCESS = 0x20


class GeneralFlags(IntFlag):
    """General category byte 0x0B."""

    NONE = 0
    ENABLE_SAFEOP = 0x01
    NOT_LRW = 0x02
    MBOX_DATA_LINK_LAYER = 0x04
    IDENT_AL_STATUS = 0x08
    IDENT_PHYSICAL_MEMORY = 0x10


class SiiPortType(IntEnum):
    """Physical port description, 4 bits per port in General bytes 0x10-0x11.

    Not the ESC's port descriptor 0x0007 (``pyethercat.wire.registers.PortType``),
    whose numbers mean other things (there MII = 3, E-Bus = 2).
    """

    NOT_USED = 0
    MII = 1
    RESERVED = 2
    EBUS = 3


class FmmuUsage(IntEnum):
    """One byte per FMMU in the FMMU category."""

    UNUSED = 0x00
    OUTPUTS = 0x01
    INPUTS = 0x02
    MAILBOX_STATE = 0x03
    NOT_USED = 0xFF


class SyncManagerType(IntEnum):
    """SyncM category type byte."""

    UNUSED = 0
    MAILBOX_OUT = 1  # master -> slave (SM0)
    MAILBOX_IN = 2  # slave -> master (SM1)
    OUTPUTS = 3
    INPUTS = 4


class SyncManagerEnable(IntFlag):
    """SyncM category enable byte."""

    NONE = 0
    ENABLE = 0x01
    FIXED_CONTENT = 0x02
    VIRTUAL = 0x04
    OP_ONLY = 0x08


class SiiPdoFlags(IntFlag):
    """Flags word of a TxPDO/RxPDO category PDO header (ETG.2010 PDO flags).

    ``SiiPdo.flags`` stays a plain ``int`` (unknown bits survive a round trip);
    test it against these members.
    """

    NONE = 0
    MANDATORY = 0x0001
    DEFAULT = 0x0002
    OVERSAMPLE = 0x0004
    FIXED_CONTENT = 0x0010
    VIRTUAL_CONTENT = 0x0020


def _enum_or_int(enum: type[IntEnum], value: int) -> int:
    """Return the enum member for a known value, the plain int otherwise."""
    try:
        return enum(value)
    except ValueError:
        return value


# --- categories ----------------------------------------------------------------


@dataclass
class SiiStrings:
    """Strings category (10): index 1 is the first string, 0 means "none".

    Strings are raw bytes (some devices store binary data such as an icon in
    a string); ``SiiInfo.string`` decodes them as latin-1, which never fails.
    ``extra`` holds body bytes after the last string other than the single
    zero byte that pads the body to whole words.
    """

    strings: list[bytes] = field(default_factory=list)
    extra: bytes = b""
    type: int = field(default=CategoryType.STRINGS, init=False)


@dataclass
class SiiGeneral:
    """General category (30), 32 bytes (ETG.2010; IgH ``master/slave.c``
    ``ec_slave_fetch_sii_general``). ``extra`` = bytes beyond 32."""

    group_index: int = 0
    image_index: int = 0
    order_index: int = 0
    name_index: int = 0
    reserved_04: int = 0
    coe_details: CoeDetails = CoeDetails.NONE
    foe_details: int = 0
    eoe_details: int = 0
    soe_channels: int = 0
    ds402_channels: int = 0
    sysman_class: int = 0
    flags: GeneralFlags = GeneralFlags.NONE
    ebus_current_ma: int = 0  # signed: negative = the device feeds current into the E-bus
    reserved_0e: int = 0  # u16
    physical_ports: int = 0  # u16, 4 bits per port, port 0 in bits 3:0
    physical_memory_address: int = 0
    reserved_14: bytes = bytes(12)
    extra: bytes = b""
    type: int = field(default=CategoryType.GENERAL, init=False)

    @property
    def ports(self) -> tuple[int, int, int, int]:
        """Port types of ports 0-3 (``SiiPortType`` where known)."""
        p = self.physical_ports
        return (
            _enum_or_int(SiiPortType, p & 0xF),
            _enum_or_int(SiiPortType, (p >> 4) & 0xF),
            _enum_or_int(SiiPortType, (p >> 8) & 0xF),
            _enum_or_int(SiiPortType, (p >> 12) & 0xF),
        )


@dataclass
class SiiFmmus:
    """FMMU category (40): one usage byte per FMMU (``FmmuUsage`` where known).

    The category is sized in words; an odd list is padded with one UNUSED
    entry when built, so it reads back one longer.
    """

    usages: list[int] = field(default_factory=list)
    type: int = field(default=CategoryType.FMMU, init=False)


@dataclass
class SiiSyncManager:
    """One SyncManager description (8 bytes)."""

    start: int = 0
    length: int = 0
    control: int = 0
    status: int = 0
    enable: int = 0
    sm_type: int = SyncManagerType.UNUSED

    @property
    def enabled(self) -> bool:
        """Enable bit (bit 0 of the enable byte)."""
        return bool(self.enable & SyncManagerEnable.ENABLE)


@dataclass
class SiiSyncManagers:
    """SyncM category (41). ``extra``: trailing bytes that are not a whole entry."""

    sync_managers: list[SiiSyncManager] = field(default_factory=list)
    extra: bytes = b""
    type: int = field(default=CategoryType.SYNCM, init=False)


@dataclass
class SiiPdoEntry:
    """One PDO entry (8 bytes). ``index`` 0 is a padding gap."""

    index: int = 0
    subindex: int = 0
    name_index: int = 0
    data_type: int = 0
    bit_length: int = 0
    flags: int = 0


@dataclass
class SiiPdo:
    """One PDO (8-byte header + entries). ``sync_manager`` :data:`SM_NOT_ASSIGNED` = none.

    ``flags`` holds :class:`SiiPdoFlags` bits.
    """

    index: int = 0
    sync_manager: int = 0
    dc_sync: int = 0
    name_index: int = 0
    flags: int = 0
    entries: list[SiiPdoEntry] = field(default_factory=list)

    @property
    def bit_length(self) -> int:
        """Sum of the entries' bit lengths."""
        return sum(e.bit_length for e in self.entries)


@dataclass
class SiiPdos:
    """TxPDO (50, slave -> master, inputs) or RxPDO (51, outputs) category."""

    type: int = CategoryType.TXPDO
    pdos: list[SiiPdo] = field(default_factory=list)
    extra: bytes = b""


@dataclass
class SiiDcMode:
    """One DC operation mode of the DC category (24 bytes; ETG.2010 Table 12 as KickCAT
    ``lib/src/ESI/SIIBuilder.cc`` cites it, siitool ``sii.c`` ``parse_dclock_section``)."""

    cycle_time_sync0: int = 0  # u32
    shift_time_sync0: int = 0  # i32
    shift_time_sync1: int = 0  # i32
    sync1_cycle_factor: int = 0  # i16
    assign_activate: int = 0  # u16, value for 0x0980/0x0981
    sync0_cycle_factor: int = 0  # i16
    name_index: int = 0
    description_index: int = 0
    reserved: bytes = bytes(4)


@dataclass
class SiiDc:
    """DC category (60). ``extra``: trailing bytes that are not a whole mode."""

    modes: list[SiiDcMode] = field(default_factory=list)
    extra: bytes = b""
    type: int = field(default=CategoryType.DC, init=False)


@dataclass
class SiiRawCategory:
    """A category kept as bytes: vendor (bit 15), NOP, FMMUX, SyncUnit, unknown."""

    type: int
    data: bytes = b""

    @property
    def vendor_specific(self) -> bool:
        """Bit 15 of the type word."""
        return bool(self.type & VENDOR_CATEGORY_FLAG)


SiiCategory = (
    SiiStrings | SiiGeneral | SiiFmmus | SiiSyncManagers | SiiPdos | SiiDc | SiiRawCategory
)


# --- the image -----------------------------------------------------------------


@dataclass
class SiiInfo:
    """A parsed SII image: fixed area words 0x00-0x3F plus the category list.

    Equality compares content only: ``checksum`` (the stored word 7),
    ``checksum_ok``, ``end_marker`` and ``warnings`` describe how an image was
    read, and ``build_sii`` recomputes the checksum, so they are left out.
    Reserved words are kept (``reserved_*``) so that nothing is lost.
    """

    pdi_control: int = 0
    pdi_config: int = 0
    sync_impulse_len: int = 0  # 10 ns units, -> 0x0982
    pdi_config2: int = 0
    station_alias: int = 0
    reserved_05: bytes = bytes(4)  # words 0x05-0x06
    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0
    serial: int = 0
    reserved_10: bytes = bytes(8)  # words 0x10-0x13 (KickCAT: execution/port delays)
    boot_rx_mailbox_offset: int = 0  # receive = master -> slave (SM0 in BOOT)
    boot_rx_mailbox_size: int = 0
    boot_tx_mailbox_offset: int = 0  # send = slave -> master (SM1 in BOOT)
    boot_tx_mailbox_size: int = 0
    rx_mailbox_offset: int = 0  # standard receive mailbox (SM0)
    rx_mailbox_size: int = 0
    tx_mailbox_offset: int = 0  # standard send mailbox (SM1)
    tx_mailbox_size: int = 0
    mailbox_protocols: MailboxProtocol = MailboxProtocol.NONE
    reserved_1d: bytes = bytes(66)  # words 0x1D-0x3D
    eeprom_size_code: int = 0  # word 0x3E: (value + 1) Kbit
    version: int = 1
    categories: list[SiiCategory] = field(default_factory=list)
    checksum: int = field(default=0, compare=False)
    checksum_ok: bool = field(default=True, compare=False)
    end_marker: bool = field(default=True, compare=False)
    warnings: list[str] = field(default_factory=list, compare=False)

    # --- mailbox --------------------------------------------------------------

    def mailbox_layout(self, boot: bool = False) -> tuple[tuple[int, int], tuple[int, int]]:
        """``((receive offset, size), (send offset, size))`` of the standard or bootstrap mailbox.

        Receive is master -> slave (SM0), send slave -> master (SM1); SII
        words 0x18-0x1B for the standard mailbox, 0x14-0x17 for the bootstrap
        mailbox (ETG.1000.6 table "SII EEPROM"). A size of 0 means none.
        """
        if boot:
            return ((self.boot_rx_mailbox_offset, self.boot_rx_mailbox_size),
                    (self.boot_tx_mailbox_offset, self.boot_tx_mailbox_size))
        return ((self.rx_mailbox_offset, self.rx_mailbox_size),
                (self.tx_mailbox_offset, self.tx_mailbox_size))

    # --- sizes ---------------------------------------------------------------

    @property
    def eeprom_size_kbit(self) -> int:
        """EEPROM size in Kbit (word 0x3E + 1)."""
        return self.eeprom_size_code + 1

    @property
    def eeprom_size_bytes(self) -> int:
        """EEPROM size in bytes ((word 0x3E + 1) * 128)."""
        return (self.eeprom_size_code + 1) * 128

    # --- flat views of the categories ------------------------------------------

    @property
    def strings(self) -> list[bytes]:
        """All strings (of every Strings category, in order); index 1 = element 0."""
        out: list[bytes] = []
        for c in self.categories:
            if isinstance(c, SiiStrings):
                out.extend(c.strings)
        return out

    @property
    def general(self) -> SiiGeneral | None:
        """The (first) General category, or None."""
        for c in self.categories:
            if isinstance(c, SiiGeneral):
                return c
        return None

    @property
    def fmmus(self) -> list[int]:
        """FMMU usage bytes (``FmmuUsage`` where known)."""
        return [u for c in self.categories if isinstance(c, SiiFmmus) for u in c.usages]

    @property
    def sync_managers(self) -> list[SiiSyncManager]:
        """SyncManager descriptions, SM0 first."""
        return [
            s for c in self.categories if isinstance(c, SiiSyncManagers) for s in c.sync_managers
        ]

    @property
    def tx_pdos(self) -> list[SiiPdo]:
        """TxPDOs (inputs, slave -> master) of every TxPDO category."""
        return [
            p
            for c in self.categories
            if isinstance(c, SiiPdos) and c.type == CategoryType.TXPDO
            for p in c.pdos
        ]

    @property
    def rx_pdos(self) -> list[SiiPdo]:
        """RxPDOs (outputs, master -> slave) of every RxPDO category."""
        return [
            p
            for c in self.categories
            if isinstance(c, SiiPdos) and c.type == CategoryType.RXPDO
            for p in c.pdos
        ]

    @property
    def dc_modes(self) -> list[SiiDcMode]:
        """DC operation modes of every DC category."""
        return [m for c in self.categories if isinstance(c, SiiDc) for m in c.modes]

    @property
    def raw_categories(self) -> list[SiiRawCategory]:
        """Categories kept as raw bytes (vendor, NOP, unknown)."""
        return [c for c in self.categories if isinstance(c, SiiRawCategory)]

    # --- strings ---------------------------------------------------------------

    def string(self, index: int) -> str | None:
        """String ``index`` (1-based) decoded as latin-1; None for 0 or out of range."""
        strings = self.strings
        if 1 <= index <= len(strings):
            return strings[index - 1].decode("latin-1")
        return None

    def _general_string(self, attr: str) -> str | None:
        gen = self.general
        return None if gen is None else self.string(int(getattr(gen, attr)))

    @property
    def device_name(self) -> str | None:
        """Device name (General name index), e.g. ``"EK1100"``."""
        return self._general_string("name_index")

    @property
    def group_name(self) -> str | None:
        """Group name (General group index)."""
        return self._general_string("group_index")

    @property
    def order_number(self) -> str | None:
        """Order number (General order index)."""
        return self._general_string("order_index")

    @property
    def image_name(self) -> str | None:
        """Image name (General image index)."""
        return self._general_string("image_index")

    def pdo_name(self, pdo: SiiPdo | SiiPdoEntry) -> str | None:
        """Name of a PDO or PDO entry, resolved through the strings."""
        return self.string(pdo.name_index)

    # --- process data summary ----------------------------------------------------

    @property
    def output_bits(self) -> int:
        """Bits of all RxPDOs assigned to a SyncManager (not SM_NOT_ASSIGNED)."""
        return sum(p.bit_length for p in self.rx_pdos if p.sync_manager != SM_NOT_ASSIGNED)

    @property
    def input_bits(self) -> int:
        """Bits of all TxPDOs assigned to a SyncManager (not SM_NOT_ASSIGNED)."""
        return sum(p.bit_length for p in self.tx_pdos if p.sync_manager != SM_NOT_ASSIGNED)
