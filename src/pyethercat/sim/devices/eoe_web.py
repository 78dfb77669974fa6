"""``builtin:eoe-web``: a small EoE device that serves its diagnostic page.

A mailbox device speaking EoE only, with 1024-byte mailboxes as a
Kollmorgen AKD drive (an EoE device with a web interface; its SII is in the
shared corpus) has them, and no process data. Its IP side is a Python echo
stack by default, or the Linux kernel in a network namespace of its own when
the topology gives ``eoe = { netns = "pyecat-..." }`` (root); there it
serves the page of :mod:`pyethercat.sim.eoe_web` on port 80.

:func:`device_status` builds that page's content for any simulated device
(this one and the ``seed002-drive``).
"""

from __future__ import annotations

import ipaddress
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

from pyethercat.sim.device import DeviceApp
from pyethercat.sim.devices.builtin import BuiltinDevice, BuiltinSm
from pyethercat.sim.eoe import EoeServer, attach_eoe, eoe_server
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.model import DeviceModel
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, al_status_code_name
from pyethercat.wire.sii import FmmuUsage, MailboxProtocol, SiiInfo, SiiPortType, SyncManagerType

__all__ = ["EOE_WEB", "EoeWebModel", "device_status", "eoe_devices"]

_MBX_SIZE = 1024
_MII2 = (SiiPortType.MII, SiiPortType.MII, SiiPortType.NOT_USED, SiiPortType.NOT_USED)


def device_status(app: Any, info: SiiInfo, started: float, *, kind: str,
                  temperatures: Sequence[tuple[str, float, float, float]],
                  live: Callable[[float], list[tuple[str, Any]]],
                  errors: Sequence[str] = ()) -> dict[str, Any]:
    """What the diagnostic page shows about ``app`` (a device application).

    ``temperatures`` are (label, mean, swing, period s): a slow sine around
    the mean; ``live(uptime_s)`` gives the live values, the first one shown
    large.
    """
    t = time.monotonic() - started
    pdi = app.pdi
    state = pdi.al_state() if pdi is not None else AlState.INIT
    status = int.from_bytes(pdi.read(R.AL_STATUS, 2), "little") if pdi is not None else 0
    code = int.from_bytes(pdi.read(R.AL_STATUS_CODE, 2), "little") if pdi is not None else 0
    errs = list(errors)
    if status & R.AL_ERROR_FLAG or code:
        errs.insert(0, f"AL status code 0x{code:04X}: {al_status_code_name(code)}")
    server: EoeServer | None = eoe_server(app)
    network: list[tuple[str, Any]] = []
    if server is not None:
        p = server.endpoint.parameters()
        prefix = ipaddress.IPv4Network(f"0.0.0.0/{p.subnet}").prefixlen if p.subnet else 32
        network = [("IP address", f"{p.ip}/{prefix}" if p.ip else "not set"),
                   ("MAC address", p.mac.hex(":") if p.mac else "-"),
                   ("Gateway", str(p.gateway or "-")),
                   ("EoE frames in / out", f"{server.receiver.stats.frames} / "
                                           f"{server.sender.stats.frames}")]
    return {
        "name": info.device_name or "EtherCAT device",
        "kind": kind,
        "identity": [("Vendor ID", f"0x{info.vendor_id:08X}"),
                     ("Product code", f"0x{info.product_code:08X}"),
                     ("Revision", f"0x{info.revision:08X}"),
                     ("Serial number", f"{info.serial}"),
                     ("Order number", info.order_number or "-")],
        "state": state.name,
        "state_ok": state in (AlState.OP, AlState.SAFEOP, AlState.PREOP)
        and not status & R.AL_ERROR_FLAG,
        "temperatures": [(label, mean + swing * math.sin(2 * math.pi * t / period))
                         for label, mean, swing, period in temperatures],
        "errors": errs,
        "live": live(t),
        "network": network,
    }


class EoeWebModel(DeviceModel):
    """``builtin:eoe-web``: EoE only; its page's live value is its EoE frame counter."""

    def instance_app(self, info: SiiInfo) -> tuple[int, DeviceApp | None]:
        instance = self.new_instance()
        app = MailboxDevice()
        started = time.monotonic()

        def status() -> dict[str, Any]:
            server = eoe_server(app)
            rx = server.receiver.stats if server is not None else None
            tx = server.sender.stats if server is not None else None
            # The device's own counters (every page load moves them), not a clock.
            return device_status(
                app, info, started, kind="EoE test device",
                temperatures=(("Board", 38.0, 3.0, 60.0), ("CPU", 52.0, 6.0, 23.0)),
                live=lambda t: [("EoE frames received", rx.frames if rx else 0),
                                ("EoE bytes received", rx.bytes if rx else 0),
                                ("EoE frames sent", tx.frames if tx else 0),
                                ("EoE frames discarded", rx.dropped if rx else 0),
                                ("Uptime", f"{t:.1f} s")])

        attach_eoe(app, info.tx_mailbox_size or _MBX_SIZE, info.serial, status)
        return instance, app


EOE_WEB = BuiltinDevice(
    key="eoe-web",
    product_code=0x00050001,
    order="PEC-EOE-WEB",
    name="PEC-EOE web device",
    group="Communication",
    profile="IPCORE",
    ports=_MII2,
    sync_managers=(
        BuiltinSm(0x1000, _MBX_SIZE, R.SM_CONTROL_MAILBOX_OUT, SyncManagerType.MAILBOX_OUT),
        BuiltinSm(0x1400, _MBX_SIZE, R.SM_CONTROL_MAILBOX_IN, SyncManagerType.MAILBOX_IN),
        BuiltinSm(0x1800, 0, R.SM_CONTROL_OUTPUTS, SyncManagerType.OUTPUTS, enable=0x00),
        BuiltinSm(0x1C00, 0, R.SM_CONTROL_INPUTS, SyncManagerType.INPUTS, enable=0x00),
    ),
    fmmus=(FmmuUsage.OUTPUTS, FmmuUsage.INPUTS, FmmuUsage.MAILBOX_STATE),
    mailbox=(0x1000, _MBX_SIZE, 0x1400, _MBX_SIZE),
    pdi_control=0x0C05,
    description="EoE only (1024-byte mailboxes, no process data): echo IP stack, or a "
                "kernel stack with a diagnostic web page in a pyecat- network namespace",
    mailbox_protocols=int(MailboxProtocol.EOE),
    model=EoeWebModel,
)


def eoe_devices() -> tuple[BuiltinDevice, ...]:
    """The EoE kinds of this module (a provider of ``sim.devices.registry``)."""
    return (EOE_WEB,)
