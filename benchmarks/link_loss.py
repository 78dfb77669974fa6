"""Link loss while cycling: lost cycles, deadlines kept, time back to OP.

The demo segment (``examples/demo.toml``: coupler, di8, do8, di2, ai2 and a
do8 on a branch) is served by ``pyethercat sim`` in a child process
(SCHED_FIFO 10) on one end of a veth pair; our master cycles at 1 ms on the
other end. Then:

- the far end of the pair goes down for 0.2 s and for 10 s (``--quick``: 0.2 s
  and 2 s): cycles lost (``down_cycles``), the spell as the loop measured it,
  overruns and skipped deadlines during the spell (the loop keeps its
  deadlines when both stay near zero), and the time from the link's return to
  every slave in OP again (the do8s ran into their 100 ms process-data
  watchdog and are acknowledged and requested to OP again);
- the simulator is killed and a new one started: time from the new
  simulator's first answer to every slave in OP (station addresses, SII
  identity, mailbox and process-data configuration, INIT -> OP).

Never asserted in tests. Needs root (veth). The last output line is one JSON
object of figures. Usage: python benchmarks/link_loss.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from common import veth

from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.sim.server import start_sim_process

DEMO = Path(__file__).resolve().parents[1] / "examples" / "demo.toml"


def wait_for(cond: Callable[[], bool], seconds: float) -> float | None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if cond():
            return time.monotonic() - t0
        time.sleep(0.002)
    return None


def all_ok(r: CyclicRunner) -> bool:
    return r.stats.link_up and all(h.status == "ok" for h in r.health.values())


def drop(r: CyclicRunner, sim_end: str, seconds: float) -> dict[str, float | int | None]:
    st = r.stats
    before = (st.down_cycles, st.overruns, st.skipped, st.cycles, st.down_ns)
    subprocess.run(["ip", "link", "set", sim_end, "down"], check=True)
    time.sleep(seconds)
    during = (st.overruns, st.skipped, st.cycles)
    subprocess.run(["ip", "link", "set", sim_end, "up"], check=True)
    up = wait_for(lambda: st.link_up, 30)
    back = wait_for(lambda: all_ok(r), 30)
    time.sleep(0.5)
    return {"drop_s": seconds, "down_cycles": st.down_cycles - before[0],
            "spell_s": (st.down_ns - before[4]) / 1e9,
            "cycles_during": during[2] - before[3],
            "overruns_during": during[0] - before[1], "skipped_during": during[1] - before[2],
            "link_up_after_s": up, "all_op_after_link_up_s": back}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s instead of 10 s for the long drop")
    args = ap.parse_args()
    a, b = veth()
    figures: dict[str, object] = {}
    sim = start_sim_process(DEMO, link=f"iface:{b}", realtime=10)
    try:
        with Master.open(iface=a) as m:
            m.scan()
            m.configure()
            with m.start(cycle=0.001) as r:
                time.sleep(2)
                st = r.stats
                figures["steady"] = {"cycles": st.cycles, "overruns": st.overruns,
                                     "skipped": st.skipped}
                for seconds in (0.2, 2.0 if args.quick else 10.0):
                    got = drop(r, b, seconds)
                    figures[f"drop_{seconds:g}s"] = got
                    print(f"far end down {seconds:g} s: {got['down_cycles']} cycles lost "
                          f"(spell {got['spell_s']:.3f} s), overruns {got['overruns_during']} "
                          f"and skipped {got['skipped_during']} of {got['cycles_during']} cycles "
                          f"meanwhile; link up {got['link_up_after_s']} s after the cable, all "
                          f"in OP {got['all_op_after_link_up_s']} s after that")
                sim.process.kill()
                sim.stop()
                if wait_for(lambda: not r.stats.link_up, 5) is None:
                    print("the killed simulator was not noticed")
                sim = start_sim_process(DEMO, link=f"iface:{b}", realtime=10)
                up = wait_for(lambda: r.stats.link_up, 30)
                back = wait_for(lambda: all_ok(r), 30)
                figures["restart"] = {"link_up_after_serving_s": up,
                                      "all_op_after_link_up_s": back}
                print(f"simulator killed and restarted: link up {up} s after it served, all "
                      f"slaves in OP {back} s after that")
            figures["stop_report"] = r.stop_report
            print(r.stop_report)
    finally:
        sim.stop()
        subprocess.run(["ip", "link", "del", a], check=False)
    print(json.dumps(figures))


if __name__ == "__main__":
    if sys.platform != "linux":
        raise SystemExit("needs Linux (veth pairs)")
    main()
