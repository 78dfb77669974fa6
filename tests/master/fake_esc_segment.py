"""A small register-level fake segment for master tests (stand-in for the simulator).

It answers frames synchronously (as a PairLink responder) and models just
what the master core touches: auto-increment/configured/broadcast reads and
writes on a 64 KiB memory per slave, AL control -> AL status with refusals,
the SII interface (read 4/8 bytes, write with enable, reload, optional busy
polls), port DL status, and fault hooks (drop, duplicate, corrupt replies).
Slaves are processed slave by slave, each taking all datagrams of the frame
in order, as a real segment does.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame, returned_source_mac


@dataclass
class FakeSlave:
    sii: bytes
    #: Ports with a link (port 0 towards the master always).
    linked_ports: tuple[int, ...] = (0, 1)
    read_8: bool = True
    #: Polls of 0x0502 that still show busy after each SII command.
    busy_polls: int = 0
    #: state -> AL status code the slave answers a request for that state with.
    refuse: dict[int, int] = field(default_factory=dict)
    features: int = reg.Feature.DC_SUPPORTED | reg.Feature.DC_64BIT
    port_descriptor: int = 0x0F  # ports 0 and 1 MII
    #: Requests for a state that the slave ignores (stays where it is, no error).
    stuck: set[int] = field(default_factory=set)
    mem: bytearray = field(default_factory=lambda: bytearray(0x10000))
    busy_left: int = 0
    sii_writes: int = 0
    #: SII words whose write the EEPROM does not acknowledge (status bit 13, nothing written).
    refuse_sii_writes: set[int] = field(default_factory=set)
    #: SII word -> bits that stay set whatever is written (a worn EEPROM cell).
    stuck_sii_bits: dict[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.sii = bytearray(self.sii)
        m = self.mem
        m[reg.TYPE] = 0x11
        m[reg.REVISION] = 1
        m[reg.FMMU_COUNT] = 8
        m[reg.SM_COUNT] = 8
        m[reg.RAM_SIZE] = 8
        m[reg.PORT_DESCRIPTOR] = self.port_descriptor
        struct.pack_into("<H", m, reg.FEATURES, self.features)
        self._reload()
        struct.pack_into("<H", m, reg.AL_STATUS, AlState.PREOP)  # power-up leftover
        dl = 0
        for p in range(4):
            if p in self.linked_ports:
                dl |= reg.dl_status_link(p) | reg.dl_status_com(p)
            else:
                dl |= reg.dl_status_loop(p)
        struct.pack_into("<H", m, reg.DL_STATUS, dl)
        struct.pack_into("<H", m, reg.SII_CONTROL,
                         reg.SiiControl.READ_8_BYTES if self.read_8 else 0)

    def _reload(self) -> None:
        self.mem[reg.STATION_ALIAS:reg.STATION_ALIAS + 2] = self.sii[8:10]

    @property
    def station(self) -> int:
        return int(struct.unpack_from("<H", self.mem, reg.STATION_ADDRESS)[0])

    @property
    def al_status(self) -> int:
        return int(struct.unpack_from("<H", self.mem, reg.AL_STATUS)[0])

    def read(self, address: int, size: int) -> bytes:
        if address <= reg.SII_CONTROL < address + size and self.busy_left > 0:
            self.busy_left -= 1
            data = bytearray(self.mem[address:address + size])
            off = reg.SII_CONTROL - address
            data[off + 1] |= 0x80  # busy
            return bytes(data)
        return bytes(self.mem[address:address + size])

    def write(self, address: int, data: bytes) -> None:
        end = address + len(data)
        self.mem[address:end] = data
        if address <= reg.AL_CONTROL < end:
            self._al_control(struct.unpack_from("<H", self.mem, reg.AL_CONTROL)[0])
        if address <= reg.SII_CONTROL < end:
            self._sii_command()
        if address <= reg.SII_CONFIG < end and self.mem[reg.SII_CONFIG] & reg.SII_CONFIG_FORCE_ECAT:
            self.mem[reg.SII_PDI_ACCESS] = 0

    def _al_control(self, value: int) -> None:
        status = self.al_status
        target = value & 0x0F
        ack = bool(value & 0x10)
        if status & 0x10 and not ack and target != AlState.INIT:
            return  # error not acknowledged: ignore
        if ack:
            status &= ~0x10
            struct.pack_into("<H", self.mem, reg.AL_STATUS_CODE, 0)
        if target in self.stuck:
            struct.pack_into("<H", self.mem, reg.AL_STATUS, status)
            return
        if target in self.refuse:
            struct.pack_into("<H", self.mem, reg.AL_STATUS, (status & 0x0F) | 0x10)
            struct.pack_into("<H", self.mem, reg.AL_STATUS_CODE, self.refuse[target])
            return
        cur = status & 0x0F
        allowed = (target == cur or target == AlState.INIT or target < cur
                   or (cur, target) in {(1, 2), (1, 3), (2, 4), (4, 8)})
        if target not in (1, 2, 3, 4, 8):
            struct.pack_into("<H", self.mem, reg.AL_STATUS, cur | 0x10)
            struct.pack_into("<H", self.mem, reg.AL_STATUS_CODE, 0x0012)
        elif not allowed:
            struct.pack_into("<H", self.mem, reg.AL_STATUS, cur | 0x10)
            struct.pack_into("<H", self.mem, reg.AL_STATUS_CODE, 0x0011)
        else:
            struct.pack_into("<H", self.mem, reg.AL_STATUS, target)

    def _sii_command(self) -> None:
        ctrl, addr = struct.unpack_from("<HI", self.mem, reg.SII_CONTROL)
        cmd = ctrl & reg.SII_COMMAND_MASK
        keep = ctrl & (reg.SiiControl.READ_8_BYTES | reg.SiiControl.WRITE_ENABLE)
        status = keep & reg.SiiControl.READ_8_BYTES
        if cmd == 0:
            struct.pack_into("<H", self.mem, reg.SII_CONTROL, status)
            return
        if cmd == reg.SiiControl.CMD_READ:
            n = 8 if self.read_8 else 4
            chunk = bytes(self.sii[2 * addr:2 * addr + n]).ljust(n, b"\xff")
            self.mem[reg.SII_DATA:reg.SII_DATA + n] = chunk
        elif cmd == reg.SiiControl.CMD_WRITE:
            if not ctrl & reg.SiiControl.WRITE_ENABLE:
                status |= reg.SiiControl.WRITE_ENABLE_ERROR
            elif addr in self.refuse_sii_writes:
                status |= reg.SiiControl.ACK_ERROR
            else:
                if 2 * addr + 2 > len(self.sii):
                    self.sii.extend(b"\xff" * (2 * addr + 2 - len(self.sii)))
                self.sii[2 * addr:2 * addr + 2] = self.mem[reg.SII_DATA:reg.SII_DATA + 2]
                if addr in self.stuck_sii_bits:
                    self.sii[2 * addr] |= self.stuck_sii_bits[addr] & 0xFF
                    self.sii[2 * addr + 1] |= self.stuck_sii_bits[addr] >> 8
                self.sii_writes += 1
        elif cmd == reg.SiiControl.CMD_RELOAD:
            self._reload()
        struct.pack_into("<H", self.mem, reg.SII_CONTROL, status)
        self.busy_left = self.busy_polls


class FakeSegment:
    """A line (or tree, by listing slaves in frame order) of FakeSlaves."""

    def __init__(self, slaves: list[FakeSlave]) -> None:
        self.slaves = slaves
        self.frames = 0
        #: Hook: frame number -> action ("drop", "dup", or a callable mangling the reply).
        self.faults: dict[int, str | Callable[[bytes], bytes]] = {}
        self.pending_late: list[bytes] = []
        self.powered = True

    def process(self, frame: bytes) -> list[bytes] | bytes | None:
        n = self.frames
        self.frames += 1
        if not self.powered:
            return None
        decoded = decode_frame(frame)
        dgs = decoded.datagrams
        for d in dgs:
            d.data = bytearray(d.data)
        for s in self.slaves:
            for d in dgs:
                self._one(s, d)
        out = [Datagram(d.command, d.index, d.address, bytes(d.data), d.irq, d.wkc)
               for d in dgs]
        reply = encode_frame(out, src=returned_source_mac(decoded.src))
        fault = self.faults.get(n)
        late, self.pending_late = self.pending_late, []
        if fault == "drop":
            return late or None
        if fault == "late":
            self.pending_late.append(reply)
            return late or None
        if fault == "dup":
            return [*late, reply, reply]
        if fault == "echo":
            return [*late, frame, reply]
        if callable(fault):
            return [*late, fault(reply)]
        return [*late, reply]

    def _one(self, s: FakeSlave, d: Datagram) -> None:
        cmd = d.command
        adp, ado = d.adp, d.ado
        size = len(d.data)
        if cmd in (Command.APRD, Command.APWR, Command.APRW):
            hit = adp == 0
            d.address = (d.address & 0xFFFF0000) | ((adp + 1) & 0xFFFF)
        elif cmd in (Command.FPRD, Command.FPWR, Command.FPRW):
            hit = adp == s.station
        elif cmd in (Command.BRD, Command.BWR):
            d.address = (d.address & 0xFFFF0000) | ((adp + 1) & 0xFFFF)
            if cmd == Command.BRD:
                mem = s.read(ado, size)
                d.data[:] = bytes(a | b for a, b in zip(d.data, mem, strict=True))
            else:
                s.write(ado, bytes(d.data))
            d.wkc += 1
            return
        else:
            return
        if not hit:
            return
        if cmd in (Command.APRD, Command.FPRD):
            d.data[:] = s.read(ado, size)
            d.wkc += 1
        else:
            s.write(ado, bytes(d.data))
            d.wkc += 1
