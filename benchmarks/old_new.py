"""The same in-process workloads on two trees, for old-vs-new figures (callgrind and wall clock).

Each tree runs this file with its own ``pyethercat`` on the import path
(``PYTHONPATH=TREE/src``); master and simulator share the process and answer
synchronously (the old tree's ``deterministic`` master, the new tree's
master on the segment's virtual clock), so the instruction counts repeat
whatever the load:

    PYTHONPATH=OLD/src valgrind --tool=callgrind --toggle-collect=functools_reduce \
        python benchmarks/old_new.py master 10 200

counts only the K measured calls (Ir / K per call); ``WALL=1`` prints the
wall-clock time per call instead (best of 5 batches).

python benchmarks/old_new.py KIND N K
  sim    N K: K x Segment.process of the master's cyclic LRW frame (N slaves, OP)
  master N K: K x runner.exchange_once() (our master's cycle + the simulator)
  mbx    0 K: K x sdo_read(0x1018, 1) on a coe-io slave; mbx 1 K: K x 64 KiB segmented upload
Both trees: each imports its own pyethercat (PYTHONPATH).
"""
import functools
import os
import sys
import time

import pyethercat
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.sim.topology import parse_topology


def topology(n):  # benchmarks/master_cycle.py's segment: coupler, do8/di8 pairs wired
    parts = ['[[slave]]\nname = "coupler"\ndevice = "builtin:coupler"\n']
    wires = []
    for i in range((n - 1) // 2):
        parts.append(f'[[slave]]\nname = "do{i}"\ndevice = "builtin:do8"\n')
        parts.append(f'[[slave]]\nname = "di{i}"\ndevice = "builtin:di8"\n')
        wires.append(f'[[wire]]\nfrom = "do{i}:0"\nto = "di{i}:0"\n')
    if (n - 1) % 2:
        parts.append('[[slave]]\nname = "extra"\ndevice = "builtin:di2"\n')
    return "\n".join(parts + wires)


def make_master(seg, responder):
    import inspect
    link = PairLink.responder_link(responder)
    if "clock" in inspect.signature(Master.__init__).parameters:   # new tree: one virtual clock
        return Master(link, clock=seg.clock)
    return Master(link, deterministic=True)                      # old tree


def measured(fn, k):
    """Run fn k times inside functools.reduce: callgrind --toggle-collect=functools_reduce
    counts the instructions of these calls only (nothing else here uses functools.reduce)."""
    if os.environ.get("WALL"):  # wall-clock instead: best of 5 batches, per call
        best = float("inf")
        for _ in range(5):
            t = time.perf_counter()
            functools.reduce(lambda acc, _: fn(), range(k), None)
            best = min(best, (time.perf_counter() - t) / k)
        print(f"WALL {best * 1e6:.1f}")
        return
    functools.reduce(lambda acc, _: fn(), range(k), None)


def main():
    kind, n, k = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    if kind == "mbx":
        seg = parse_topology('[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n').build()
        m = make_master(seg, seg.process)
        m.scan()
        m.set_state("PREOP")
        io = m.slaves[0]
        for _ in range(20):
            io.sdo_read(0x1018, 1)
        if n == 0:   # expedited SDO round trips
            measured(lambda: io.sdo_read(0x1018, 1), k)
        else:        # 64 KiB segmented uploads
            measured(lambda: io.sdo_read(0x2003), k)
        return
    seg = parse_topology(topology(n)).build()
    frames = []

    def responder(frame):
        frames.append(frame)
        return seg.process(frame)

    m = make_master(seg, responder)
    m.scan()
    m.configure()
    from pyethercat.master.cyclic import CyclicRunner
    if hasattr(m, "pd"):   # new tree
        m.pd.bring_up(m.slaves, 5.0)
        runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=0.001,
                              clock=seg.clock, check_interval=0)
    else:                  # old tree
        m._bring_up(m.slaves, 5.0)
        runner = CyclicRunner(m.scheduler, m._need_config(), m.images, m.slaves, cycle=0.001,
                              check_interval=0)
    for _ in range(20):
        runner.exchange_once()
    m.request_state("OP")
    for _ in range(50):
        runner.exchange_once()
    assert all(int(s.state) == 8 for s in m.read_states()), m.read_states()
    runner.exchange_once()   # the last frame seen is now the cyclic one
    if kind == "master":
        measured(runner.exchange_once, k)
    else:
        frame = frames[-1]
        measured(lambda: seg.process(frame), k)
    print(pyethercat.__file__, len(m.slaves), len(frames[-1]), file=sys.stderr)


main()
