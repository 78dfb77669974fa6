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

With ``--interop`` (root: veth pairs), last the interop run of the ring:
SOEM (pysoem, redundant open), KickCAT's master (redundant link) and ours
at 1 kHz over two veth pairs while the middle cable is pulled and plugged
ten times (``tests/interop/test_ring_interop.py``, run through pytest; its
figures come back through the JUnit XML): cycles, cycles with a wrong
working counter, cycles with wrong data, lost frames.

Then each target (at most 1 bad cycle per fault, 0 between frames, 100 %
located, link recovery within 1 cycle, back in OP within 100 ms, the bad
cable named within 1 s, interop) with "met" or "NOT MET". The load
average is printed before and after (figures of a loaded machine
are provisional). The last output line is one JSON object of the figures.
Usage: python benchmarks/redundancy.py [--seconds 60] [--faults 100] [--slaves 20] [--seed 1]
                                       [--crc-seeds 10] [--interop]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from pyethercat.cli.ring_experiment import crc_naming, run_experiment

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "examples" / "demo.toml"
INTEROP = "tests/interop/test_ring_interop.py"


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def interop() -> dict[str, Any]:
    """Run the ring interop tests; each master's figures (or why it has none)."""
    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "ring.xml"
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               INTEROP, f"--junitxml={xml}"], cwd=REPO, capture_output=True,
                              text=True, check=False)
        if not xml.exists():
            raise SystemExit(f"interop run failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
        figures: dict[str, Any] = {}
        for case in ET.parse(xml).iter("testcase"):
            name = case.get("name", "")
            who = next(w for w in ("soem", "kickcat", "our") if w in name)
            props = {p.get("name"): int(p.get("value", "0")) for p in case.iter("property")}
            outcome = ("skipped" if case.find("skipped") is not None else
                       "FAILED" if case.find("failure") is not None or case.find("error")
                       is not None else "passed")
            figures[who] = {"outcome": outcome, **props}
        return figures


def verdicts(summary: dict[str, Any], cycle_s: float) -> list[tuple[str, bool]]:
    """Each target of the experiment, the bad cable and the interop run, and whether it was met."""
    after = summary["crc_cycles_after_first_error_max"]
    out = [
        ("at most 1 lost or incomplete cycle per fault", summary["bad_cycles_max"] <= 1),
        ("0 for faults between frames", summary["bad_cycles_max_between_frames"] == 0),
        ("100 % of the faults located where injected", summary["located_pct"] == 100.0),
        ("link faults recovered within 1 cycle", summary["recovery_cycles_max_link"] <= 1),
        ("slaves plugged back in OP within 100 ms",
         summary["back_in_op_ms_max"] is None or summary["back_in_op_ms_max"] <= 100),
        ("a bad cable named within 1 s of its first CRC error",
         after is not None and after * cycle_s <= 1.0
         and summary["crc_named"].split("/")[0] == summary["crc_named"].split("/")[1]),
    ]
    for who, f in summary.get("interop", {}).items():
        out.append((f"interop {who}: full WKC and right data through 10 cable pulls",
                    f["outcome"] == "passed" and f.get("wrong_wkc") == 0
                    and f.get("bad_data") == 0 and f.get("pulls") == 10))
    return out


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
    ap.add_argument("--interop", action="store_true",
                    help="also run SOEM, KickCAT and ours on the ring over veth pairs (root)")
    args = ap.parse_args()
    if args.interop and os.geteuid() != 0:
        raise SystemExit("--interop makes veth pairs: run as root (or with CAP_NET_ADMIN)")
    load_before = load()
    print(f"load average before: {load_before}")
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
    if args.interop:
        figures = interop()
        for who, f in figures.items():
            print(f"interop {who}: {f['outcome']}, {f.get('cycles', '-')} cycles, "
                  f"{f.get('pulls', '-')} pulls and plugs, {f.get('wrong_wkc', '-')} with a wrong "
                  f"WKC, {f.get('bad_data', '-')} with wrong data, {f.get('lost', '-')} lost")
        summary["interop"] = figures
    summary["load_before"] = load_before
    checks = verdicts(summary, args.cycle_us / 1e6)
    for text, ok in checks:
        print(f"{'met' if ok else 'NOT MET':>7}  {text}")
    summary["targets_met"] = all(ok for _, ok in checks)
    print(f"load average after: {load()}")
    summary["load_after"] = load()
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
