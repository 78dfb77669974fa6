"""Start-up of a big mixed segment: our master brings ``pyethercat sim`` to OP over a veth pair.

The segment: a ``builtin:coupler`` and then N-1 terminals, 30 % of them
``builtin:coe-io`` (CoE mailbox, PDO mapping read by SDO), the rest
alternating ``di8``/``do8`` (default N = 1000). ``pyethercat sim`` serves it
on one end of a fresh veth pair (``pyecat-<tag>a/b``, removed afterwards);
our master opens the other end and the script times each phase of the
start-up: the scan (addresses, SII of every slave), the configuration (CoE
PDO mapping read from the coe-io slaves, process image), and the bring-up to
OP with cyclic frames running (``Master.start``), then checks that every
slave is in OP and that outputs come back through the coe-io loop.

Needs root (veth pair, raw socket). ``python benchmarks/sim_veth_op.py [N] [CYCLE_MS]``;
the last line is a JSON object of the figures with the load average.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import veth

from pyethercat.errors import EtherCATError
from pyethercat.master import Master
from pyethercat.sim.server import start_sim_process
from pyethercat.wire.al import AlState


def topology(n: int) -> str:
    kinds = ["coupler"] + ["coe-io" if i % 10 in (1, 4, 7) else ("do8" if i % 2 else "di8")
                           for i in range(1, n)]
    return "".join(f'[[slave]]\nname = "s{i}"\ndevice = "builtin:{k}"\n' for i, k in enumerate(kinds))


def main() -> int:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    cycle = (float(sys.argv[2]) if len(sys.argv) > 2 else 10.0) / 1000
    if os.geteuid() != 0:
        print("needs root (a veth pair and a raw socket): run with sudo", file=sys.stderr)
        return 2
    figures: dict[str, object] = {"slaves": n, "cycle_ms": cycle * 1000,
                                  "load_average": " ".join(f"{x:.1f}" for x in os.getloadavg())}
    a, b = veth()
    try:
        with tempfile.TemporaryDirectory(prefix="pyecat-bench-") as tmp:
            topo = Path(tmp) / "seg.toml"
            topo.write_text(topology(n))
            t = time.perf_counter()
            with start_sim_process(topo, link=f"iface:{b}", ready_timeout=300.0):
                figures["sim_ready_s"] = round(time.perf_counter() - t, 2)
                # A frame of AL control writes to hundreds of slaves keeps the simulator
                # busy for tens of ms (one ESC after the other in Python): 2 s per try.
                with Master.open(iface=a, timeout=2.0) as m:
                    t0 = time.perf_counter()
                    slaves = m.scan()
                    t1 = time.perf_counter()
                    cfg = m.configure()
                    t2 = time.perf_counter()
                    figures.update(found=len(slaves), groups=len(cfg.groups), scan_s=round(t1 - t0, 2),
                                   configure_s=round(t2 - t1, 2))
                    try:
                        runner = m.start(cycle=cycle, timeout=120.0)
                    except EtherCATError as exc:  # the phases so far are still figures
                        figures["error"] = f"start: {type(exc).__name__}: {exc}"[:300]
                        figures["failed_after_s"] = round(time.perf_counter() - t2, 2)
                        runner = None
                    if runner is not None:
                        with runner:
                            t3 = time.perf_counter()
                            in_op = sum(s.al_state == AlState.OP for s in m.slaves)
                            coe = [s for s in m.slaves if s.name.startswith("PEC-COEIO")]
                            for k, s in enumerate(coe):
                                s.outputs["Value 16"] = k
                            time.sleep(10 * cycle)
                            echoed = sum(s.inputs["Value 16"] == k for k, s in enumerate(coe))
                            figures["wkc_errors"] = runner.stats.wkc_errors
                        figures.update(in_op=in_op, coe_io=len(coe), echoed=echoed,
                                       to_op_s=round(t3 - t2, 2), startup_s=round(t3 - t0, 2))
    finally:
        subprocess.run(["ip", "link", "del", a], check=False, capture_output=True)
    figures["load_average_end"] = " ".join(f"{x:.1f}" for x in os.getloadavg())
    if "error" in figures:
        print(f"{n} slaves: scan {figures['scan_s']} s, configure {figures['configure_s']} s, then "
              f"{figures['error']} after {figures['failed_after_s']} s")
    else:
        print(f"{n} slaves ({figures['coe_io']} coe-io): scan {figures['scan_s']} s, configure "
              f"{figures['configure_s']} s, to OP {figures['to_op_s']} s; start-up {figures['startup_s']} s; "
              f"{figures['in_op']} in OP, {figures['echoed']}/{figures['coe_io']} coe-io echo their outputs")
    print(json.dumps(figures))
    return 0 if figures.get("in_op") == n == figures.get("found") else 1


if __name__ == "__main__":
    raise SystemExit(main())
