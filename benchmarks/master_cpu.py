"""The master's own cost per frame: CPU time and instruction counts, independent of the load.

Wall-clock throughput on a shared machine measures the machine; what our
code costs per FoE packet and per cyclic cycle does not depend on it. This
script measures the master alone: ``pyethercat sim`` serves the segment in a
child process over a socketpair (no root, no veth), and only this process
(the master) is counted.

Only the work is counted, not the waiting: the scheduler's poll for a reply
(``reply_spin``) and the loop clock's spin before a deadline are off here
(both poll for as long as the other side takes, which is the load's figure).

(a) FoE: a file written and read back (``builtin:coe-io`` with ``foe = true``,
    128-byte mailboxes: 116 bytes per packet); the master's CPU time per
    packet (``time.process_time``: this process only, the simulator is another);
(b) cycles: ``exchange_once`` (the loop's exchange path: outputs into the
    frame, send, wait, inputs back, one WKC check per datagram) and the
    cyclic loop itself (``run(cycles=N)`` at 1 kHz: the same plus statistics,
    supervision, riders, the wait), 10 and 100 slaves; CPU time per cycle.

``--callgrind`` runs each part under ``valgrind --tool=callgrind`` twice with
two sizes (only this process is instrumented; the simulator runs natively)
and prints the instructions per packet and per cycle from the difference
(start-up cancels out): the load-independent figure to compare trees with.

The last output line is one JSON object of figures.
Usage: python benchmarks/master_cpu.py [--callgrind] [--part foe|cycle|all]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FOE_TOPOLOGY = '[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\nfoe = true\n'
#: Bytes that compress badly (made in C: under callgrind a Python loop would dominate).
FOE_FILE = random.Random(15).randbytes(1 << 20)
FOE_PACKET = 116
#: The simulator serves under SCHED_FIFO when allowed (root), so that other work on a
#: shared machine does not starve it into the master's frame timeouts.
SIM_PRIORITY = 10


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def topology(n: int) -> str:
    """A coupler and do8/di8 pairs wired back to back (as benchmarks/master_cycle.py)."""
    parts = ['[[slave]]\nname = "coupler"\ndevice = "builtin:coupler"\n']
    wires = []
    for i in range((n - 1) // 2):
        parts.append(f'[[slave]]\nname = "do{i}"\ndevice = "builtin:do8"\n')
        parts.append(f'[[slave]]\nname = "di{i}"\ndevice = "builtin:di8"\n')
        wires.append(f'[[wire]]\nfrom = "do{i}:0"\nto = "di{i}:0"\n')
    if (n - 1) % 2:
        parts.append('[[slave]]\nname = "extra"\ndevice = "builtin:di2"\n')
    return "\n".join(parts + wires)


def foe_part(size: int) -> dict[str, float]:
    """FoE write and read back of ``size`` bytes; the master's CPU per packet."""
    from pyethercat.master.foe import FoeClient
    from pyethercat.master.master import Master
    from pyethercat.sim.server import start_sim_process

    with tempfile.TemporaryDirectory(prefix="pyecat-mcpu-") as tmp:
        topo = Path(tmp) / "foe.toml"
        topo.write_text(FOE_TOPOLOGY)
        with start_sim_process(topo, link="unix", realtime=SIM_PRIORITY) as sim, \
                Master(sim.link, owns_link=False, timeout=0.2) as m:
            m.scan()
            m.set_state("PREOP")
            # Count the work, not the waiting: no polling for the reply before blocking.
            m.scheduler.reply_spin = 0.0
            mbx = m.slaves[0].mbx
            assert mbx is not None
            foe = FoeClient(mbx)
            blob = FOE_FILE[:size]
            foe.write("warm.bin", blob[:4096])
            c0, t0 = time.process_time(), time.perf_counter()
            foe.write("bench.bin", blob)
            c1, t1 = time.process_time(), time.perf_counter()
            back = foe.read("bench.bin")
            c2, t2 = time.process_time(), time.perf_counter()
            if back != blob:
                raise RuntimeError("FoE read back differs from what was written")
            packets = size // FOE_PACKET + 1
            m.set_state("INIT")
    return {"foe_bytes": size, "foe_packets": packets,
            "foe_write_cpu_us_per_packet": (c1 - c0) / packets * 1e6,
            "foe_read_cpu_us_per_packet": (c2 - c1) / packets * 1e6,
            "foe_write_wall_us_per_packet": (t1 - t0) / packets * 1e6,
            "foe_read_wall_us_per_packet": (t2 - t1) / packets * 1e6}


def cycle_part(n: int, cycles: int) -> dict[str, float]:
    """``exchange_once`` and the 1 kHz in-process loop, ``cycles`` each; CPU per cycle."""
    from pyethercat.clock import PerfClock
    from pyethercat.master.master import Master
    from pyethercat.sim.server import start_sim_process

    with tempfile.TemporaryDirectory(prefix="pyecat-mcpu-") as tmp:
        topo = Path(tmp) / f"seg{n}.toml"
        topo.write_text(topology(n))
        with start_sim_process(topo, link="unix", realtime=SIM_PRIORITY) as sim, \
                Master(sim.link, owns_link=False, timeout=0.2) as m:
            m.scan()
            m.configure()
            m.scheduler.reply_spin = 0.0  # (the work, not the waiting: see foe_part)
            runner = m.start(cycle=0.001, isolated=False, clock=PerfClock(spin_ns=0))
            runner.halt()
            for _ in range(50):
                runner.exchange_once()
            c0, t0 = time.process_time(), time.perf_counter()
            ok = sum(runner.exchange_once() for _ in range(cycles))
            c1, t1 = time.process_time(), time.perf_counter()
            before = runner.stats.cycles
            # The loop in this thread for exactly ``cycles`` cycles (halt() above set the
            # stop flag that run() obeys).
            runner._stop.clear()  # noqa: SLF001 - a benchmark drives the loop directly
            stats = runner.run(cycles=cycles)
            c2 = time.process_time()
            ran = stats.cycles - before
            m.set_state("INIT")
    return {f"exchange_{n}_cpu_us": (c1 - c0) / cycles * 1e6,
            f"exchange_{n}_wall_us": (t1 - t0) / cycles * 1e6,
            f"exchange_{n}_ok": ok / cycles,
            f"loop_{n}_cpu_us": (c2 - c1) / ran * 1e6,
            f"loop_{n}_lost": float(stats.lost_frames),
            f"loop_{n}_late": float(stats.late)}


def run_parts(part: str, foe_size: int, cycles: int, sizes: list[int]) -> dict[str, float]:
    out: dict[str, float] = {}
    if part in ("foe", "all"):
        out.update(foe_part(foe_size))
    if part in ("cycle", "all"):
        for n in sizes:
            out.update(cycle_part(n, cycles))
    return out


def _callgrind(args: list[str]) -> int:
    """Instructions of this script run with ``args`` under callgrind (this process only)."""
    with tempfile.TemporaryDirectory(prefix="pyecat-cg-") as tmp:
        out = Path(tmp) / "cg.out"
        done = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                               sys.executable, __file__, "--inner", *args],
                              check=False, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True)
        if done.returncode:
            raise RuntimeError(f"callgrind run {args} failed: {done.stderr[-2000:]}")
        text = out.read_text(errors="replace")
    m = re.search(r"^summary:\s+(\d+)", text, re.M) or re.search(r"^totals:\s+(\d+)", text, re.M)
    if m is None:
        raise RuntimeError("callgrind wrote no summary")
    return int(m.group(1))


def callgrind_figures(part: str, sizes: list[int]) -> dict[str, float]:
    """Instructions per FoE packet and per cycle, from two runs of different length."""
    out: dict[str, float] = {}
    if part in ("foe", "all"):
        small, big = 16 * 1024, 64 * 1024
        a = _callgrind(["--part", "foe", "--foe-kib", str(small // 1024)])
        b = _callgrind(["--part", "foe", "--foe-kib", str(big // 1024)])
        # write and read: two packets' worth of round trips per 116 bytes
        packets = 2 * ((big - small) // FOE_PACKET)
        out["foe_instructions_per_packet"] = (b - a) / packets
    if part in ("cycle", "all"):
        for n in sizes:
            a = _callgrind(["--part", "cycle", "--sizes", str(n), "--cycles", "100"])
            b = _callgrind(["--part", "cycle", "--sizes", str(n), "--cycles", "300"])
            # 200 more exchange_once calls and 200 more loop cycles
            out[f"cycle_{n}_instructions_per_exchange_and_loop_cycle"] = (b - a) / 200
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("foe", "cycle", "all"), default="all")
    ap.add_argument("--foe-kib", type=int, default=1024, help="FoE file size (KiB)")
    ap.add_argument("--cycles", type=int, default=3000, help="cycles per cycle measurement")
    ap.add_argument("--sizes", default="10,100", help="slave counts of the cycle part")
    ap.add_argument("--callgrind", action="store_true",
                    help="also count instructions (valgrind; several minutes)")
    ap.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.inner:
        run_parts(args.part, args.foe_kib * 1024, args.cycles, sizes)
        return
    print(f"load average at start: {_load()}")
    figures: dict[str, object] = {"load_start": _load()}
    got = run_parts(args.part, args.foe_kib * 1024, args.cycles, sizes)
    figures.update(got)
    if "foe_packets" in got:
        print(f"FoE {args.foe_kib} KiB ({got['foe_packets']:.0f} packets each way): master CPU "
              f"per packet write {got['foe_write_cpu_us_per_packet']:.1f} us, read "
              f"{got['foe_read_cpu_us_per_packet']:.1f} us; wall per packet write "
              f"{got['foe_write_wall_us_per_packet']:.1f} us, read "
              f"{got['foe_read_wall_us_per_packet']:.1f} us")
    for n in sizes if args.part in ("cycle", "all") else []:
        print(f"{n} slaves: exchange_once CPU {got[f'exchange_{n}_cpu_us']:.1f} us "
              f"(wall {got[f'exchange_{n}_wall_us']:.1f} us), 1 kHz loop CPU per cycle "
              f"{got[f'loop_{n}_cpu_us']:.1f} us (lost {got[f'loop_{n}_lost']:.0f}, late "
              f"{got[f'loop_{n}_late']:.0f} of {args.cycles})")
    if args.callgrind:
        cg = callgrind_figures(args.part, sizes)
        figures.update(cg)
        for k, v in cg.items():
            print(f"callgrind {k}: {v:,.0f}")
    figures["load_end"] = _load()
    print(f"load average at end: {_load()}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
