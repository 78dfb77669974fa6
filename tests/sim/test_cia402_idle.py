"""The drive's idle fast path (cycles skipped while an axis stands with the power off) is invisible.

Two drives get the same frames and SDOs, one with the fast path, one that runs
every cycle in full (``idle_fast_path = False``, the behaviour before the fast
path existed); every input buffer, every SDO upload and every emergency must be
the same byte for byte, through idle stretches in each power state, parameter
writes while idle (a load torque that makes the axis fall with the power off),
enabling, a CSP move, a quick stop, a limit-switch fault, idle cycles in Fault,
the fault reset and a lazy actual value read by SDO.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
from test_cia402_drive import IN_LEN, RX_FMT, SM2, SM3, Drive, i32

from pyethercat.wire.cia402 import DriveState, decode_state
from pyethercat.wire.mailbox import decode_message


def f32(v: float) -> bytes:
    return struct.pack("<f", v)


class Pair:
    """The same master traffic to a fast-path drive and a full-cycle drive, compared."""

    def __init__(self) -> None:
        self.fast, self.full = Drive(), Drive()
        full_model = self.full.s.seg.slaves[0].spec.model
        assert full_model is not self.fast.s.seg.slaves[0].spec.model
        full_model.idle_fast_path = False
        self.fast.op()
        self.full.op()
        self.inputs: list[bytes] = []
        self.skipped = 0

    def both(self, act: Callable[[Drive], object]) -> None:
        a, b = act(self.fast), act(self.full)
        assert a == b

    def cycle(self, n: int = 1, **out: int) -> None:
        for d in (self.fast, self.full):
            d.out.update(out)
        model = self.fast.s.seg.slaves[0].spec.model
        for _ in range(n):
            got = []
            for d in (self.fast, self.full):
                d.s.clock.advance(1_000_000)
                o = d.out
                assert d.s.fpwr(SM2, struct.pack(RX_FMT, o["cw"], o["mode"], o["pos"], o["vel"],
                                                 o["torque"])) == 1
                got.append(bytes(d.s.fprd(SM3, IN_LEN).data))
            assert got[0] == got[1], f"cycle {len(self.inputs)}: {got[0].hex()} != {got[1].hex()}"
            self.inputs.append(got[0])
            self.skipped += model._quiet is not None

    @property
    def state(self) -> DriveState | None:
        return decode_state(int.from_bytes(self.inputs[-1][:2], "little"))

    def emergencies(self) -> None:
        def drain(d: Drive) -> list[bytes]:
            out = []
            while (raw := d.s.fetch()) is not None:
                decode_message(raw)
                out.append(raw[6:])  # the CoE part (the mailbox header's counter may differ)
            return out
        self.both(drain)


def test_idle_fast_path_changes_nothing_observable() -> None:
    t = Pair()
    t.cycle(30, cw=0x00, mode=8)                          # switch on disabled, standing
    quiet_sod = t.skipped
    t.cycle(5, cw=0x06)
    t.cycle(20, cw=0x07)                                  # switched on, standing
    t.cycle(5, pos=12_345)                                # a target while off is ignored
    t.both(lambda d: d.s.download(0x2100, 4, f32(0.5)))   # load beyond the Coulomb friction:
    t.cycle(20)                                           # the axis falls, power off
    t.both(lambda d: d.s.download(0x2100, 4, f32(0.0)))
    t.cycle(20)
    t.cycle(3, cw=0x0F, pos=struct.unpack("<i", t.inputs[-1][3:7])[0])
    assert t.state == DriveState.OPERATION_ENABLED
    here = struct.unpack("<i", t.inputs[-1][3:7])[0]
    for k in range(1, 101):                               # CSP ramp, then hold
        t.cycle(pos=here + 300 * k)
    t.cycle(30)
    t.cycle(200, cw=0x02)                                 # quick stop, then idle after it
    t.cycle(30, cw=0x00)
    assert t.state == DriveState.SWITCH_ON_DISABLED
    t.both(lambda d: d.s.download(0x2100, 8, i32(here + 40_000)))  # positive limit switch
    t.cycle(5, cw=0x06)
    t.cycle(3, cw=0x0F, mode=9, vel=0)
    t.cycle(400, vel=200_000)                             # into the switch: fault
    assert t.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
    t.cycle(30, vel=0)                                    # idle in Fault
    t.emergencies()
    t.both(lambda d: d.sdo(0x6064, 0, "<i"))              # lazy actual value by SDO
    t.both(lambda d: d.sdo(0x60FD, 0, "<I"))
    t.cycle(5)
    t.both(lambda d: d.s.download(0x2100, 8, i32(1 << 30)))
    t.cycle(3, cw=0x80)                                   # fault reset
    t.cycle(20, cw=0x00)
    assert t.state == DriveState.SWITCH_ON_DISABLED
    t.emergencies()
    # the fast path did skip cycles (idle stretches), and not only at the start
    assert quiet_sod > 20
    assert t.skipped > quiet_sod + 100
    assert len({b[3:7] for b in t.inputs}) > 50  # positions moved: a real trajectory compared
    assert np.frombuffer(b"".join(t.inputs), np.uint8).any()
