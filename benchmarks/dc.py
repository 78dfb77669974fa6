"""Distributed clocks on a simulated 50-slave tree, on virtual time: how well and how fast.

The tree is examples/dc-tree-50.toml (a cross, forks on ports 1-3, every
oscillator off by up to +-100 ppm). Master and simulator share one virtual
clock, so every figure below is exact and repeatable (the wall-clock time the
simulation took is printed too):

(a) the set-up: delay error against the simulator's walk (max |ns|), the
    static drift compensation (FRMW, frames, virtual duration), the worst
    |0x092C| after it;
(b) the SYNC0 spread (latest minus earliest true time of one pulse over all
    46 terminals) with the static compensation alone, after 0.2/1/10 s
    without any cyclic FRMW;
(c) with 1 kHz cyclic compensation (master follows the reference): the
    largest spread over ``--seconds`` (60), before and after one slave's
    oscillator steps by 20 ppm half-way;
(d) time until the spread stays below 100 ns, with and without the static
    compensation.

``--plot DIR`` writes dc-setup.png (|0x092C| per slave during the
compensation), dc-run.png (monitor, phase lock, SYNC0 spread over the run)
for docs/dc.md. The last output line is one JSON object of figures.
Usage: python benchmarks/dc.py [--seconds 60] [--plot docs/img]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.dc import DcReport, DcSettings
from pyethercat.master.dc_loop import DcCycle
from pyethercat.master.master import Master
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import load_topology

TREE = Path(__file__).resolve().parents[1] / "examples" / "dc-tree-50.toml"
EPOCH = 800_000_000_000_000_000


class Bench:
    """One simulated tree, its master, set up (optionally without static compensation)."""

    def __init__(self, static: int, trace: bool = False) -> None:
        self.clock = VirtualClock(1_000_000_000)
        self.seg: Segment = load_topology(TREE).build(clock=self.clock)
        self.m = Master(PairLink.responder_link(self.seg.process), clock=self.clock)
        self.m.dc.master_time = lambda: self.clock.now_ns() + EPOCH
        self.m.scan()
        t = time.perf_counter()
        self.report: DcReport = self.m.dc.setup(
            DcSettings(static_sync=static, trace_every=250 if trace else 0))
        self.setup_wall = time.perf_counter() - t
        self.m.configure()
        self.m.dc.configure_sync(1_000_000)
        self.m.pd.bring_up(self.m.slaves, 5.0)

    def delay_error(self) -> int:
        route = self.seg.route
        passes = route.passes.tolist()
        ref = passes[self.report.reference or 0]
        return max(abs(int(s.delay_ns) - int(route.epu_ns[passes[s.position]] - route.epu_ns[ref]))
                   for s in self.report.slaves if s.delay_ns is not None)

    def runner(self, dc: bool) -> tuple[CyclicRunner, DcCycle | None]:
        plan = self.m.dc.cycle(1_000_000, "master", self.clock) if dc else None
        r = CyclicRunner(self.m.scheduler, self.m.process_data, self.m.images, self.m.slaves,
                         cycle=0.001, clock=self.clock, check_interval=0, dc=plan)
        return r, plan

    def spread(self) -> tuple[float, int]:
        """Largest spread of the recorded pulses every pulsing slave fired, and how many."""
        sys_, true = self.seg.dc.sync.recorded_pulses()
        pulsing = np.nonzero(self.seg.dc.sync.pulses[: len(self.seg.slaves)] > 0)[0]
        if not len(pulsing):
            return 0.0, 0
        rows_sys, rows_true = sys_[pulsing], true[pulsing]
        worst, seen = 0.0, 0
        for value in np.unique(rows_sys[0]):
            hit = rows_sys == value
            if value == 0 or not hit.any(axis=1).all():
                continue
            times = rows_true[hit]
            worst = max(worst, float(times.max() - times.min()))
            seen += 1
        return worst, seen


def converge(static: int, limit_s: float = 10.0) -> float | None:
    """Virtual seconds from the first cyclic frame until the spread stays below 100 ns (for 1 s)."""
    b = Bench(static)
    r, _ = b.runner(True)
    start = b.clock.now_ns()
    below_since: int | None = None
    while b.clock.now_ns() - start < limit_s * 1e9:
        r.run(seconds=0.05)
        spread, seen = b.spread()
        if not seen:
            continue
        if spread < 100:
            if below_since is None:
                below_since = b.clock.now_ns()
            elif b.clock.now_ns() - below_since >= 1e9:
                # (pulses start 100 ms after the SYNC set-up, before the first frame)
                return max(0.0, (below_since - start) / 1e9 - 0.05)
        else:
            below_since = None
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of the cyclic run (c)")
    ap.add_argument("--plot", default=None, metavar="DIR", help="write dc-setup.png and dc-run.png")
    args = ap.parse_args()
    out: dict[str, object] = {}

    # (a) set-up
    b = Bench(15_000, trace=True)
    rep = b.report
    out["delay_error_max_ns"] = b.delay_error()
    out["static_frmw"] = rep.static_sync
    out["static_frames"] = rep.static_frames
    out["setup_virtual_ms"] = round(rep.duration_s * 1e3, 1)
    out["setup_wall_s"] = round(b.setup_wall, 2)
    out["worst_092c_after_static_ns"] = rep.worst_difference_ns
    print(f"(a) 50 slaves: delays within {out['delay_error_max_ns']} ns of the simulator's; "
          f"static compensation {rep.static_sync} FRMW in {rep.static_frames} frames, "
          f"{out['setup_virtual_ms']} ms (virtual; {out['setup_wall_s']} s wall); "
          f"worst |0x092C| after it {rep.worst_difference_ns} ns")
    if args.plot:
        from pyethercat.cli.dc_plot import plot_dc

        Path(args.plot).mkdir(parents=True, exist_ok=True)
        plot_dc(str(Path(args.plot) / "dc-setup.png"), rep,
                title="static drift compensation, 50 slaves +-100 ppm")

    # (b) static compensation alone: cycles without the DC datagram
    r, _ = b.runner(False)
    alone = {}
    elapsed = 0.0
    for mark in (0.2, 1.0, 10.0):  # (the first pulses come 0.1 s after the SYNC set-up)
        r.run(seconds=mark - elapsed)
        elapsed = mark
        alone[mark] = b.spread()[0]
    out["static_only_spread_ns"] = {str(k): round(v, 1) for k, v in alone.items()}
    print("(b) static compensation alone, SYNC0 spread: "
          + ", ".join(f"after {k:g} s {v:.0f} ns" for k, v in alone.items()))

    # (c) 1 kHz compensation with a 20 ppm step half-way
    c = Bench(15_000)
    r, plan = c.runner(True)
    assert plan is not None
    start = c.clock.now_ns()
    before = after = 0.0
    series: list[tuple[float, float]] = []
    stepped = False
    wall = time.perf_counter()
    while c.clock.now_ns() - start < args.seconds * 1e9:
        r.run(seconds=0.05)
        spread, seen = c.spread()
        if seen:
            series.append(((c.clock.now_ns() - start) / 1e9, spread))
        if stepped:
            after = max(after, spread)
        else:
            before = max(before, spread)
        if not stepped and c.clock.now_ns() - start >= args.seconds * 0.5e9:
            drift = c.seg.dc_report()[7]["drift_ppm"]
            assert isinstance(drift, float)
            c.seg.set_drift(7, drift + 20.0)
            stepped = True
    wall = time.perf_counter() - wall
    out["run_seconds"] = args.seconds
    out["spread_max_ns"] = round(before, 1)
    out["spread_max_after_step_ns"] = round(after, 1)
    out["spread_median_ns"] = round(float(np.median([s for _, s in series])), 1)
    out["run_wall_s"] = round(wall, 1)
    out["wkc_errors"] = r.stats.wkc_errors
    print(f"(c) 1 kHz compensation, {args.seconds:g} s: SYNC0 spread max {before:.0f} ns "
          f"(median {out['spread_median_ns']} ns), after a 20 ppm step max {after:.0f} ns; "
          f"phase error {plan.lock.error_ns if plan.lock else '-'} ns; "
          f"{r.stats.cycles} cycles in {wall:.0f} s wall")
    if args.plot:
        plot_dc(str(Path(args.plot) / "dc-run.png"), None, plan, series,
                title=f"1 kHz compensation, 50 slaves, 20 ppm step at {args.seconds / 2:g} s")

    # (d) convergence
    with_static = converge(15_000)
    without = converge(0)
    out["converge_100ns_s"] = with_static
    out["converge_100ns_without_static_s"] = without
    print(f"(d) spread below 100 ns for good after {with_static} s with the static "
          f"compensation, {without} s without it")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
