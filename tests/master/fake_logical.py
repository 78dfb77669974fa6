"""The master-core fake segment plus logical addressing (FMMUs, bitwise), IO wiring and faults.

Stand-in for the simulator in cyclic tests: LRD/LWR/LRW through each slave's
FMMU registers bit by bit (as an ESC maps them), wires that copy a slave's
output RAM bits to another slave's input RAM after every frame (outputs that
loop back to inputs), power cycling (registers reset: station address 0,
INIT) and link breaks (slaves behind the break stop answering).
"""

from __future__ import annotations

import struct

from fake_esc_segment import FakeSegment, FakeSlave

from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram


def _fmmus(mem: bytearray) -> list[tuple[int, int, int, int, int, int, int]]:
    out = []
    for n in range(8):
        a = reg.fmmu_address(n)
        ls, ln, sb, eb, ps, pb, ty, act = struct.unpack_from("<IHBBHBBB", mem, a)
        if act & 1 and ln:
            bits = 8 * ln - sb - (7 - eb)
            out.append((ls, ln, sb, bits, ps, pb, ty))
    return out


def _get_bit(buf: bytes | bytearray, bit: int) -> int:
    return (buf[bit >> 3] >> (bit & 7)) & 1


def _set_bit(buf: bytearray, bit: int, v: int) -> None:
    if v:
        buf[bit >> 3] |= 1 << (bit & 7)
    else:
        buf[bit >> 3] &= ~(1 << (bit & 7)) & 0xFF


class LogicalSegment(FakeSegment):
    def __init__(self, slaves: list[FakeSlave]) -> None:
        super().__init__(slaves)
        for s in slaves:
            struct.pack_into("<H", s.mem, reg.AL_STATUS, AlState.INIT)
        #: (src slave, src RAM address, dst slave, dst RAM address, bits)
        self.wires: list[tuple[int, int, int, int, int]] = []
        self.off: set[int] = set()
        self.break_after: int | None = None
        self._sii = [bytes(s.sii) for s in slaves]

    def reachable(self, i: int) -> bool:
        if any(j <= i for j in self.off):
            return False
        return self.break_after is None or i <= self.break_after

    def process(self, frame: bytes):  # type: ignore[override]
        saved = self.slaves
        self.slaves = [s for i, s in enumerate(saved) if self.reachable(i)]
        try:
            return super().process(frame)
        finally:
            self.slaves = saved
            self._propagate()

    def _propagate(self) -> None:
        for src, sa, dst, da, bits in self.wires:
            s, d = self.slaves[src].mem, self.slaves[dst].mem
            for i in range(bits):
                _set_bit(d, 8 * da + i, _get_bit(s, 8 * sa + i))

    def power_cycle(self, i: int) -> None:
        fresh = FakeSlave(self._sii[i])
        struct.pack_into("<H", fresh.mem, reg.AL_STATUS, AlState.INIT)
        self.slaves[i] = fresh

    def drop_to(self, i: int, state: int, code: int = 0x001B) -> None:
        struct.pack_into("<HHH", self.slaves[i].mem, reg.AL_STATUS, state | 0x10, 0, code)

    def _one(self, s: FakeSlave, d: Datagram) -> None:
        cmd = d.command
        if cmd not in (Command.LRD, Command.LWR, Command.LRW):
            super()._one(s, d)
            return
        lo, size = d.logical_address, len(d.data)
        read_hit = write_hit = False
        incoming = bytes(d.data)
        for ls, _ln, sb, bits, ps, pb, ty in _fmmus(s.mem):
            for i in range(bits):
                lbit = 8 * ls + sb + i
                if not 8 * lo <= lbit < 8 * (lo + size):
                    continue
                fbit = lbit - 8 * lo
                pbit = 8 * ps + pb + i
                if ty & 1 and cmd in (Command.LRD, Command.LRW):
                    _set_bit(d.data, fbit, _get_bit(s.mem, pbit))
                    read_hit = True
                if ty & 2 and cmd in (Command.LWR, Command.LRW):
                    _set_bit(s.mem, pbit, _get_bit(incoming, fbit))
                    write_hit = True
        d.wkc += (1 if read_hit else 0) + ((2 if cmd == Command.LRW else 1) if write_hit else 0)
