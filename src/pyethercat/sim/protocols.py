"""Adding FoE and SoE servers to a simulated slave, as its SII and the topology say.

A slave serves FoE when its SII announces FoE in the mailbox protocol word
(0x1C) - so every ESI device that lists ``<FoE/>`` does - unless the topology
turns it off; the same for SoE. ``foe = true`` / ``soe = true`` in the
topology add them to a device whose SII does not announce them (the SII is
not changed: a master that trusts the SII will not try). A slave with a
bootstrap mailbox in its SII (words 0x14-0x17) also gets a bootloader: in BOOT
its FoE server takes firmware images (:mod:`pyethercat.sim.firmware`), and on
BOOT -> INIT the device restarts with the new revision in its SII and, for a
CoE device, in 0x1018:03 and 0x100A.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pyethercat.errors import ConfigError
from pyethercat.sim.coe import CoeServer
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.firmware import FirmwareImage, FirmwareSlot
from pyethercat.sim.foe import FoeOptions, FoeProtocol
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.soe import SoeProtocol
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.mailbox.objects import IdentitySub, StandardObject
from pyethercat.wire.sii import MailboxProtocol, SiiInfo
from pyethercat.wire.sii.model import WORD_REVISION

__all__ = ["MailboxOptions", "ProtocolDevice", "add_mailbox_protocols", "apply_firmware"]


@dataclass
class MailboxOptions:
    """Mailbox protocol settings of one slave from the topology file.

    ``foe``/``soe`` None: as the SII announces. ``foe_options`` tunes the FoE
    server (directory, password, BUSY schedule, packet wrap).
    """

    foe: bool | None = None
    soe: bool | None = None
    foe_options: FoeOptions = field(default_factory=FoeOptions)


class ProtocolDevice(MailboxDevice):
    """A device with a mailbox whose protocols are all added servers (no CoE of its own)."""


def add_mailbox_protocols(app: DeviceApp | None, info: SiiInfo,
                          options: MailboxOptions | None = None, *,
                          where: str = "slave") -> DeviceApp | None:
    """``app`` with FoE/SoE servers added as ``info`` and ``options`` ask (maybe a new app).

    No application, or one answering every request with "protocol not
    supported", is replaced by a :class:`ProtocolDevice`; any other app that is
    no :class:`MailboxDevice` cannot take servers (:class:`ConfigError`).
    """
    opts = options if options is not None else MailboxOptions()
    announced = info.mailbox_protocols
    foe = bool(announced & MailboxProtocol.FOE) if opts.foe is None else opts.foe
    soe = bool(announced & MailboxProtocol.SOE) if opts.soe is None else opts.soe
    if not foe and not soe:
        return app
    if not (info.rx_mailbox_size and info.tx_mailbox_size):
        raise ConfigError(f"{where}: FoE/SoE need a mailbox, the SII describes none")
    if not isinstance(app, MailboxDevice):
        from pyethercat.sim.devices import MailboxErrorApp

        if app is not None and type(app) not in (MailboxErrorApp, DeviceApp):
            raise ConfigError(f"{where}: the device application {type(app).__name__} has no "
                              "mailbox engine to add FoE/SoE to")
        app = ProtocolDevice()
    device = app
    if foe:
        firmware = None
        if info.boot_rx_mailbox_size and info.boot_tx_mailbox_size:
            firmware = FirmwareSlot(info.vendor_id, info.product_code,
                                    password=opts.foe_options.firmware_password)
        device.add_protocol(FoeProtocol(
            device.sender(MailboxType.FOE), device.al_state, device.mailbox_sizes,
            options=opts.foe_options, firmware=firmware,
            on_firmware=lambda image: apply_firmware(device, image)))
    if soe:
        device.add_protocol(SoeProtocol(device.sender(MailboxType.SOE), device.al_state,
                                        lambda: device.mailbox_sizes()[1]))
    return device


def apply_firmware(app: MailboxDevice, image: FirmwareImage) -> None:
    """The device restarts with ``image``: its revision and version become visible."""
    if app.pdi is not None:
        app.pdi.write_sii(WORD_REVISION, image.revision.to_bytes(4, "little"))
    coe = app.protocols.get(MailboxType.COE)
    if isinstance(coe, CoeServer):
        od = coe.od
        ident = od.find(StandardObject.IDENTITY)
        if ident is not None and IdentitySub.REVISION in ident.entries:
            ident.entries[IdentitySub.REVISION].raw[:] = image.revision.to_bytes(4, "little")
        version = od.find(StandardObject.SOFTWARE_VERSION)
        if version is None:
            od.var(StandardObject.SOFTWARE_VERSION, "Manufacturer software version",
                   DataType.VISIBLE_STRING, default=image.version)
        else:
            entry = version.entries[0]
            entry.raw = bytearray(image.version.encode("utf-8"))
            entry.max_length = max(entry.max_length or 0, len(entry.raw))
