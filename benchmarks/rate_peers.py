"""High cycle rates with every pair of master and simulator: what the host itself allows.

Issue 18 asks for at most 0.1 % late cycles at 10 kHz with 10 slaves and at
4 kHz with 100 slaves, over a veth pair. ``master_cycle.py --rates`` measures
our engine against our simulator. This script runs the same rates with each
master against each simulator, on the same devices, in one invocation:

- masters: our isolated engine (``Master.start(isolated=True)``) and SOEM
  (pysoem in a SCHED_FIFO thread, send + receive each period, as its users
  run it; ``master_cycle.run_soem``);
- simulators: ``pyethercat sim`` and KickCAT's C++ ``network_simulator``
  (``../shared/tools/build-kickcat.sh``), both serving ``--slaves`` copies of
  KickCAT's Freedom-K64F example slave (LAN9252; our simulator builds it
  from the corpus ESI ``esi/kickcat_freedom-k64f.xml``, KickCAT's from its
  EEPROM dump and the same ESI).

SOEM against KickCAT is the pair with no Python on either side's frame
path: what it loses is this host's floor (wake-ups, the veth pair, the
vCPUs), not ours. Late: a start more than a quarter period after its
deadline, or a deadline skipped because the cycle before overran it; both
masters count the same way. SOEM reads the PDO layout without complete
access on both simulators (see ``sim_rtt.py``).

Needs root (veth pairs, SCHED_FIFO) and KickCAT's emulator (without it only
our simulator is measured). The last output line is one JSON object.

Usage: python benchmarks/rate_peers.py [--runs 10:10000,100:4000] [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

from common import (
    KICKCAT_BINARY,
    KICKCAT_SRC,
    guest_halt_poll,
    have_kickcat,
    host_idle,
    kickcat_simulator,
    veth,
)
from master_cycle import engine_at_rate, host_floor, print_rate, run_soem

from pyethercat.sim.sim_process import start_sim_process

ROOT = Path(__file__).resolve().parents[1]
ESI = ROOT.parent / "shared" / "corpus" / "esi" / "kickcat_freedom-k64f.xml"
KICKCAT_CONFIG = "slave_configs/freedom-k64f.json"
#: The simulators' SCHED_FIFO priority: below the masters' loops (``--priority``).
SIM_PRIORITY = 20


@contextmanager
def ours(iface: str, n: int) -> Iterator[None]:
    """``pyethercat sim`` serving ``n`` Freedom-K64F slaves on ``iface``."""
    with tempfile.TemporaryDirectory() as tmp:
        topo = Path(tmp) / "freedom.toml"
        topo.write_text("".join(f'[[slave]]\nname = "s{i}"\nesi = "{ESI}"\n\n' for i in range(n)))
        sim = start_sim_process(topo, link=f"iface:{iface}", realtime=SIM_PRIORITY)
        try:
            yield
        finally:
            sim.stop()


def kickcat(iface: str, n: int) -> AbstractContextManager[None]:
    """KickCAT's ``network_simulator`` serving ``n`` Freedom-K64F slaves on ``iface``."""
    return kickcat_simulator(iface, [KICKCAT_CONFIG] * n, SIM_PRIORITY)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="10:10000,100:4000",
                    help="SLAVES:HZ pairs, comma-separated")
    ap.add_argument("--seconds", type=float, default=10.0, help="per master, simulator and rate")
    ap.add_argument("--priority", type=int, default=40, help="the masters' SCHED_FIFO priority")
    ap.add_argument("--guest-halt-poll-ns", type=int, default=None, metavar="NS",
                    help="a KVM guest's idle vCPUs poll NS before they halt, for the runs")
    args = ap.parse_args()
    if os.geteuid() != 0:
        print(json.dumps({"error": "needs root (veth pairs, SCHED_FIFO)"}))
        sys.exit(1)
    if not ESI.exists():
        print(json.dumps({"error": f"{ESI} is missing (../shared/corpus)"}))
        sys.exit(1)
    sims: list[tuple[str, Callable[[str, int], AbstractContextManager[None]]]] = [("ours", ours)]
    if have_kickcat():
        sims.append(("kickcat", kickcat))
    else:
        print(f"KickCAT's network_simulator not at {KICKCAT_BINARY} (source {KICKCAT_SRC}): "
              "build it with ../shared/tools/build-kickcat.sh; measuring our simulator only")
    out: dict[str, object] = {"load_average_start": os.getloadavg(), "seconds": args.seconds,
                              "priority": args.priority}
    with guest_halt_poll(args.guest_halt_poll_ns):
        out["host_idle"] = host_idle()
        print(f"load average before: {out['load_average_start']}; host idle: {out['host_idle']}")
        out["runs"] = measure(args.runs, sims, args.seconds, args.priority)
    out["load_average_end"] = os.getloadavg()
    print(f"load average after: {out['load_average_end']}")
    print(json.dumps(out))


def measure(specs: str, sims: list[tuple[str, Callable[[str, int], AbstractContextManager[None]]]],
            seconds: float, priority: int) -> list[dict[str, object]]:
    """Every master against every simulator for each SLAVES:HZ of ``specs``, then the
    host's floor at that period."""
    runs: list[dict[str, object]] = []
    for spec in specs.split(","):
        n_text, hz_text = spec.split(":")
        n, hz = int(n_text), int(hz_text)
        period_ns = round(1e9 / hz)
        for sim_name, serve in sims:
            for master in ("engine", "soem"):
                a, b = veth()
                try:
                    with serve(a, n):
                        if master == "engine":
                            r = engine_at_rate(b, period_ns / 1e9, seconds, priority)
                        else:
                            r = run_soem(b, seconds, False, priority, period=period_ns,
                                         complete_access=False)
                finally:
                    subprocess.run(["ip", "link", "del", a], check=False, capture_output=True)
                r.update(master=master, simulator=sim_name)
                runs.append(r)
                print_rate(r, seconds, f"{master:>6} / {sim_name:<7}: ")
                time.sleep(0.5)
        floor = host_floor(min(seconds, 30.0), period_ns // 1000, priority)
        runs.append({"host_floor": floor, "rate_hz": hz})
    return runs


if __name__ == "__main__":
    main()
