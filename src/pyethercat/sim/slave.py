"""A slave of a simulated segment: what it is (:class:`SimSlaveSpec`) and its handle (:class:`SimSlave`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pyethercat.sim.device import DeviceApp
from pyethercat.sim.esc import Esc
from pyethercat.sim.host import EscHost
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.model import DeviceModel
from pyethercat.sim.profiles import EscProfile
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import SiiInfo

__all__ = ["SimSlave", "SimSlaveSpec"]


@dataclass
class SimSlaveSpec:
    """What a slave is: its EEPROM image, its ESC and its application.

    ``alias`` overrides SII word 4; ``drift_ppm`` makes its local clock run
    fast (positive) or slow; ``forwarding_delay_ns`` overrides the profile's
    delay; ``initial_inputs`` fills the input SM as soon as it is enabled.
    ``sii_info`` is the parsed image when the caller has it (saves a parse).
    """

    name: str
    sii: bytes
    profile: EscProfile
    app: DeviceApp | None = None
    alias: int | None = None
    drift_ppm: float = 0.0
    forwarding_delay_ns: int | None = None
    initial_inputs: bytes | None = None
    sii_info: SiiInfo | None = None
    #: The device model of the slave's kind (shared by its instances) and the
    #: slave's instance number in it (-1: a new instance).
    model: DeviceModel | None = None
    instance: int = -1

    @property
    def delay_ns(self) -> int:
        """The forwarding delay: the override, else the profile's."""
        d = self.forwarding_delay_ns
        return d if d is not None else self.profile.default_forwarding_delay_ns

    def make_esc(self, host: EscHost, memory: EscMemory, index: int) -> Esc:
        """The slave's ESC model as slave ``index`` of a segment (``host``, ``memory``)."""
        return Esc(host, memory, index, self.name, self.sii, self.profile, self.app, self.alias,
                   self.initial_inputs, self.sii_info)


class SimSlave:
    """One slave of a segment. ``esc`` is its ESC model; ``read``/``write`` are raw test helpers."""

    def __init__(self, name: str, spec: SimSlaveSpec, index: int, esc: Esc) -> None:
        self.name = name
        self.spec = spec
        self.index = index
        self.esc = esc

    def read(self, address: int, length: int) -> bytes:
        """Raw memory bytes (no side effects; memory the chip lacks reads 0)."""
        data = self.esc.row[address: address + length].tobytes()
        return data + bytes(length - len(data))

    def write(self, address: int, data: bytes) -> None:
        """Raw memory write (no side effects; for test set-up)."""
        if address + len(data) > len(self.esc.row):
            raise ValueError(f"raw write 0x{address:04X}+{len(data)} past the simulated memory")
        self.esc.row[address: address + len(data)] = np.frombuffer(bytes(data), np.uint8)

    def u16(self, address: int) -> int:
        return self.esc.u16(address)

    @property
    def al_state(self) -> AlState:
        return self.esc.al_state()

    def __repr__(self) -> str:
        return f"SimSlave({self.index}, {self.name!r}, {self.spec.profile.name})"
