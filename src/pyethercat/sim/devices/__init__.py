"""Device kinds of simulated slaves: the built-in catalogue and what a slave runs.

:data:`DEVICES` (``sim.devices.registry``) holds the kinds a topology file
names as ``device = "builtin:<key>"``; :func:`behaviour` picks what a slave
runs from its kind or its SII image:

- a kind with a device model (``BuiltinDevice.model``) runs as an instance of
  the segment's model of that kind (one model object per kind and segment,
  created on first use in ``models``);
- a plain IO terminal runs nothing: its inputs come from wiring or from the
  PDI, its outputs stay in the SM buffer;
- a device with a mailbox but no protocol model gets :class:`MailboxErrorApp`,
  which answers every mailbox request with "mailbox protocol not supported",
  as a real slave without that protocol would.
"""

from __future__ import annotations

from collections.abc import MutableMapping
from dataclasses import dataclass

from pyethercat.errors import MailboxError
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.devices.builtin import VENDOR_ID, BuiltinDevice
from pyethercat.sim.devices.registry import DEVICES, DeviceRegistry, register_device
from pyethercat.sim.model import DeviceModel
from pyethercat.wire.mailbox.header import (
    MailboxErrorCode,
    MailboxHeader,
    MailboxType,
    encode_mailbox,
    encode_mailbox_error,
)
from pyethercat.wire.sii import SiiInfo

__all__ = [
    "DEVICES",
    "VENDOR_ID",
    "Behaviour",
    "BuiltinDevice",
    "DeviceRegistry",
    "MailboxErrorApp",
    "behaviour",
    "builtin_names",
    "get_builtin",
    "register_device",
]


class MailboxErrorApp(DeviceApp):
    """An IO device with a mailbox but no mailbox protocol.

    Every request the master writes into SM0 is answered in SM1 with a mailbox
    error reply (type 0): code 0x0002 "protocol not supported" for a well-formed
    header, 0x0001 "syntax" when even the header is unreadable.
    """

    def on_mailbox(self, data: bytes) -> None:
        if self.pdi is None:
            return
        try:
            header = MailboxHeader.decode(data)
        except MailboxError:
            code, counter, address = MailboxErrorCode.SYNTAX, 0, 0
        else:
            code, counter, address = (
                MailboxErrorCode.UNSUPPORTED_PROTOCOL,
                header.counter,
                header.address,
            )
        reply = encode_mailbox(
            MailboxType.ERR, encode_mailbox_error(code), counter=counter, address=address
        )
        # If SM1 is still full the master has not fetched the last reply; a
        # real slave would drop the new one too.
        self.pdi.post_mailbox(reply)


@dataclass
class Behaviour:
    """What one slave runs: its application (rare events) and its model instance (arrays)."""

    app: DeviceApp | None = None
    model: DeviceModel | None = None
    instance: int = -1


def get_builtin(key: str) -> BuiltinDevice:
    """The kind ``key`` of :data:`DEVICES`; :class:`ConfigError` naming the choices if unknown."""
    return DEVICES.get_kind(key)


def builtin_names() -> list[str]:
    """Names accepted after ``builtin:``."""
    return DEVICES.names()


def behaviour(kind: BuiltinDevice | None, info: SiiInfo,
              models: MutableMapping[object, DeviceModel] | None = None) -> Behaviour:
    """What a slave of ``kind`` (None: known by its SII only) runs.

    ``models`` holds the segment's device models by kind key; a model is
    created there on the kind's first slave (a fresh dictionary when None:
    the slave gets a model of its own).
    """
    if kind is not None and kind.model is not None:
        models = {} if models is None else models
        model = models.get(kind.key)
        if model is None:
            model = models[kind.key] = kind.model()
        instance, app = model.instance_app(info)
        return Behaviour(app, model, instance)
    has_mailbox = kind.mailbox is not None if kind is not None else bool(
        info.rx_mailbox_size and info.tx_mailbox_size)
    return Behaviour(MailboxErrorApp() if has_mailbox else None)
