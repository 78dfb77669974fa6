"""Built-in simulated devices: a coupler and four small IO terminals.

Each built-in is described by a :class:`BuiltinDevice` (identity, ports, sync
managers, FMMUs, PDOs) from which a complete SII EEPROM image is generated
with :func:`pyethercat.wire.sii.build_sii`. A master reading that EEPROM sees
an ordinary EtherCAT slave: strings, General, FMMU, SyncM and TxPDO/RxPDO
categories, a correct header checksum.

Identity. The built-ins carry the vendor id :data:`VENDOR_ID` (0x00504543, the
ASCII letters "PEC"), a number chosen here because it is far above the range
the EtherCAT Technology Group hands out; it belongs to nobody, so no master
mistakes a simulated terminal for a real product.

Layout, modelled on Beckhoff's mailbox-less EL1xxx/EL2xxx terminals: the
digital terminals have no mailbox, and their only process-data sync manager
is SM0 (inputs: 0x1000, buffered, ECAT reads; outputs: buffered, ECAT writes,
watchdog on). A real EL2004 places its outputs at 0x0F00 (the ESC's digital
output register); the built-in ``do8`` uses process RAM at 0x1000 instead, so
it works on every ESC profile; the EL2004 built from its corpus SII dump keeps
0x0F00. ``ai2`` is modelled on an EL31xx: it has a standard mailbox (SM0/SM1,
no mailbox protocol yet, so masters read its PDOs from the SII), SM2 for
outputs (none) and SM3 for its two 16-bit inputs.

Behaviour. Plain IO terminals need no Python per frame and have no device
model: inputs are set by the segment's wiring (:meth:`Segment.wire`) or by
test code through the PDI, outputs are read from the SM buffer. A kind with
behaviour names a device model (``model``, ``sim.model.DeviceModel``); the
kinds are found through ``sim.devices.registry``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pyethercat.wire import registers as R
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.sii import (
    CoeDetails,
    FmmuUsage,
    MailboxProtocol,
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
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerType,
    build_sii,
)
from pyethercat.wire.sii.model import CategoryType

if TYPE_CHECKING:
    from pyethercat.sim.model import DeviceModel

__all__ = [
    "VENDOR_ID",
    "BuiltinDevice",
    "BuiltinPdo",
    "BuiltinPdoEntry",
    "BuiltinSm",
    "io_devices",
]

#: Vendor id of every built-in device ("PEC" in ASCII; not an assigned ETG id).
VENDOR_ID = 0x00504543
#: Revision number of the current built-in device generation.
REVISION = 0x00010000

# CoE basic data type codes (SOEM ec_type.h ec_datatype) used by the built-in PDO entries.
_BOOL = int(DataType.BOOLEAN)
_INT16 = int(DataType.INTEGER16)

# Sync manager control bytes of the plain IO terminals (SOES esc.h _ESCsm); the
# mailbox device uses the register map's typical SM0-SM3 bytes.
_SM_CTRL_INPUTS_IO = R.sm_control(R.SmMode.BUFFERED, R.SmDirection.READ, al_event=False)  # EL1xxx: 0x00
_SM_CTRL_OUTPUTS_IO = R.sm_control(R.SmMode.BUFFERED, R.SmDirection.WRITE, al_event=False,
                                   watchdog=True)  # EL2xxx: 0x44

# SII fixed-area word 0: low byte PDI type, high byte ESC configuration
# (0x0141). Built-ins run a state machine of their own (no device emulation);
# bits 2/3 enable the DC SYNC-out and latch-in units (Wireshark ecat_esc_reg_141), as the
# EK1100's image does (0x0D00: device emulation + SYNC-out + latch-in).
_PDI_CONTROL_IO = 0x0C04  # PDI type 4: digital I/O
_PDI_CONTROL_NONE = 0x0C00


@dataclass(frozen=True)
class BuiltinPdoEntry:
    """One PDO entry: object index/subindex, bit length, name, CoE type code."""

    index: int
    subindex: int
    bits: int
    name: str
    data_type: int = _BOOL


@dataclass(frozen=True)
class BuiltinPdo:
    """One fixed PDO assigned to sync manager ``sm``."""

    index: int
    sm: int
    name: str
    entries: tuple[BuiltinPdoEntry, ...]

    @property
    def bits(self) -> int:
        """Sum of the entries' bit lengths."""
        return sum(e.bits for e in self.entries)


@dataclass(frozen=True)
class BuiltinSm:
    """One sync manager as the SII describes it (start, length, control, type)."""

    start: int
    length: int
    control: int
    sm_type: SyncManagerType
    enable: int = 0x01


@dataclass(frozen=True)
class BuiltinDevice:
    """Static description of one built-in device type."""

    key: str  # "di8": the name after "builtin:" in a topology file
    product_code: int
    order: str  # order number string, e.g. "PEC-DI8" (string 1: SOEM's slave name)
    name: str  # device name string (what SOEM shows as the slave name)
    group: str
    profile: str  # default ESC profile (sim.esc.PROFILES key)
    ports: tuple[SiiPortType, SiiPortType, SiiPortType, SiiPortType]
    sync_managers: tuple[BuiltinSm, ...]
    fmmus: tuple[FmmuUsage, ...]
    tx_pdos: tuple[BuiltinPdo, ...] = ()
    rx_pdos: tuple[BuiltinPdo, ...] = ()
    mailbox: tuple[int, int, int, int] | None = None  # rx offset/size, tx offset/size
    ebus_current_ma: int = 0
    pdi_control: int = _PDI_CONTROL_IO
    description: str = ""
    # Devices with a mailbox protocol (sim.devices.coe_io): SII CoE details and
    # protocols, their own identity.
    coe_details: int = 0
    mailbox_protocols: int = 0
    vendor_id: int = VENDOR_ID
    revision: int = REVISION
    # DC op modes in the SII (ESI <Dc><OpMode>): "SM-Synchron" (no SYNC pulses)
    # and "DC-Synchron" (AssignActivate 0x0300, SYNC0), as Beckhoff terminals with
    # a DC mode list them.
    dc_modes: bool = False
    #: Makes the device model of the kind for one segment (None: no behaviour;
    #: a kind with a mailbox but no model answers "protocol not supported").
    model: Callable[[], DeviceModel] | None = None

    @property
    def input_bits(self) -> int:
        """Bits of input process data (TxPDOs, slave -> master)."""
        return sum(p.bits for p in self.tx_pdos)

    @property
    def output_bits(self) -> int:
        """Bits of output process data (RxPDOs, master -> slave)."""
        return sum(p.bits for p in self.rx_pdos)

    @property
    def input_bytes(self) -> int:
        """Bytes of the input sync manager buffer."""
        return (self.input_bits + 7) // 8

    @property
    def output_bytes(self) -> int:
        """Bytes of the output sync manager buffer."""
        return (self.output_bits + 7) // 8

    def sii_info(self, serial: int = 0, alias: int = 0) -> SiiInfo:
        """The SII content of this device as a typed model."""
        strings: list[bytes] = []

        def intern(text: str) -> int:
            raw = text.encode("latin-1")
            if raw not in strings:
                strings.append(raw)
            return strings.index(raw) + 1

        # String 1 is the order number, as in Beckhoff's images: SOEM takes
        # string 1 as the slave's name, whatever the General name index says.
        order_i = intern(self.order)
        group_i = intern(self.group)
        name_i = intern(self.name)

        def sii_pdos(ctype: int, pdos: tuple[BuiltinPdo, ...]) -> SiiPdos:
            out = SiiPdos(type=ctype)
            for pdo in pdos:
                entries = [
                    SiiPdoEntry(
                        index=e.index,
                        subindex=e.subindex,
                        name_index=intern(e.name),
                        data_type=e.data_type,
                        bit_length=e.bits,
                    )
                    for e in pdo.entries
                ]
                # Mandatory + fixed content (0x0011), as Beckhoff images carry.
                out.pdos.append(
                    SiiPdo(
                        index=pdo.index,
                        sync_manager=pdo.sm,
                        name_index=intern(pdo.name),
                        flags=SiiPdoFlags.MANDATORY | SiiPdoFlags.FIXED_CONTENT,
                        entries=entries,
                    )
                )
            return out

        tx = sii_pdos(CategoryType.TXPDO, self.tx_pdos)
        rx = sii_pdos(CategoryType.RXPDO, self.rx_pdos)
        physical_ports = 0
        for i, p in enumerate(self.ports):
            physical_ports |= int(p) << (4 * i)
        general = SiiGeneral(
            group_index=group_i,
            order_index=order_i,
            name_index=name_i,
            coe_details=CoeDetails(self.coe_details),
            ebus_current_ma=self.ebus_current_ma,
            physical_ports=physical_ports,
        )
        sms = SiiSyncManagers(
            sync_managers=[
                SiiSyncManager(
                    start=s.start,
                    length=s.length,
                    control=s.control,
                    enable=s.enable,
                    sm_type=s.sm_type,
                )
                for s in self.sync_managers
            ]
        )
        categories: list[object] = [SiiStrings(strings=strings), general]
        if self.fmmus:
            categories.append(SiiFmmus(usages=[int(u) for u in self.fmmus]))
        if self.sync_managers:
            categories.append(sms)
        if self.tx_pdos:
            categories.append(tx)
        if self.rx_pdos:
            categories.append(rx)
        if self.dc_modes:
            categories.append(SiiDc(modes=[
                SiiDcMode(assign_activate=0, name_index=intern("SM-Synchron"),
                          description_index=intern("SM-Synchron")),
                SiiDcMode(assign_activate=0x0300, name_index=intern("DC-Synchron"),
                          description_index=intern("DC-Synchron")),
            ]))
        info = SiiInfo(
            pdi_control=self.pdi_control,
            station_alias=alias,
            vendor_id=self.vendor_id,
            product_code=self.product_code,
            revision=self.revision,
            serial=serial,
            eeprom_size_code=0x000F,  # 2 KiB (16 Kbit), like EL/EK terminals
            version=1,
        )
        if self.mailbox is not None:
            rx_off, rx_size, tx_off, tx_size = self.mailbox
            info.rx_mailbox_offset, info.rx_mailbox_size = rx_off, rx_size
            info.tx_mailbox_offset, info.tx_mailbox_size = tx_off, tx_size
            info.boot_rx_mailbox_offset, info.boot_rx_mailbox_size = rx_off, rx_size
            info.boot_tx_mailbox_offset, info.boot_tx_mailbox_size = tx_off, tx_size
            info.mailbox_protocols = MailboxProtocol(self.mailbox_protocols)
        info.categories = categories  # type: ignore[assignment]
        return info

    def sii_image(self, serial: int = 0, alias: int = 0) -> bytes:
        """The EEPROM image bytes (checksum set, padded with 0xFF to 2 KiB).

        Built once per alias, then the serial number is put in: a segment of
        thousands of one kind builds one image (the serial, words 0x0E-0x0F,
        lies outside the checksummed words 0-6)."""
        images: dict[int, bytes] = self.__dict__.setdefault("_sii_images", {})
        image = images.get(alias)
        if image is None:
            image = images[alias] = build_sii(self.sii_info(serial=0, alias=alias))
        return with_serial(image, serial)


def with_serial(image: bytes, serial: int) -> bytes:
    """``image`` with SII words 0x0E-0x0F (the serial number) set to ``serial``."""
    return image[:_SERIAL] + (serial & 0xFFFFFFFF).to_bytes(4, "little") + image[_SERIAL + 4:]


#: Byte offset of the serial number in an SII image (word 0x0E).
_SERIAL = 0x1C


def _bits(prefix: int, count: int, name: str, sm: int, obj_base: int) -> tuple[BuiltinPdo, ...]:
    """``count`` one-bit channel PDOs (Beckhoff style: one PDO per channel)."""
    return tuple(
        BuiltinPdo(
            index=prefix + ch,
            sm=sm,
            name=f"Channel {ch + 1}",
            entries=(BuiltinPdoEntry(obj_base + 0x10 * ch, 1, 1, name),),
        )
        for ch in range(count)
    )


_EBUS2 = (SiiPortType.EBUS, SiiPortType.EBUS, SiiPortType.NOT_USED, SiiPortType.NOT_USED)

COUPLER = BuiltinDevice(
    key="coupler",
    product_code=0x00010004,
    order="PEC-CU4",
    name="PEC-CU4 EtherCAT coupler, 4 ports",
    group="Coupler",
    profile="ET1100",
    # Port 0 in (MII), port 1 to the terminals (E-Bus), ports 2 and 3 out
    # (MII): a branch can hang off port 3 or port 2.
    ports=(SiiPortType.MII, SiiPortType.EBUS, SiiPortType.MII, SiiPortType.MII),
    sync_managers=(),
    fmmus=(),
    ebus_current_ma=-2000,  # feeds the E-Bus
    pdi_control=_PDI_CONTROL_NONE,
    description="coupler without process data, 4 ports (0 in, 1 E-Bus, 2 and 3 out)",
)

DI8 = BuiltinDevice(
    key="di8",
    product_code=0x00020008,
    order="PEC-DI8",
    name="PEC-DI8 8Ch. digital input",
    group="DigIn",
    profile="ET1200",
    ports=_EBUS2,
    sync_managers=(BuiltinSm(0x1000, 1, _SM_CTRL_INPUTS_IO, SyncManagerType.INPUTS),),
    fmmus=(FmmuUsage.INPUTS, FmmuUsage.NOT_USED),
    tx_pdos=_bits(0x1A00, 8, "Input", 0, 0x6000),
    ebus_current_ma=90,
    dc_modes=True,
    description="8 digital inputs, 1 byte, TxPDOs 0x1A00-0x1A07 (0x6000+0x10*ch:01, BOOL)",
)

DO8 = BuiltinDevice(
    key="do8",
    product_code=0x00030008,
    order="PEC-DO8",
    name="PEC-DO8 8Ch. digital output",
    group="DigOut",
    profile="ET1200",
    ports=_EBUS2,
    sync_managers=(BuiltinSm(0x1000, 1, _SM_CTRL_OUTPUTS_IO, SyncManagerType.OUTPUTS),),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.NOT_USED),
    rx_pdos=_bits(0x1600, 8, "Output", 0, 0x7000),
    ebus_current_ma=110,
    dc_modes=True,
    description="8 digital outputs, 1 byte, RxPDOs 0x1600-0x1607 (0x7000+0x10*ch:01, BOOL)",
)

DI2 = BuiltinDevice(
    key="di2",
    product_code=0x00020002,
    order="PEC-DI2",
    name="PEC-DI2 2Ch. digital input",
    group="DigIn",
    profile="ET1200",
    ports=_EBUS2,
    sync_managers=(BuiltinSm(0x1000, 1, _SM_CTRL_INPUTS_IO, SyncManagerType.INPUTS),),
    fmmus=(FmmuUsage.INPUTS, FmmuUsage.NOT_USED),
    tx_pdos=_bits(0x1A00, 2, "Input", 0, 0x6000),
    ebus_current_ma=90,
    dc_modes=True,
    description="2 digital inputs (2 bits: masters map it with a bit-wise FMMU)",
)

AI2 = BuiltinDevice(
    key="ai2",
    product_code=0x00040002,
    order="PEC-AI2",
    name="PEC-AI2 2Ch. analog input 16 bit",
    group="AnaIn",
    profile="ET1200",
    ports=_EBUS2,
    sync_managers=(
        BuiltinSm(0x1000, 128, R.SM_CONTROL_MAILBOX_OUT, SyncManagerType.MAILBOX_OUT),
        BuiltinSm(0x1080, 128, R.SM_CONTROL_MAILBOX_IN, SyncManagerType.MAILBOX_IN),
        BuiltinSm(0x1100, 0, R.SM_CONTROL_OUTPUTS, SyncManagerType.OUTPUTS, enable=0x00),
        BuiltinSm(0x1180, 4, R.SM_CONTROL_INPUTS, SyncManagerType.INPUTS),
    ),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.INPUTS, FmmuUsage.MAILBOX_STATE),
    tx_pdos=(
        BuiltinPdo(0x1A00, 3, "AI Channel 1", (BuiltinPdoEntry(0x6000, 0x11, 16, "Value", _INT16),)),
        BuiltinPdo(0x1A01, 3, "AI Channel 2", (BuiltinPdoEntry(0x6010, 0x11, 16, "Value", _INT16),)),
    ),
    mailbox=(0x1000, 128, 0x1080, 128),
    ebus_current_ma=130,
    dc_modes=True,
    description="2 analog inputs, INT16 each (4 bytes), standard mailbox SM0/SM1, inputs on SM3",
)

def io_devices() -> tuple[BuiltinDevice, ...]:
    """The IO kinds of this module (a provider of ``sim.devices.registry``)."""
    return (COUPLER, DI8, DO8, DI2, AI2)
