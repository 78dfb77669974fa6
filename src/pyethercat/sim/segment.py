"""A simulated EtherCAT segment: slaves joined port to port (skeleton, API final)."""

from __future__ import annotations

from dataclasses import dataclass

from pyethercat.sim.clock import Clock, VirtualClock
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.profiles import EscProfile


@dataclass
class SlaveSpec:
    """What a slave is: its EEPROM image, its ESC and its application."""

    name: str
    sii: bytes
    profile: EscProfile
    app: DeviceApp | None = None
    alias: int | None = None
    drift_ppm: float = 0.0
    forwarding_delay_ns: int | None = None
    initial_inputs: bytes | None = None


class SimSlave:
    """One slave of a segment (``esc`` gives test helpers for its memory)."""

    def __init__(self, name: str, spec: SlaveSpec, index: int) -> None:
        self.name = name
        self.spec = spec
        self.index = index


class Segment:
    """A segment of simulated slaves; :meth:`process` answers one frame."""

    def __init__(self, clock: Clock | None = None, mac_wire_ns: int = 80) -> None:
        self.clock: Clock = clock if clock is not None else VirtualClock()
        self.mac_wire_ns = mac_wire_ns
        self.slaves: list[SimSlave] = []

    def add_slave(self, spec: SlaveSpec, parent: int | None = None, port: int | None = None,
                  cable_delay_ns: int = 5) -> int:
        raise NotImplementedError

    def process(self, frame: bytes) -> bytes | None:
        raise NotImplementedError

    def wire(self, src_slave: int, src_bit: int, dst_slave: int, dst_bit: int, bits: int) -> None:
        raise NotImplementedError

    def break_link(self, slave: int, port: int) -> None:
        raise NotImplementedError

    def restore_link(self, slave: int, port: int) -> None:
        raise NotImplementedError

    def power_off(self, slave: int) -> None:
        raise NotImplementedError

    def power_on(self, slave: int) -> None:
        raise NotImplementedError

    def corrupt_frames(self, slave: int, port: int, count: int = 1) -> None:
        raise NotImplementedError

    def drop_probability(self, p: float, seed: int | None = None) -> None:
        raise NotImplementedError
