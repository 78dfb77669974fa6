"""Cable redundancy: a 20-slave ring at 1 kHz for 60 s through 100 random single faults.

The experiment of Huan, Xiao and Liu ("Research of redundancy and hot swap
technology in industrial Ethernet EtherCAT"), on the simulated ring in this
process and in virtual time (``pyethercat.cli.ring_experiment``; repeatable,
the wall-clock time it took is printed too): cable pulls between any two
neighbours, port A and port B faults, nodes switched off and on, slaves
hot-swapped (the same one or a fresh device of its kind); a share of the
faults strikes while a frame is on the wire. Printed: the application's
send and receive counters, cycles with stale data of a slave present, the
master's working-counter verdicts, per fault the bad cycles, where the
master located it (against where it was injected), the recovery in cycles
and, for slaves plugged back, the time until they were in OP exchanging data.

Then a bad cable: CRC errors on 1e-3 of the frames crossing the branch cable
of examples/demo.toml (a tree) while a one-port master cycles at 1 kHz, for
``--crc-seeds`` seeds: cycles until the first corrupted frame and until the
master named the cable.

The last output line is one JSON object of the figures.
Usage: python benchmarks/redundancy.py [--seconds 60] [--faults 100] [--slaves 20] [--seed 1]
                                       [--crc-seeds 10]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pyethercat.cli.ring_experiment import crc_naming, run_experiment

DEMO = Path(__file__).resolve().parents[1] / "examples" / "demo.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--faults", type=int, default=100)
    ap.add_argument("--slaves", type=int, default=20)
    ap.add_argument("--cycle-us", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--in-flight", type=float, default=0.2,
                    help="share of faults struck while a frame is on the wire")
    ap.add_argument("--crc-seeds", type=int, default=10)
    args = ap.parse_args()
    t0 = time.monotonic()
    result = run_experiment(slaves=args.slaves, cycle=args.cycle_us / 1e6, seconds=args.seconds,
                            faults=args.faults, seed=args.seed, in_flight=args.in_flight)
    wall = time.monotonic() - t0
    for line in result.lines():
        print(line)
    print(f"wall-clock time {wall:.1f} s for {args.seconds:g} s of virtual time "
          f"({wall / max(1, result.cycles) * 1e6:.0f} us per cycle)")
    summary = result.summary()
    summary["wall_s"] = round(wall, 1)
    summary["seed"] = args.seed
    crc = []
    for seed in range(1, args.crc_seeds + 1):
        # the demo's branch cable: coupler (sim index 0) port 3 to the do8 on it
        first, named, where = crc_naming(str(DEMO), 0, 3, 1e-3, seed=seed)
        crc.append((first, named))
        print(f"bad cable, seed {seed}: first CRC error after {first} cycles, named after "
              f"{named} cycles: {where}")
    delays = [n - f for f, n in crc if f is not None and n is not None]
    named_all = [n for _, n in crc if n is not None]
    summary["crc_named"] = f"{len(named_all)}/{len(crc)}"
    summary["crc_cycles_after_first_error_max"] = max(delays, default=None)
    summary["crc_cycles_to_name_max"] = max(named_all, default=None)
    summary["crc_cycles_to_name_median"] = sorted(named_all)[len(named_all) // 2] if named_all else None
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
