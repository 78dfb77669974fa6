"""The redundancy experiment on a simulated 20-slave ring: 100 random single faults.

Cable pulls between neighbours, master port A and B faults, nodes switched
off and on, hot swaps; about a third of them while a frame is on the wire.
Virtual time: the same run every time (the figures of record, 60 s at 1
kHz, come from benchmarks/redundancy.py; here the faults follow each other
faster). What must hold:

- no cycle lost or with stale data of a slave present, except at most one
  for a fault that struck a frame on the wire; none otherwise, a node that
  went included (the copies of the cycle that shows it gone say which slaves
  neither side of the break reached, so the others' inputs are taken);
- the master's own working-counter check finds no cycle short of the slaves
  it believes present, except the frame a fault struck on the wire;
- every fault located where it was injected;
- a cable fault costs no cycle at all (recovery within one cycle);
- a slave plugged back is in OP exchanging data within 100 ms (of virtual
  time: cycles, not a stopwatch).
"""

from __future__ import annotations

from pyethercat.cli.ring_experiment import FAULT_KINDS, run_experiment


def test_one_hundred_faults_on_a_twenty_slave_ring() -> None:
    r = run_experiment(slaves=20, seconds=7.0, faults=100, seed=11, hold=(0.005, 0.015),
                       settle=0.045, in_flight=0.3)
    s = r.summary()
    assert s["faults"] == 100 and {f.kind for f in r.faults} == set(FAULT_KINDS)
    assert s["in_flight"] >= 20
    for f in r.faults:
        assert f.bad_cycles <= (1 if f.in_flight else 0), f
        assert f.flagged_cycles <= (1 if f.in_flight else 0), f
        assert f.located_ok, f
        if f.kind in ("link", "port A", "port B"):
            assert f.recovery_cycles <= 1, f
        if f.kind in ("node", "hot swap"):
            assert f.back_in_op_ms is not None and f.back_in_op_ms <= 100, f
    assert r.sent == r.cycles and r.lost <= s["in_flight"]
    assert s["located_pct"] == 100.0
