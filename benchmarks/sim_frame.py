"""Simulator frame-processing time versus a real 100BASE-TX segment, at scale.

Segments of 10, 100, 1000 and 10,000 slaves, in two mixes:

- ``dido``: alternating ``builtin:di8`` / ``builtin:do8`` terminals (ET1200);
- ``coe30``: every tenth slave of three is ``builtin:coe-io`` (ET1100, CoE
  mailbox, 7 output and 7 input bytes through its PDO mapping), the rest
  di8/do8: 30 % CoE devices.

Each segment is configured as a master does it (station addresses, the
kind's sync managers, one FMMU per direction, process image outputs first,
then inputs) and brought to OP. Then it measures ``Segment.process`` for

- the cyclic exchange: LRW datagrams over the whole image, 1486 bytes per
  frame at most (10,000 di/do slaves need 7 frames), all frames of a cycle;
- one frame with a 1486-byte LRW from logical address 0 (the frame of the
  earlier figures: a full frame whatever the image size);
- one frame with a 2-byte BRD of AL status (0x0130).

``ratio`` compares with the time the same frames need on a real segment:
frame bytes on the wire (Ethernet frame with FCS, at least 64 bytes, plus
preamble and inter-frame gap are left out: a lower bound, so the ratio errs
high) x 80 ns, plus the forwarding and cable delays of the walk (ET1200
and ET1100 forwarding delays of the profiles; each slave is passed twice)
once per cycle (the frames of a cycle follow each other on the wire).
Targets: ratio <= 0.25 at every size and mix; the cycle of 200 coe-io
slaves at most 3x the cycle of 200 do8 slaves.

Then a segment of 100 simulated CiA 402 servo drives in CSP on DC SYNC0
1 ms (``benchmarks/drive_frame.py`` has the set-up, and 1 and 10 drives):
the simulator's time for all frames of one cycle, including the drive
model's cycle of every drive, against their wire time (``cia402_100_*``,
not part of ``max_ratio``: the drives' physics come on top of the frame path).

Two more columns say where the rest of the time goes, for the cyclic frames:

- ``floor us``: the frames' data moves and register updates alone, on the
  segment's own compiled plans (the FMMU stages' gathers and scatters, the
  fused register program of each datagram, the working counter), with none
  of the bookkeeping around them (the frame parse, watchdogs, arrival, IRQ
  field, clock) and no device application: what any frame of that shape
  needs from numpy, the least the simulator could spend on it in Python.
  ``floor/wire`` is that against the wire time;
- ``no-app us``: the whole frame path with the device applications not
  told of new outputs (the CoE models' gather, compute and scatter left
  out): the frame path's share, the rest is theirs.

It also reports the build time of the 10,000-slave ``coe30`` segment from
its topology text (target < 10 s), and memory per simulated slave: the ESC
memory arrays per slave for each ESC profile, and the process's resident
memory growth per slave over the whole build.

``python benchmarks/sim_frame.py [SECONDS] [--quick]``: SECONDS per
measurement (default 1); ``--quick`` stops at 1000 slaves. The last output
line is one JSON object of all the figures, with the load average.
"""

from __future__ import annotations

import json
import os
import struct
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

from pyethercat.clock import VirtualClock
from pyethercat.sim.devices import DEVICES
from pyethercat.sim.devices.builtin import BuiltinDevice
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as R
from pyethercat.wire.datagram import HEADER_SIZE, MAX_DATA, WKC, Command, Datagram
from pyethercat.wire.frame import ECAT_HEADER_SIZE, ETH_HEADER_SIZE, decode_frame, encode_frame
from pyethercat.wire.sii import SyncManagerType

#: Datagram header + WKC: 12 bytes; a frame holds 1498 bytes of datagrams.
_PER_FRAME = MAX_DATA
_OUT_TYPES = (SyncManagerType.OUTPUTS,)
_IN_TYPES = (SyncManagerType.INPUTS,)


def kinds_of(n: int, mix: str) -> list[str]:
    """The device kinds of an ``n``-slave segment of ``mix``."""
    out = []
    for i in range(n):
        if mix == "coe30" and i % 10 in (1, 4, 7):
            out.append("coe-io")
        elif mix in ("dido", "coe30"):
            out.append("do8" if i % 2 else "di8")
        else:  # a single kind
            out.append(mix)
    return out


def topology_text(kinds: Sequence[str]) -> str:
    return "".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:{k}"\n' for i, k in enumerate(kinds))


def _send_all(seg: Segment, datagrams: list[Datagram]) -> list[Datagram]:
    """Send datagrams packed into frames (as many as fit); the replies in order."""
    replies: list[Datagram] = []
    batch: list[Datagram] = []
    size = 0

    def flush() -> None:
        nonlocal batch, size
        if batch:
            reply = seg.process(encode_frame(batch))
            assert reply is not None, "frame lost"
            replies.extend(decode_frame(reply).datagrams)
        batch, size = [], 0

    for d in datagrams:
        if size + 12 + len(d.data) > _PER_FRAME or len(batch) >= 100:
            flush()
        batch.append(d)
        size += 12 + len(d.data)
    flush()
    return replies


def _sm_bytes(start: int, length: int, control: int, enable: int) -> bytes:
    return struct.pack("<HHBBBB", start, length, control, 0, enable, 0)


def _fmmu(logical: int, length: int, phys: int, ftype: int) -> bytes:
    return struct.pack("<IHBBHBBB3x", logical, length, 0, 7, phys, 0, ftype, 1)


def configure(seg: Segment, kinds: Sequence[str]) -> tuple[int, int]:
    """Station addresses, SMs, FMMUs and OP, as a master would; (output bytes, image bytes)."""
    devs: list[BuiltinDevice] = [DEVICES.get_kind(k) for k in kinds]
    _send_all(seg, [Datagram.positional(Command.APWR, i, R.STATION_ADDRESS, struct.pack("<H", 0x1000 + i))
                    for i in range(len(devs))])
    out_total = sum(d.output_bytes for d in devs)
    writes: list[Datagram] = []
    out_at, in_at = 0, out_total
    for i, dev in enumerate(devs):
        st = 0x1000 + i
        fmmu = 0
        for n, sm in enumerate(dev.sync_managers):
            length = sm.length
            if sm.sm_type in _OUT_TYPES:
                length = dev.output_bytes
            elif sm.sm_type in _IN_TYPES:
                length = dev.input_bytes
            enable = 1 if length else 0
            writes.append(Datagram.device(Command.FPWR, st, R.sm_address(n),
                                          _sm_bytes(sm.start, length, sm.control, enable)))
            if sm.sm_type in _OUT_TYPES and length:
                writes.append(Datagram.device(Command.FPWR, st, R.fmmu_address(fmmu),
                                              _fmmu(out_at, length, sm.start, int(R.FmmuType.WRITE))))
                out_at += length
                fmmu += 1
            elif sm.sm_type in _IN_TYPES and length:
                writes.append(Datagram.device(Command.FPWR, st, R.fmmu_address(fmmu),
                                              _fmmu(in_at, length, sm.start, int(R.FmmuType.READ))))
                in_at += length
                fmmu += 1
    # The SM watchdog at 1 s (10,000 ticks of 100 us): one cycle of the 10,000-slave coe30
    # segment is 33 frames of 3.2 ms on the wire, longer than the default 100 ms, so the
    # first slaves' outputs would expire before the last frame of the cycle (0x001B).
    writes.append(Datagram.device(Command.BWR, 0, R.WATCHDOG_TIME_PROCESS_DATA, struct.pack("<H", 10_000)))
    _send_all(seg, writes)
    image = in_at
    for state in (2, 4):
        _send_all(seg, [Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", state))])
    for f in cycle_frames(image):
        seg.process(f)
    _send_all(seg, [Datagram.device(Command.BWR, 0, R.AL_CONTROL, struct.pack("<H", 8))])
    (status,) = _send_all(seg, [Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)])
    assert status.wkc == len(devs) and status.data[0] & 0x0F == 8, (status, "not all in OP")
    return out_total, image


def cycle_frames(image: int) -> list[bytes]:
    """The frames of one cycle: LRW datagrams over the image, one per frame."""
    return [encode_frame([Datagram.logical(Command.LRW, at, min(_PER_FRAME - 12, image - at))])
            for at in range(0, image, _PER_FRAME - 12)]


def measure(seg: Segment, frames: list[bytes], seconds: float) -> float:
    """Best time per cycle (all ``frames``) in seconds, over batches within ``seconds``."""

    def cycle() -> None:
        for f in frames:
            seg.process(f)

    return best_time(cycle, max(1, 50 // len(frames)) if len(seg.slaves) < 5000 else 2, seconds)


def best_time(cycle: Callable[[], None], batch: int, seconds: float) -> float:
    """Best time of one ``cycle()`` in seconds, over batches of ``batch`` within ``seconds``."""
    for _ in range(3):
        cycle()
    best = float("inf")
    deadline = time.perf_counter() + seconds
    while True:
        t0 = time.perf_counter()
        for _ in range(batch):
            cycle()
        best = min(best, (time.perf_counter() - t0) / batch)
        if time.perf_counter() >= deadline:
            return best


def measure_floor(seg: Segment, frames: list[bytes], seconds: float) -> float:
    """Best time per cycle of the frames' data moves and register updates alone (``floor us``
    in the module docstring): each frame copied, its LRW's FMMU stages applied to the
    segment's memory, its fused register program run, its working counter written."""
    memory = seg.memory
    flat, shadow = memory.flat, memory.shadow_flat
    doff = ETH_HEADER_SIZE + ECAT_HEADER_SIZE + HEADER_SIZE
    jobs = []
    for f in frames:
        (d,) = decode_frame(f).datagrams
        n = len(d.data)
        plan = seg.logical_plan(int(d.command), d.address, n)
        assert plan is not None and plan.fused is not None, "the cycle maps nothing"
        jobs.append((f, n, plan.stages, plan.fused, plan.wkc))

    def cycle() -> None:
        for f, n, stages, fused, wkc in jobs:
            buf = bytearray(f)
            data = np.frombuffer(buf, np.uint8, n, doff)
            for stage in stages:
                stage.apply(flat, data)
            fused.registers(flat, shadow)
            WKC.pack_into(buf, doff + n, wkc)
            bytes(buf)

    return best_time(cycle, max(1, 50 // len(frames)), seconds)


def measure_without_apps(seg: Segment, frames: list[bytes], seconds: float) -> float:
    """:func:`measure` with the device applications not told of new outputs (``no-app us``)."""
    apps = seg.apps
    listening = apps._listening
    apps._listening = False  # (what DeviceApps.outputs_completed checks first)
    try:
        return measure(seg, frames, seconds)
    finally:
        apps._listening = listening


def wire_time(seg: Segment, frames: list[bytes]) -> float:
    """Seconds the frames need on a real segment (see the module docstring)."""
    return (sum(max(len(f) + 4, 64) for f in frames) * seg.mac_wire_ns + seg.route.delay_ns) * 1e-9


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def build(kinds: Sequence[str]) -> tuple[Segment, float, float]:
    """The segment from its topology text; (segment, wall s, CPU s)."""
    text = topology_text(kinds)
    w0, c0 = time.perf_counter(), time.process_time()
    seg = parse_topology(text).build(clock=VirtualClock())
    return seg, time.perf_counter() - w0, time.process_time() - c0


def main() -> int:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    seconds = float(args[0]) if args else 1.0
    sizes = (10, 100, 1000) if "--quick" in sys.argv else (10, 100, 1000, 10_000)
    figures: dict[str, float | str] = {"load_average": " ".join(f"{x:.1f}" for x in os.getloadavg())}
    print(f"load average {figures['load_average']}")
    print("memory arrays per slave (ESC memory + complete-buffer shadow):")
    for name in ("ET1200", "LAN9252", "ET1100", "IPCORE"):
        per = EscMemory(1, PROFILES[name].ram_end).nbytes
        figures[f"mem_array_per_slave_{name}_bytes"] = per
        print(f"  {name:8} {per:>7} bytes")
    print(f"{'slaves':>6} {'mix':>6} {'frame':>8} {'frames':>6} {'sim us':>9} {'wire us':>9} {'ratio':>6} "
          f"{'floor us':>9} {'floor/wire':>10} {'no-app us':>9}")
    ratios: list[float] = []
    for n in sizes:
        for mix in ("dido", "coe30"):
            kinds = kinds_of(n, mix)
            rss0 = _rss()
            seg, wall, cpu = build(kinds)
            rss1 = _rss()
            _, image = configure(seg, kinds)
            if n == 10_000:
                figures[f"build_{n}_{mix}_s"] = round(wall, 2)
                figures[f"build_{n}_{mix}_cpu_s"] = round(cpu, 2)
                figures[f"rss_per_slave_{n}_{mix}_bytes"] = (rss1 - rss0) // n
                figures[f"mem_array_per_slave_{n}_{mix}_bytes"] = seg.memory.nbytes // n
                print(f"build {n} {mix}: {wall:.2f} s wall, {cpu:.2f} s CPU; resident memory "
                      f"+{(rss1 - rss0) // n} bytes/slave, memory arrays {seg.memory.nbytes // n} bytes/slave")
            cycle = cycle_frames(image)
            brd = [encode_frame([Datagram.device(Command.BRD, 0, R.AL_STATUS, 2)])]
            full = [encode_frame([Datagram.logical(Command.LRW, 0, MAX_DATA)])]
            for name, frames in (("cycle", cycle), ("lrw1486", full), ("brd0130", brd)):
                sim = measure(seg, frames, seconds)
                wire = wire_time(seg, frames)
                ratio = sim / wire
                ratios.append(ratio)
                extra = ""
                if name == "cycle":
                    no_app = measure_without_apps(seg, frames, seconds)
                    floor = measure_floor(seg, frames, seconds)
                    extra = f" {floor * 1e6:>9.1f} {floor / wire:>10.3f} {no_app * 1e6:>9.1f}"
                    figures[f"cycle_{n}_{mix}_floor_us"] = round(floor * 1e6, 2)
                    figures[f"cycle_{n}_{mix}_floor_ratio"] = round(floor / wire, 3)
                    figures[f"cycle_{n}_{mix}_no_app_us"] = round(no_app * 1e6, 2)
                print(f"{n:>6} {mix:>6} {name:>8} {len(frames):>6} {sim * 1e6:>9.1f} {wire * 1e6:>9.1f} "
                      f"{ratio:>6.3f}{extra}")
                figures[f"{name}_{n}_{mix}_sim_us"] = round(sim * 1e6, 2)
                figures[f"{name}_{n}_{mix}_wire_us"] = round(wire * 1e6, 2)
                figures[f"{name}_{n}_{mix}_ratio"] = round(ratio, 3)
            del seg
    per_kind: dict[str, float] = {}
    for kind in ("do8", "coe-io"):
        kinds = kinds_of(200, kind)
        seg, _, _ = build(kinds)
        _, image = configure(seg, kinds)
        per_kind[kind] = measure(seg, cycle_frames(image), seconds)
        figures[f"cycle_200_{kind}_sim_us"] = round(per_kind[kind] * 1e6, 2)
        if kind == "coe-io":
            no_app = measure_without_apps(seg, cycle_frames(image), seconds)
            figures["cycle_200_coe-io_no_app_us"] = round(no_app * 1e6, 2)
    factor = per_kind["coe-io"] / per_kind["do8"]
    figures["coe200_over_do200"] = round(factor, 2)
    figures["coe200_no_app_over_do200"] = round(no_app / per_kind["do8"], 2)
    print(f"200 coe-io cycle {per_kind['coe-io'] * 1e6:.1f} us, 200 do8 cycle {per_kind['do8'] * 1e6:.1f} us: "
          f"{factor:.2f}x (target <= 3); the coe-io frames without their model "
          f"{no_app * 1e6:.1f} us: {no_app / per_kind['do8']:.2f}x")
    from drive_frame import Rig  # this directory is on sys.path when run as a script

    rig = Rig(100)
    drives = min((rig.measure(100) for _ in range(3)), key=lambda r: r["cycle_us"])
    rig.finish()
    print(f"100 cia402 csp: cycle {drives['cycle_us']:.1f} us, wire {drives['wire_us']:.1f} us, "
          f"ratio {drives['ratio']:.2f} (one 1 ms cycle: {drives['frames_per_cycle']:g} frames, "
          f"drive model {drives['drives_us']:.0f} us)")
    for key in ("frame_us", "cycle_us", "wire_us", "ratio", "drives_us"):
        figures[f"cia402_100_{key}"] = drives[key]
    figures["max_ratio"] = max(ratios)
    print(f"max ratio {max(ratios):.3f} (target <= 0.25); load average now "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
