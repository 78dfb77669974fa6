"""Hostile configurations and frames leave a segment a fresh master can bring to OP.

A master (or a fuzzer) may write anything: an SM window over the register
space, FMMUs of 64 KiB running past the end of the logical space, random
bytes in any register. Registers 0x0000-0x0EFF are never governed by a sync
manager, plans are bounded by the datagram, and after such frames a new
master finds, configures and runs the segment as if it were fresh.
"""

from __future__ import annotations

import random
import struct
import tracemalloc
from collections.abc import Callable

import pytest
from simhelp import fmmu_bytes, sm_bytes

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame

TOPOLOGY = """
[[slave]]
name = "coupler"
device = "builtin:coupler"
[[slave]]
name = "do8"
device = "builtin:do8"
[[slave]]
name = "di8"
device = "builtin:di8"
[[slave]]
name = "io"
device = "builtin:coe-io"
[[wire]]
from = "do8:0"
to = "di8:0"
"""


def _send(seg: object, *dgrams: Datagram) -> list[Datagram]:
    reply = seg.process(encode_frame(list(dgrams)))  # type: ignore[attr-defined]
    return [] if reply is None else decode_frame(reply).datagrams


def _hostile_frames() -> list[bytes]:
    frames = [
        # SM0 over the register space: start 0x0800, mailbox mode, enabled (every slave)
        encode_frame([Datagram.device(Command.BWR, 0, R.sm_address(0),
                                      sm_bytes(0x0800, 0x100, R.SM_CONTROL_MAILBOX_IN))]),
        # ... and SM1 reading the AL registers
        encode_frame([Datagram.device(Command.BWR, 0, R.sm_address(1),
                                      sm_bytes(0x0120, 0x20, R.SM_CONTROL_MAILBOX_IN))]),
        # an FMMU whose logical range runs past 0xFFFFFFFF, and a bit FMMU of 64 KiB
        encode_frame([Datagram.device(Command.BWR, 0, R.fmmu_address(0),
                                      fmmu_bytes(0xFFFFFF02, 0xFFFF, 0, 7, 0x1000, 0, 3)),
                      Datagram.device(Command.BWR, 0, R.fmmu_address(1),
                                      fmmu_bytes(0x10, 0xFFFF, 3, 2, 0x0800, 5, 3))]),
        encode_frame([Datagram.logical(Command.LRW, 0, bytes(1486))]),
        encode_frame([Datagram.logical(Command.LRW, 0xFFFFFA00, bytes(1486))]),
        # eight overlapping bit-wise FMMUs of 64 KiB on every slave
        encode_frame([Datagram.device(Command.BWR, 0, R.fmmu_address(k),
                                      fmmu_bytes(0xFFFF0000 + k * 0x1000, 0xFFFF, 5, 3, 0x1000 + 0x10 * k, 2, 3))
                      for k in range(8)]),
        encode_frame([Datagram.logical(Command.LRW, 0xFFFF0000, bytes(1486))]),
        encode_frame([Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", 0x18))]),
    ]
    # Mutated configuration frames: random bytes into the register space. Not
    # into DL control 0x0100-0x0103: closing port 0 by loop control cuts a
    # real ESC off its master too (every frame then circulates and is destroyed).
    rng = random.Random(20251124)
    for _ in range(400):
        ado = rng.randrange(0x0000, 0x0A00)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 48)))
        if ado < R.DL_CONTROL + 4 and ado + len(data) > R.DL_CONTROL:
            continue
        cmd = rng.choice([Command.BWR, Command.APWR, Command.BRW, Command.FPWR])
        d = (Datagram.positional(cmd, -rng.randrange(4), ado, data) if cmd == Command.APWR
             else Datagram.device(cmd, rng.randrange(4), ado, data))
        frames.append(encode_frame([d, Datagram.logical(Command.LRW, rng.randrange(2**32), bytes(64))]))
    return frames


def test_an_sm_over_the_registers_governs_nothing() -> None:
    seg = parse_topology(TOPOLOGY).build()
    # A mailbox the master reads (slave -> master) over the SM registers themselves.
    _send(seg, Datagram.device(Command.BWR, 0, R.sm_address(0),
                               sm_bytes(0x0800, 0x100, R.SM_CONTROL_MAILBOX_IN)))
    # A fresh master's reset of all SM registers (0x0800-0x08FF, the window's last
    # byte included) is written and counted by every slave, every time: no
    # "mailbox" fills up and refuses the next one...
    for _ in range(3):
        (d,) = _send(seg, Datagram.device(Command.BWR, 0, R.SM_BASE, bytes(0x100)))
        assert d.wkc == 4
        (d,) = _send(seg, Datagram.device(Command.BRD, 0, R.sm_address(0), R.SM_SIZE))
        assert d.wkc == 4 and bytes(d.data) == bytes(R.SM_SIZE)
        _send(seg, Datagram.device(Command.BWR, 0, R.sm_address(0),
                                   sm_bytes(0x0800, 0x100, R.SM_CONTROL_MAILBOX_IN)))
    # ...not even through an FMMU (an ECAT-read SM refuses logical writes in its
    # window: here it governs nothing) ...
    _send(seg, Datagram.device(Command.BWR, 0, R.fmmu_address(0),
                               fmmu_bytes(0x10000, 8, 0, 7, R.sm_address(2), 0, 2)))
    (d,) = _send(seg, Datagram.logical(Command.LWR, 0x10000, sm_bytes(0x1100, 1, 0x64, enable=0)))
    assert d.wkc == 4
    assert all(sl.read(R.sm_address(2), 4) == struct.pack("<HH", 0x1100, 1) for sl in seg.slaves)
    assert seg.sm_span() == (0, 0)
    # ...and an SM reading registers leaves them readable.
    _send(seg, Datagram.device(Command.BWR, 0, R.sm_address(1),
                               sm_bytes(0x0120, 0x20, R.SM_CONTROL_MAILBOX_IN)))
    (d,) = _send(seg, Datagram.device(Command.BRD, 0, R.AL_STATUS, 2))
    assert d.wkc == 4


def test_after_hostile_frames_a_fresh_master_brings_the_segment_to_op() -> None:
    # One clock for both: the hostile frames wrote the EEPROMs, and the
    # master's pauses while they finish their write cycle pass for the slaves too.
    clock = VirtualClock()
    seg = parse_topology(TOPOLOGY).build(clock=clock)
    for frame in _hostile_frames():
        seg.process(frame)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.scan()
    assert [s.name.split()[0] for s in m.slaves] == ["PEC-CU4", "PEC-DO8", "PEC-DI8", "PEC-COEIO"]
    m.configure()
    # To OP with the loop on the shared virtual clock, then frames stepped by hand: a
    # run(seconds=...) ends in the orderly stop (PREOP) and counts its seconds in real time.
    runner = m.start(cycle=0.001, clock=clock)
    runner.halt()
    assert all(s.al_state == AlState.OP for s in m.slaves)
    assert [int(sl.al_state) for sl in seg.slaves] == [int(AlState.OP)] * 4
    # the process image works: an output reaches the wired input
    m.slaves[1].outputs["Output 1"] = 1
    assert runner.exchange_once() and runner.exchange_once()
    assert m.slaves[2].inputs["Input 1"] == 1


# --- hostile FMMU configurations: plans bounded by the datagram -------------------------

_RW = 3


def _fmmus_over(seg: Segment, address: int, n: int) -> int:
    """Active FMMUs of the segment's slaves with a byte in the logical window [address, address + n)
    (the ESC compares logical addresses modulo 2**32), read off the FMMU registers."""
    count = 0
    for sl in seg.slaves:
        nf = sl.spec.profile.fmmu_count
        raw = sl.read(R.FMMU_BASE, nf * R.FMMU_SIZE)
        for k in range(nf):
            logical, length, _, _, _, _, ftype, act = R.FMMU_STRUCT.unpack_from(raw, k * R.FMMU_SIZE)
            if act & 1 and length and ftype & 3:
                d = (address - logical) % 2**32
                count += d < length or d + n > 2**32
    return count


def _lrw_costs(seg: Segment, address: int, n: int = 1486) -> tuple[int, int, int, int]:
    """Two LRWs of ``n`` bytes at ``address``: (FMMUs over the window, plan entries, bytes
    allocated at the peak of the first LRW (planning it), and of the second (running it))."""
    peaks = []
    tracemalloc.start()
    try:
        for _ in range(2):
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            _send(seg, Datagram.logical(Command.LRW, address, bytes(n)))
            peaks.append(tracemalloc.get_traced_memory()[1] - base)
    finally:
        tracemalloc.stop()
    lmap = seg.state.lmap
    size = lmap.plan_size(address, n) if lmap is not None else None
    return _fmmus_over(seg, address, n), size or 0, peaks[0], peaks[1]


def _set_all(seg: Segment, configs: list[bytes]) -> None:
    for k, raw in enumerate(configs):
        _send(seg, Datagram.device(Command.BWR, 0, R.fmmu_address(k), raw))


def _wrap(seg: Segment) -> list[int]:
    # 0xFFFF bytes from 0xFFFFFF02: the last 0xFE bytes of the logical space, then 0..0xFF00
    _set_all(seg, [fmmu_bytes(0xFFFFFF02, 0xFFFF, 0, 7, 0x1000, 0, _RW)])
    return [0xFFFFFA00, 0x0, 0x1000]


def _bitwise_64k(seg: Segment) -> list[int]:
    # eight overlapping bit-wise 64 KiB FMMUs per slave, most of them across the end of the space
    _set_all(seg, [fmmu_bytes(0xFFFF0000 + k * 0x1000, 0xFFFF, 5, 3, 0x1000 + 0x10 * k, 2, _RW)
                   for k in range(8)])
    return [0xFFFF0000, 0xFFFFFA00, 0x0]


def _sixteen_shifts(seg: Segment) -> list[int]:
    # every FMMU a chip has over one window, each with its own bit offset: cross traffic
    # along the whole route, read and written bit by bit
    _set_all(seg, [fmmu_bytes(0xFFFF0000 - 3 * k, 0xFFFF, k % 8, 3 * k % 8, 0x1000 + 7 * k, 5 * k % 8, _RW)
                   for k in range(16)])
    return [0xFFFF0100]


def _random_fmmus(seg: Segment) -> list[int]:
    rng = random.Random(20251125)
    addresses = []
    for j in range(24):
        logical = rng.choice([0xFFFFFF02, rng.randrange(2**32), 0xFFFF0000 + rng.randrange(0x10000)])
        raw = fmmu_bytes(logical, rng.randrange(1, 0x10000), rng.randrange(8), rng.randrange(8),
                         rng.randrange(0x10000), rng.randrange(8), rng.choice([1, 2, 3]))
        d = (Datagram.device(Command.BWR, 0, R.fmmu_address(rng.randrange(16)), raw) if j % 2 else
             Datagram.device(Command.FPWR, 0, R.fmmu_address(rng.randrange(16)), raw))
        _send(seg, d)
        addresses.append(rng.choice([0xFFFFFA00, 0, logical, (logical + 100) % 2**32]))
    return addresses


@pytest.mark.parametrize("slaves", [4, 20])
@pytest.mark.parametrize("configure", [_wrap, _bitwise_64k, _sixteen_shifts, _random_fmmus],
                         ids=["wrap", "bitwise-64k", "sixteen-shifts", "random"])
def test_hostile_fmmus_cost_what_the_datagram_covers(configure: Callable[[Segment], list[int]],
                                                     slaves: int) -> None:
    # A real ESC handles any FMMU configuration at wire speed. Here the plan of a
    # logical datagram holds at most one read and one write entry per datagram byte
    # (and the byte after it, for a bit offset) and FMMU over it, whatever the FMMUs'
    # lengths; planning allocates a fixed multiple of that (plus fixed-size working
    # arrays), running a planned datagram a fraction of it.
    kinds = ["coupler", "do8", "di8", "coe-io"] * (slaves // 4)
    seg = parse_topology("".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:{k}"\n'
                                 for i, k in enumerate(kinds))).build()
    n = 1486
    for address in configure(seg):
        fmmus, size, planning, running = _lrw_costs(seg, address, n)
        assert size <= 2 * (n + 1) * fmmus, (hex(address), fmmus, size)
        assert planning <= 128 * 2 * (n + 1) * fmmus + 1_000_000, (hex(address), fmmus, planning)
        assert running <= 16 * size + 100_000, (hex(address), size, running)
