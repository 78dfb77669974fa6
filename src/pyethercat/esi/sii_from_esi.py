"""SII (EEPROM) image from an ESI device description.

:func:`esi_to_sii` turns one :class:`~pyethercat.esi.model.EsiDevice` into the
image a configuration tool (siitool, the vendors' EEPROM generators) would
write into the slave's EEPROM:

* fixed area: words 0-6 from ``Eeprom/ConfigData`` (PDI control, PDI
  configuration, SYNC impulse, PDI configuration 2, station alias), the header
  checksum, vendor/product/revision/serial, the bootstrap mailbox from
  ``Eeprom/BootStrap``, the standard mailbox from the ``MBoxOut``/``MBoxIn``
  sync managers, the mailbox protocol word from ``Mailbox``, the size word from
  ``Eeprom/ByteSize``;
* categories in the usual order: Strings, General, FMMU, SyncM, TxPDO, RxPDO,
  DC, then any ``Eeprom/Category`` the file carries verbatim.

Conventions where the ESI leaves a choice (they match what the vendor images
in the corpus do, see ``docs/esi.md``): string 1 is the order number
(``<Type>``), then the group type, then the device name, then PDO and entry
names; equal strings are stored once. A PDO carries the SM it is assigned to by
default (0xFF when it is only selectable), flags Mandatory (0x0001), Fixed
(0x0010) and Virtual (0x0020). When the PDO categories do not fit into
``ByteSize`` they are left out (SOES-style small EEPROMs describe their PDOs in
the object dictionary only), and a note says so.

:func:`sii_differences` compares two images field by field (identity, mailbox,
SMs, FMMUs, PDOs, DC, General) and names each difference; the corpus test and
``pyethercat esi sii --compare`` use it.

Pure functions: no I/O except :func:`sii_image_from_file`, a convenience that
only reads the ESI file it is given (the simulator's topology loader goes
through ``sim.devices.esi_device.load_esi_device`` instead, which caches the
parse).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from pyethercat.errors import EsiError, SiiError
from pyethercat.esi.model import LCID_ENGLISH, EsiDevice, EsiFile, EsiPdo, EsiSm
from pyethercat.esi.parse import load_esi
from pyethercat.wire.sii import (
    SM_NOT_ASSIGNED,
    CategoryType,
    CoeDetails,
    FmmuUsage,
    GeneralFlags,
    MailboxProtocol,
    SiiCategory,
    SiiDc,
    SiiDcMode,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdoFlags,
    SiiPdos,
    SiiPortType,
    SiiRawCategory,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerEnable,
    SyncManagerType,
    build_sii,
    parse_sii,
)

__all__ = [
    "DEFAULT_EEPROM_BYTES",
    "FMMU_USAGES",
    "MAILBOX_PROTOCOLS",
    "PORT_LETTERS",
    "SM_TYPES",
    "SiiDifference",
    "SiiFromEsi",
    "esi_to_sii",
    "esi_to_sii_info",
    "sii_differences",
    "sii_image_from_file",
]

#: EEPROM size used when the ESI gives no ``ByteSize`` (16 Kbit, the common part).
DEFAULT_EEPROM_BYTES = 2048


# The ESI names <-> SII codes correspondences, one table each; esi/from_sii.py
# (SII -> ESI) and the simulator's ESI dictionary read them too.

#: ESI ``<Mailbox>`` element names and their protocol bit of SII word 0x1C.
MAILBOX_PROTOCOLS: dict[str, MailboxProtocol] = {
    "AoE": MailboxProtocol.AOE,
    "EoE": MailboxProtocol.EOE,
    "CoE": MailboxProtocol.COE,
    "FoE": MailboxProtocol.FOE,
    "SoE": MailboxProtocol.SOE,
    "VoE": MailboxProtocol.VOE,
}

#: ESI ``<Fmmu>`` text -> FMMU category byte.
FMMU_USAGES: dict[str, FmmuUsage] = {
    "Outputs": FmmuUsage.OUTPUTS,
    "Inputs": FmmuUsage.INPUTS,
    "MBoxState": FmmuUsage.MAILBOX_STATE,
}

#: ESI ``<Sm>`` role -> SII sync manager type.
SM_TYPES: dict[str, SyncManagerType] = {
    "MBoxOut": SyncManagerType.MAILBOX_OUT,
    "MBoxIn": SyncManagerType.MAILBOX_IN,
    "Outputs": SyncManagerType.OUTPUTS,
    "Inputs": SyncManagerType.INPUTS,
}

#: SII port type -> the Device@Physics letter written for it: Y = MII
#: (100BASE-TX), K = E-Bus (LVDS); an unused port is a space.
PORT_LETTERS: dict[int, str] = {SiiPortType.MII: "Y", SiiPortType.EBUS: "K"}

# Reading ESI names: any case; H is MII with fast hot connect.
_PROTOCOL_BITS = {k.lower(): v for k, v in MAILBOX_PROTOCOLS.items()}
_FMMU_USAGE = {k.lower(): v for k, v in FMMU_USAGES.items()}
_PHYSICS_PORT = {**{v: k for k, v in PORT_LETTERS.items()}, "H": SiiPortType.MII}


@dataclass
class SiiFromEsi:
    """Result of :func:`esi_to_sii`: the model, the image bytes and notes.

    ``notes`` tell what the generator decided that a reader may not expect
    (PDO categories left out because they do not fit, EEPROM size chosen).
    """

    info: SiiInfo
    image: bytes
    notes: list[str] = field(default_factory=list)


class _Strings:
    """String table being built: index 0 means "no string"; equal strings stored once."""

    def __init__(self) -> None:
        self.items: list[bytes] = []
        self._index: dict[bytes, int] = {}

    def add(self, text: str | None) -> int:
        if not text:
            return 0
        raw = text.encode("latin-1", errors="replace")[:255]
        found = self._index.get(raw)
        if found is not None:
            return found
        if len(self.items) >= 255:
            return 0  # the category holds at most 255 strings; further names stay unnamed
        self.items.append(raw)
        self._index[raw] = len(self.items)
        return len(self.items)


def _sm_type(sm: EsiSm) -> int:
    kind = sm.kind
    return SM_TYPES[kind] if kind is not None else SyncManagerType.UNUSED


def _sm_enable(sm: EsiSm) -> int:
    flags = SyncManagerEnable.NONE
    if sm.enable:
        flags |= SyncManagerEnable.ENABLE
    if sm.virtual:
        flags |= SyncManagerEnable.VIRTUAL
    if sm.op_only:
        flags |= SyncManagerEnable.OP_ONLY
    return int(flags)


def _fmmu_usage(device: EsiDevice, name: str, sm_index: int | None) -> int:
    """FMMU category byte for ``<Fmmu Sm=..>name</Fmmu>``.

    The standard names map directly. A vendor name (e.g. "OrbitaIn") is
    resolved through the SM or PDO of that name, or the ``Sm`` attribute:
    an FMMU that serves an output SM maps outputs, and so on.
    """
    key = name.strip()
    usage = _FMMU_USAGE.get(key.lower())
    if usage is not None:
        return int(usage)
    sm: EsiSm | None = None
    if sm_index is not None and 0 <= sm_index < len(device.sms):
        sm = device.sms[sm_index]
    if sm is None:
        sm = next((s for s in device.sms if s.name == key), None)
    if sm is None:
        pdo = next((p for p in device.pdos if p.name.pick() == key and p.sm is not None), None)
        if pdo is not None and pdo.sm is not None and pdo.sm < len(device.sms):
            sm = device.sms[pdo.sm]
    if sm is None or sm.kind is None:
        return int(FmmuUsage.UNUSED)
    return int({"Outputs": FmmuUsage.OUTPUTS, "Inputs": FmmuUsage.INPUTS,
                "MBoxIn": FmmuUsage.MAILBOX_STATE}.get(sm.kind, FmmuUsage.UNUSED))  # fmt: skip


def _ports(physics: str | None) -> int:
    value = 0
    for n, letter in enumerate((physics or "")[:4]):
        value |= int(_PHYSICS_PORT.get(letter.upper(), SiiPortType.NOT_USED)) << (4 * n)
    return value


def _coe_details(device: EsiDevice) -> CoeDetails:
    mbx = device.mailbox
    coe = mbx.coe if mbx is not None else None
    if coe is None:
        return CoeDetails.NONE
    d = CoeDetails.SDO
    if coe.sdo_info:
        d |= CoeDetails.SDO_INFO
    if coe.pdo_assign:
        d |= CoeDetails.PDO_ASSIGN
    if coe.pdo_config:
        d |= CoeDetails.PDO_CONFIG
    if coe.pdo_upload:
        d |= CoeDetails.UPLOAD_AT_STARTUP
    if coe.complete_access:
        d |= CoeDetails.SDO_COMPLETE_ACCESS
    return d


def _default_sms(device: EsiDevice) -> dict[int, int]:
    """PDO index -> SM it is assigned to by default (as ``pdo_layout`` decides)."""
    layout = device.pdo_layout()
    return {p.index: s.sm.index for s in layout.sms for p in s.pdos}


def _pdo_category(
    pdos: tuple[EsiPdo, ...], assigned: dict[int, int], ctype: int, strings: _Strings, lcid: int
) -> SiiPdos:
    out: list[SiiPdo] = []
    for p in pdos:
        flags = SiiPdoFlags.NONE
        if p.mandatory:
            flags |= SiiPdoFlags.MANDATORY
        if p.fixed:
            flags |= SiiPdoFlags.FIXED_CONTENT
        if p.virtual:
            flags |= SiiPdoFlags.VIRTUAL_CONTENT
        name_index = strings.add(p.name.pick(lcid))
        entries = []
        for e in p.entries:
            info = e.type_info
            entries.append(
                SiiPdoEntry(
                    index=e.index,
                    subindex=e.subindex,
                    name_index=0 if e.is_padding else strings.add(e.name.pick(lcid)),
                    data_type=int(info.code) & 0xFF if info is not None and not e.is_padding else 0,
                    bit_length=e.bit_len & 0xFF,
                )
            )
        out.append(
            SiiPdo(
                index=p.index,
                sync_manager=assigned.get(p.index, SM_NOT_ASSIGNED),
                dc_sync=0,
                name_index=name_index,
                flags=int(flags),
                entries=entries,
            )
        )
    return SiiPdos(type=ctype, pdos=out)


def _size_code(byte_size: int, where: str) -> int:
    kbit, rest = divmod(byte_size * 8, 1024)
    if rest or kbit < 1 or kbit > 0x10000:
        raise EsiError(
            f"Eeprom/ByteSize {byte_size} is not a whole number of Kbit between 1 and 65536", where
        )
    return kbit - 1


def esi_to_sii_info(
    device: EsiDevice,
    *,
    vendor_id: int,
    serial: int = 0,
    alias: int | None = None,
    include_pdos: bool | None = None,
    lcid: int = LCID_ENGLISH,
    notes: list[str] | None = None,
) -> SiiInfo:
    """The SII model of ``device`` (see the module text for the conventions).

    ``include_pdos``: True always writes the TxPDO/RxPDO categories (raising
    :class:`EsiError` if the image then exceeds ``ByteSize``), False never,
    None (default) writes them when they fit. ``alias`` overrides the station
    alias that ``ConfigData`` may carry. ``notes`` (if given) receives remarks.
    """
    where = str(device)
    note = notes if notes is not None else []
    eeprom = device.eeprom
    info = SiiInfo(
        vendor_id=vendor_id & 0xFFFFFFFF,
        product_code=device.product_code,
        revision=device.revision,
        serial=serial & 0xFFFFFFFF,
    )
    if eeprom is not None and eeprom.data:
        note.append("ESI gives the whole image (Eeprom/Data); used as is")
        return parse_sii(eeprom.data)
    config = (eeprom.config_data if eeprom is not None else None) or b""
    head = bytearray(14)
    head[: min(14, len(config))] = config[:14]
    info.pdi_control = int.from_bytes(head[0:2], "little")
    info.pdi_config = int.from_bytes(head[2:4], "little")
    info.sync_impulse_len = int.from_bytes(head[4:6], "little")
    info.pdi_config2 = int.from_bytes(head[6:8], "little")
    info.station_alias = int.from_bytes(head[8:10], "little")
    info.reserved_05 = bytes(head[10:14])
    if alias is not None:
        info.station_alias = alias & 0xFFFF
    boot = (eeprom.bootstrap if eeprom is not None else None) or b""
    if boot:
        if len(boot) < 8:
            raise EsiError(f"Eeprom/BootStrap has {len(boot)} bytes, 8 are needed", where)
        info.boot_rx_mailbox_offset = int.from_bytes(boot[0:2], "little")
        info.boot_rx_mailbox_size = int.from_bytes(boot[2:4], "little")
        info.boot_tx_mailbox_offset = int.from_bytes(boot[4:6], "little")
        info.boot_tx_mailbox_size = int.from_bytes(boot[6:8], "little")
    out_sm, in_sm = device.mbox_out, device.mbox_in
    sizes = device.mailbox_sizes
    if out_sm is not None and in_sm is not None and sizes is not None:
        info.rx_mailbox_offset = out_sm.start_address or 0
        info.tx_mailbox_offset = in_sm.start_address or 0
        info.rx_mailbox_size, info.tx_mailbox_size = sizes
    protocols = MailboxProtocol.NONE
    if device.mailbox is not None:
        for name in device.mailbox.protocols:
            protocols |= _PROTOCOL_BITS.get(name.lower(), MailboxProtocol.NONE)
    info.mailbox_protocols = protocols

    strings = _Strings()
    order_idx = strings.add(device.type_name.strip())
    group_idx = strings.add(device.group_type.strip() if device.group_type else None)
    name_idx = strings.add(device.name.pick(lcid).strip() or device.type_name.strip())
    mbx = device.mailbox
    general = SiiGeneral(
        group_index=group_idx,
        image_index=0,
        order_index=order_idx,
        name_index=name_idx,
        coe_details=_coe_details(device),
        foe_details=1 if mbx is not None and mbx.supports("FoE") else 0,
        eoe_details=1 if mbx is not None and mbx.supports("EoE") else 0,
        soe_channels=1 if mbx is not None and mbx.supports("SoE") else 0,
        ds402_channels=mbx.coe.ds402_channels if mbx is not None and mbx.coe is not None else 0,
        flags=GeneralFlags.MBOX_DATA_LINK_LAYER
        if mbx is not None and mbx.data_link_layer
        else GeneralFlags.NONE,
        ebus_current_ma=max(-32768, min(32767, device.info.ebus_current or 0)),
        # Byte 0x0E repeats the group index "for compatibility" (ETG.2010).
        reserved_0e=group_idx,
        physical_ports=_ports(device.physics),
    )
    usages = [_fmmu_usage(device, f.name, f.sm) for f in device.fmmus]
    if len(usages) % 2:
        usages.append(FmmuUsage.UNUSED)  # the category is sized in words
    fmmus = SiiFmmus(usages=usages)
    sms = SiiSyncManagers(
        sync_managers=[
            SiiSyncManager(
                start=s.start_address or 0,
                length=s.default_size or 0,
                control=s.control_byte or 0,
                status=0,
                enable=_sm_enable(s),
                sm_type=_sm_type(s),
            )
            for s in device.sms
        ]
    )
    # Strings used by the DC modes are added after the PDO names, so build the
    # PDO categories first (on a copy of the table when they may be dropped).
    pdo_strings = _copy(strings)
    pdo_cats: list[SiiCategory] = []
    assigned = _default_sms(device)
    if device.tx_pdos:
        pdo_cats.append(
            _pdo_category(device.tx_pdos, assigned, CategoryType.TXPDO, pdo_strings, lcid)
        )
    if device.rx_pdos:
        pdo_cats.append(
            _pdo_category(device.rx_pdos, assigned, CategoryType.RXPDO, pdo_strings, lcid)
        )

    def assemble(with_pdos: bool) -> SiiInfo:
        table = pdo_strings if with_pdos else _copy(strings)
        dc = _dc_category(device, table)
        cats: list[SiiCategory] = [SiiStrings(strings=list(table.items)), general]
        if fmmus.usages:
            cats.append(fmmus)
        if sms.sync_managers:
            cats.append(sms)
        if with_pdos:
            cats.extend(pdo_cats)
        if dc is not None:
            cats.append(dc)
        for number, data in eeprom.categories if eeprom is not None else ():
            cats.append(SiiRawCategory(type=number, data=data))
        result = SiiInfo(**{k: getattr(info, k) for k in _FIXED_FIELDS})
        result.categories = cats
        return result

    byte_size = eeprom.byte_size if eeprom is not None else None
    want = include_pdos if include_pdos is not None else True
    candidate = assemble(want and bool(pdo_cats))
    needed = _content_bytes(candidate)
    if byte_size is None:
        size = DEFAULT_EEPROM_BYTES
        while size < needed:
            size *= 2
        candidate.eeprom_size_code = _size_code(size, where)
        note.append(f"no Eeprom/ByteSize: EEPROM size {size} bytes")
        return candidate
    code = _size_code(byte_size, where)
    candidate.eeprom_size_code = code
    if needed <= byte_size:
        return candidate
    if include_pdos is None and pdo_cats:
        smaller = assemble(False)
        smaller.eeprom_size_code = code
        if _content_bytes(smaller) <= byte_size:
            note.append(
                f"PDO categories left out: with them the image needs {needed} bytes, "
                f"Eeprom/ByteSize is {byte_size}"
            )
            return smaller
    raise EsiError(f"the SII image needs {needed} bytes but Eeprom/ByteSize is {byte_size}", where)


_FIXED_FIELDS = (
    "pdi_control", "pdi_config", "sync_impulse_len", "pdi_config2", "station_alias",
    "reserved_05", "vendor_id", "product_code", "revision", "serial", "reserved_10",
    "boot_rx_mailbox_offset", "boot_rx_mailbox_size", "boot_tx_mailbox_offset",
    "boot_tx_mailbox_size", "rx_mailbox_offset", "rx_mailbox_size", "tx_mailbox_offset",
    "tx_mailbox_size", "mailbox_protocols", "reserved_1d", "eeprom_size_code", "version",
)  # fmt: skip


def _copy(table: _Strings) -> _Strings:
    new = _Strings()
    new.items = list(table.items)
    new._index = dict(table._index)
    return new


def _content_bytes(info: SiiInfo) -> int:
    """Bytes the image occupies up to and including the end marker."""
    try:
        return len(build_sii(info, pad=False))
    except SiiError as exc:
        raise EsiError(f"cannot encode the SII image: {exc}") from exc


def _dc_category(device: EsiDevice, strings: _Strings) -> SiiDc | None:
    if device.dc is None or not device.dc.op_modes:
        return None
    modes = []
    for m in device.dc.op_modes:
        modes.append(
            SiiDcMode(
                cycle_time_sync0=(m.cycle_time_sync0 or 0) & 0xFFFFFFFF,
                shift_time_sync0=_i32(m.shift_time_sync0 or 0),
                shift_time_sync1=_i32(m.shift_time_sync1 or 0),
                sync1_cycle_factor=_i16(m.cycle_time_sync1_factor or 0),
                assign_activate=m.assign_activate & 0xFFFF,
                sync0_cycle_factor=_i16(m.cycle_time_sync0_factor or 0),
                name_index=strings.add(m.name),
                description_index=strings.add(m.desc),
            )
        )
    return SiiDc(modes=modes)


def _i32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


def _i16(v: int) -> int:
    v &= 0xFFFF
    return v - (1 << 16) if v & 0x8000 else v


def esi_to_sii(
    device: EsiDevice,
    *,
    vendor_id: int,
    serial: int = 0,
    alias: int | None = None,
    include_pdos: bool | None = None,
    lcid: int = LCID_ENGLISH,
) -> SiiFromEsi:
    """Model, image bytes (padded with 0xFF to the EEPROM size) and notes for ``device``."""
    notes: list[str] = []
    info = esi_to_sii_info(
        device,
        vendor_id=vendor_id,
        serial=serial,
        alias=alias,
        include_pdos=include_pdos,
        lcid=lcid,
        notes=notes,
    )
    try:
        image = build_sii(info)
    except SiiError as exc:
        raise EsiError(f"cannot encode the SII image: {exc}", str(device)) from exc
    return SiiFromEsi(info=info, image=image, notes=notes)


def sii_image_from_file(
    path: str | os.PathLike[str],
    *,
    product: int | None = None,
    revision: int | None = None,
    serial: int = 0,
) -> bytes:
    """SII image of device ``product`` (rev ``revision``; default highest) of an ESI file.

    Without ``product`` the file must describe exactly one product.
    """
    esi = load_esi(path)
    device = pick_device(esi, product, revision)
    return esi_to_sii(device, vendor_id=esi.vendor.id, serial=serial).image


def pick_device(esi: EsiFile, product: int | None, revision: int | None) -> EsiDevice:
    """The device of an :class:`EsiFile` chosen by product code / revision.

    With no product code the file must hold one product (any number of revisions).
    """
    if product is None:
        products = sorted({d.product_code for d in esi.devices})
        if len(products) != 1:
            listed = ", ".join(f"0x{p:08X}" for p in products[:10])
            raise EsiError(
                f"the file describes {len(products)} products ({listed}"
                f"{', ...' if len(products) > 10 else ''}); choose one with a product code",
                esi.source,
            )
        product = products[0]
    return esi.find_device(product, revision)


# --- comparing two images -----------------------------------------------------------------


@dataclass(frozen=True)
class SiiDifference:
    """One field that differs between two SII images (``a`` vs ``b``)."""

    field: str
    a: object
    b: object

    def __str__(self) -> str:
        return f"{self.field}: {self.a!r} != {self.b!r}"


def _pdo_view(info: SiiInfo, pdo: SiiPdo) -> dict[str, object]:
    return {
        "sm": pdo.sync_manager,
        "flags": pdo.flags,
        "name": info.pdo_name(pdo),
        "entries": [
            (e.index, e.subindex, e.bit_length, e.data_type, info.pdo_name(e) if e.index else None)
            for e in pdo.entries
        ],
    }


def _fmmu_view(usages: list[int]) -> list[int]:
    out = list(usages)
    while out and out[-1] in (FmmuUsage.UNUSED, FmmuUsage.NOT_USED):
        out.pop()  # the category is word-sized: a trailing unused byte is padding
    return out


def sii_differences(a: SiiInfo, b: SiiInfo) -> list[SiiDifference]:
    """Every content difference between images ``a`` and ``b``, field by field.

    Field names: fixed-area attribute names (``vendor_id``, ``pdi_control``,
    ``rx_mailbox_size``, ``eeprom_size_code`` ...), ``sm[N].<attr>`` / ``sm.count``,
    ``fmmu``, ``txpdo[0x1A00].<part>`` / ``rxpdo[...]`` / ``txpdo.indices``,
    ``dc[N].<attr>`` / ``dc.count``, ``general.<attr>`` (names resolved through
    the strings). String-table layout itself is not compared, only what it names.
    """
    diffs: list[SiiDifference] = []

    def cmp(name: str, x: object, y: object) -> None:
        if x != y:
            diffs.append(SiiDifference(name, x, y))

    for name in _FIXED_FIELDS:
        if name in ("reserved_10", "reserved_1d"):
            continue
        cmp(name, getattr(a, name), getattr(b, name))
    sa, sb = a.sync_managers, b.sync_managers
    cmp("sm.count", len(sa), len(sb))
    for i, (sx, sy) in enumerate(zip(sa, sb, strict=False)):
        for attr in ("start", "length", "control", "status", "enable", "sm_type"):
            cmp(f"sm[{i}].{attr}", getattr(sx, attr), getattr(sy, attr))
    cmp("fmmu", _fmmu_view(a.fmmus), _fmmu_view(b.fmmus))
    for kind, pa, pb in (("txpdo", a.tx_pdos, b.tx_pdos), ("rxpdo", a.rx_pdos, b.rx_pdos)):
        ia = [p.index for p in pa]
        ib = [p.index for p in pb]
        cmp(f"{kind}.indices", ia, ib)
        mb = {p.index: p for p in pb}
        for p in pa:
            q = mb.get(p.index)
            if q is None:
                continue
            va, vb = _pdo_view(a, p), _pdo_view(b, q)
            for part in va:
                cmp(f"{kind}[0x{p.index:04X}].{part}", va[part], vb[part])
    da, db = a.dc_modes, b.dc_modes
    cmp("dc.count", len(da), len(db))
    for i, (x, y) in enumerate(zip(da, db, strict=False)):
        for attr in (
            "cycle_time_sync0", "shift_time_sync0", "shift_time_sync1",
            "sync1_cycle_factor", "assign_activate", "sync0_cycle_factor",
        ):  # fmt: skip
            cmp(f"dc[{i}].{attr}", getattr(x, attr), getattr(y, attr))
        cmp(f"dc[{i}].name", a.string(x.name_index), b.string(y.name_index))
        cmp(f"dc[{i}].description", a.string(x.description_index), b.string(y.description_index))
    ga, gb = a.general, b.general
    if (ga is None) != (gb is None):
        cmp("general", ga is not None, gb is not None)
    elif ga is not None and gb is not None:
        cmp("general.name", a.device_name, b.device_name)
        cmp("general.order", a.order_number, b.order_number)
        cmp("general.group", a.group_name, b.group_name)
        cmp("general.group_compat", a.string(ga.reserved_0e), b.string(gb.reserved_0e))
        for attr in (
            "reserved_04", "coe_details", "foe_details", "eoe_details", "soe_channels", "ds402_channels",
            "sysman_class", "flags", "ebus_current_ma", "physical_ports",
            "physical_memory_address",
        ):  # fmt: skip
            cmp(f"general.{attr}", int(getattr(ga, attr)), int(getattr(gb, attr)))
    return diffs
