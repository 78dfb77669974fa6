"""Simulator frame-processing time versus a real 100BASE-TX segment (issue 3).

For 10, 100 and 1000 slaves (alternating di8 / do8 terminals on ET1200-class
E-Bus ESCs, 100 ns forwarding delay, 5 ns cables) this measures the time
``Segment.process`` needs for

- one frame with a 1486-byte LRW over the process image (all slaves mapped),
- one frame with a 2-byte BRD of AL status (0x0130),

and the ratio to the time the frame needs on a real segment: frame bytes on
the wire (Ethernet frame including FCS, at least 64 bytes) x 80 ns plus the
forwarding and cable delays of the whole walk (each slave is passed twice).
Target: ratio <= 0.5. The last output line is one JSON object of the figures.

Then the same for a segment of 100 simulated CiA 402 servo drives in CSP on
DC SYNC0 1 ms (``benchmarks/drive_frame.py`` has the set-up, and 1 and 10
drives): the simulator's time for all frames of one cycle, including the
drive model's cycle of every drive, against their wire time. These figures
(``cia402_100_*``) are not part of ``max_ratio``: the 0.5 target is for the
frame path; the drives' physics come on top.
"""

from __future__ import annotations

import json
import struct
import sys
import time

from pyethercat.clock import VirtualClock
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.segment import Segment, SimSlaveSpec
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import MAX_DATA, Command, Datagram
from pyethercat.wire.frame import encode_frame
from pyethercat.wire.sii import (
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdos,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    build_sii,
)
from pyethercat.wire.sii.model import CategoryType

OUT_SM, IN_SM = 0x0F00, 0x1000


def terminal_sii(name: str, outputs: bool) -> bytes:
    """Minimal SII of an 8-channel digital terminal (no mailbox)."""
    sms = [SiiSyncManager(OUT_SM, 1, 0x64, 0, 1, 3) if outputs else SiiSyncManager(IN_SM, 1, 0x20, 0, 1, 4)]
    pdo = SiiPdo(0x1600 if outputs else 0x1A00, 0, entries=[SiiPdoEntry(0x7000 if outputs else 0x6000, 1, 0, 1, 8)])
    cats = [SiiStrings([name.encode()]), SiiGeneral(name_index=1), SiiSyncManagers(sms),
            SiiPdos(CategoryType.RXPDO if outputs else CategoryType.TXPDO, [pdo])]
    info = SiiInfo(vendor_id=2, product_code=0x1008 if not outputs else 0x2008, revision=1,
                   eeprom_size_code=7, categories=cats)
    return build_sii(info)


def build(n: int) -> tuple[Segment, int]:
    seg = Segment(VirtualClock(0))
    seg.advance_clock = True
    di, do = terminal_sii("di8", False), terminal_sii("do8", True)
    prof = PROFILES["ET1200"]
    for i in range(n):
        seg.add_slave(SimSlaveSpec(f"t{i}", do if i % 2 else di, prof))

    def send(*ds: Datagram) -> None:
        assert seg.process(encode_frame(list(ds))) is not None

    logical = 0
    for i in range(n):
        st = 0x1000 + i
        send(Datagram.positional(Command.APWR, i, R.STATION_ADDRESS, struct.pack("<H", st)))
        outputs = bool(i % 2)
        sm = 0 if outputs else 0  # one SM per terminal (SM0), as Beckhoff IO terminals do
        start = OUT_SM if outputs else IN_SM
        control = R.SM_CONTROL_OUTPUTS if outputs else R.SM_CONTROL_INPUTS
        ftype = R.FmmuType.WRITE if outputs else R.FmmuType.READ
        send(Datagram.device(Command.FPWR, st, R.sm_address(sm), struct.pack("<HHBBBB", start, 1, control, 0, 1, 0)),
             Datagram.device(Command.FPWR, st, R.fmmu_address(0),
                             struct.pack("<IHBBHBBB3x", logical, 1, 0, 7, start, 0, int(ftype), 1)))
        logical += 1
    for state in (AlStateValues.PREOP, AlStateValues.SAFEOP):
        send(Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", state)))
    return seg, logical


class AlStateValues:
    PREOP = 2
    SAFEOP = 4
    OP = 8


def measure(seg: Segment, frame: bytes, seconds: float) -> float:
    """Median-ish time per process() call in seconds (best of several batches)."""
    for _ in range(20):
        seg.process(frame)
    best = float("inf")
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        batch = 50
        t0 = time.perf_counter()
        for _ in range(batch):
            seg.process(frame)
        best = min(best, (time.perf_counter() - t0) / batch)
    return best


def main() -> int:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 1.0
    figures: dict[str, float] = {}
    print(f"{'slaves':>6} {'frame':>10} {'sim us':>9} {'wire us':>9} {'ratio':>6}")
    for n in (10, 100, 1000):
        seg, image = build(n)
        lrw = encode_frame([Datagram.logical(Command.LRW, 0, MAX_DATA)])
        brd = encode_frame([Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)])
        # sanity: every slave answers
        from pyethercat.wire.frame import decode_frame

        reply = seg.process(lrw)
        assert reply is not None
        wkc = decode_frame(reply).datagrams[0].wkc
        assert wkc == (n // 2) * 2 + (n - n // 2), (n, wkc)
        send_op = encode_frame([Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", AlStateValues.OP))])
        seg.process(send_op)
        for name, frame in (("lrw1486", lrw), ("brd0130", brd)):
            sim = measure(seg, frame, seconds)
            wire = (max(len(frame) + 4, 64) * seg.mac_wire_ns + seg.route.delay_ns) * 1e-9
            ratio = sim / wire
            print(f"{n:>6} {name:>10} {sim * 1e6:>9.1f} {wire * 1e6:>9.1f} {ratio:>6.2f}")
            figures[f"{name}_{n}_sim_us"] = round(sim * 1e6, 2)
            figures[f"{name}_{n}_wire_us"] = round(wire * 1e6, 2)
            figures[f"{name}_{n}_ratio"] = round(ratio, 3)
    figures["max_ratio"] = max(v for k, v in figures.items() if k.endswith("_ratio"))
    from drive_frame import Rig  # this directory is on sys.path when run as a script

    rig = Rig(100)
    drives = min((rig.measure(100) for _ in range(3)), key=lambda r: r["cycle_us"])
    rig.finish()
    print(f"{100:>6} {'cia402 csp':>10} {drives['cycle_us']:>9.1f} {drives['wire_us']:>9.1f} "
          f"{drives['ratio']:>6.2f}   (one 1 ms cycle: {drives['frames_per_cycle']:g} frames, "
          f"drive model {drives['drives_us']:.0f} us)")
    for key in ("frame_us", "cycle_us", "wire_us", "ratio", "drives_us"):
        figures[f"cia402_100_{key}"] = drives[key]
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
