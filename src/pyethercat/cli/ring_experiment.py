"""The redundancy experiment: a ring run through random single faults, every cycle counted.

After the test of Huan, Xiao and Liu ("Research of redundancy and hot swap
technology in industrial Ethernet EtherCAT"): a master with ports A and B
cycles process data while cables are pulled, nodes powered off and slaves
hot-swapped, and counters at the application level show what was lost.
Here the segment is simulated in this process, in virtual time (the run is
repeatable and takes seconds): a ring of ``slaves`` IO terminals (di8,
do8, ai2 in turn), cycled at ``cycle`` seconds; ``faults`` random single
faults, each held for a random time and mended:

- ``link``: the cable between two neighbours is pulled and plugged again;
- ``port A`` / ``port B``: the master's cable at port A or B;
- ``node``: a slave is switched off and on (it comes back in INIT, without
  its station address);
- ``hot swap``: a slave is unplugged and a device of the same kind (the
  same one, or a fresh one) plugged into its place.

A share of the faults (``in_flight``) strikes while a frame is on the wire:
between the copy sent on A and the copy sent on B of one frame.

Per cycle: the frame came back (the paper's send and receive counters),
its working counter was complete for the slaves present, and every present
slave's data is fresh (the simulator sets new inputs every cycle and checks
the outputs it gets). Per fault: the bad cycles it caused, whether the
master located it where it was injected, how long it took to be whole again
and, for a slave plugged back, how long until it was in OP exchanging data.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pyethercat.clock import VirtualClock
from pyethercat.master.config import Layout
from pyethercat.master.cyclic import Cycle, CyclicRunner
from pyethercat.master.master import Master
from pyethercat.master.ringwatch import RingWatch
from pyethercat.wire.al import AlState

__all__ = ["FAULT_KINDS", "ExperimentResult", "FaultRecord", "crc_naming", "run_experiment"]

FAULT_KINDS = ("link", "port A", "port B", "node", "hot swap")
_DEVICES = ("di8", "do8", "ai2")


@dataclass
class FaultRecord:
    """One injected fault and what the master made of it."""

    number: int
    kind: str
    #: Where it was injected, in the words the master's diagnosis uses.
    truth: str
    injected_cycle: int
    in_flight: bool
    mended_cycle: int = -1
    #: Where the master located it (the first fault event after the injection).
    located: str | None = None
    #: Cycles lost, or with stale data of a slave present, while it lasted.
    bad_cycles: int = 0
    #: Cycles the master's working-counter check found short of the slaves it believed
    #: present (how it notices a node gone: one cycle).
    flagged_cycles: int = 0
    #: Cycles from the injection to the first whole cycle (0: none was bad).
    recovery_cycles: int = 0
    #: A slave plugged back (node, hot swap): ms from plugging until OP with data flowing.
    back_in_op_ms: float | None = None
    detail: str = ""

    @property
    def located_ok(self) -> bool:
        return self.located == self.truth


@dataclass
class ExperimentResult:
    """Counters of the whole run and the record of every fault."""

    slaves: int
    cycle_s: float
    cycles: int = 0
    sent: int = 0
    received: int = 0
    wkc_wrong: int = 0
    incomplete: int = 0
    stale: int = 0
    faults: list[FaultRecord] = field(default_factory=list)

    @property
    def lost(self) -> int:
        return self.sent - self.received

    def summary(self) -> dict[str, Any]:
        """The figures as plain numbers (JSON-ready)."""
        located = sum(f.located_ok for f in self.faults)
        by_kind: dict[str, dict[str, Any]] = {}
        for f in self.faults:
            k = by_kind.setdefault(f.kind, {"faults": 0, "bad_cycles_max": 0, "located": 0,
                                            "recovery_cycles_max": 0})
            k["faults"] += 1
            k["bad_cycles_max"] = max(k["bad_cycles_max"], f.bad_cycles)
            k["located"] += f.located_ok
            k["recovery_cycles_max"] = max(k["recovery_cycles_max"], f.recovery_cycles)
        back = [f.back_in_op_ms for f in self.faults if f.back_in_op_ms is not None]
        return {
            "slaves": self.slaves, "cycle_us": round(self.cycle_s * 1e6), "cycles": self.cycles,
            "send_counter": self.sent, "recv_counter": self.received, "lost": self.lost,
            "wkc_wrong_cycles": self.wkc_wrong, "flagged_incomplete_cycles": self.incomplete,
            "stale_cycles": self.stale, "faults": len(self.faults),
            "in_flight": sum(f.in_flight for f in self.faults),
            "bad_cycles_max": max((f.bad_cycles for f in self.faults), default=0),
            "flagged_cycles_max": max((f.flagged_cycles for f in self.faults), default=0),
            "bad_cycles_max_between_frames": max(
                (f.bad_cycles for f in self.faults if not f.in_flight), default=0),
            "located": located, "located_pct": round(100 * located / len(self.faults), 1)
            if self.faults else 100.0,
            "recovery_cycles_max_link": max(
                (f.recovery_cycles for f in self.faults if f.kind in ("link", "port A", "port B")),
                default=0),
            "back_in_op_ms_max": round(max(back), 1) if back else None,
            "back_in_op_ms_mean": round(sum(back) / len(back), 1) if back else None,
            "by_kind": by_kind,
        }

    def lines(self) -> list[str]:
        """A readable report."""
        s = self.summary()
        out = [f"ring of {self.slaves} slaves, {s['cycle_us']} us cycle, {self.cycles} cycles, "
               f"{len(self.faults)} faults ({s['in_flight']} while a frame was on the wire)",
               f"  SendCounter {self.sent}  RecvCounter {self.received}  lost {self.lost}",
               f"  cycles lost {self.lost}, with stale data of a slave present {self.stale}; "
               f"the master's WKC check: {self.wkc_wrong} short of all slaves (a slave gone "
               f"counts), {self.incomplete} short of those it knew present",
               f"  per fault: at most {s['bad_cycles_max']} bad cycle(s) "
               f"({s['bad_cycles_max_between_frames']} for faults between frames); located "
               f"{s['located']}/{len(self.faults)}; link recovery within "
               f"{s['recovery_cycles_max_link']} cycle(s)"]
        if s["back_in_op_ms_max"] is not None:
            out.append(f"  slaves plugged back in OP after {s['back_in_op_ms_mean']} ms on "
                       f"average, {s['back_in_op_ms_max']} ms at most")
        for kind, k in s["by_kind"].items():
            out.append(f"  {kind:<9} {k['faults']:>3} faults, located {k['located']}, bad cycles "
                       f"<= {k['bad_cycles_max']}, recovery <= {k['recovery_cycles_max']} cycle(s)")
        wrong = [f for f in self.faults if not f.located_ok or f.bad_cycles > (1 if f.in_flight
                                                                                else 0)]
        for f in wrong[:10]:
            out.append(f"  ! fault {f.number} {f.kind} {f.truth!r}: located {f.located!r}, "
                       f"{f.bad_cycles} bad cycle(s) {f.detail}")
        return out


def ring_topology(slaves: int) -> dict[str, Any]:
    """The experiment's segment: IO terminals in a line, the ring closed at the last."""
    return {"segment": {"ring": True, "drift_ppm": 0.0},
            "slave": [{"name": f"s{i}", "device": f"builtin:{_DEVICES[i % len(_DEVICES)]}"}
                      for i in range(slaves)]}


class _Harness:
    """Drives the simulated ring and checks every cycle (the test slave of the paper)."""

    def __init__(self, slaves: int, cycle: float, seed: int) -> None:
        from pyethercat.sim.ring import ring_link
        from pyethercat.sim.topology import device_spec, parse_topology

        self.device_spec = device_spec
        self.clock = VirtualClock()
        self.seg = parse_topology(ring_topology(slaves)).build(clock=self.clock)
        self._in_flight: list[Callable[[], None]] = []
        self.master = Master(ring_link(self.seg, before=self._before), clock=self.clock)
        self.rng = random.Random(seed)
        self.n = slaves
        m = self.master
        m.scan()
        self.config = m.configure(layout=Layout.BYTE)
        m.pd.bring_up(m.slaves, 2.0)
        self.runner = CyclicRunner(m.scheduler, self.config, m.images, m.slaves, cycle=cycle,
                                   clock=self.clock, check_interval=0.05, recover=m.pd.recover)
        self.watch = RingWatch(m.ring, log=self.runner.log)
        self.runner.riders.append(self.watch)
        self.image = np.frombuffer(m.images["main"].buffer, np.uint8)
        cfg = self.config.slaves
        # Per direction and data length: the slaves and their bytes in the image, so a
        # cycle's data is set and checked with a few array operations.
        self.inputs = _blocks([(p, cfg[p].input_bit_offset // 8, cfg[p].input_bytes)
                               for p in range(slaves) if cfg[p].input_bytes])
        self.outputs = _blocks([(p, cfg[p].output_bit_offset // 8, cfg[p].output_bytes)
                                for p in range(slaves) if cfg[p].output_bytes])
        self.k = 0
        self.want: list[np.ndarray] = []
        # Each slave's data pattern; a cycle adds its number to it.
        self._base = [((np.arange(at.shape[1])[None, :] * 3 + slaves[:, None] * mult) & 0xFF)
                      for mult, blocks in ((11, self.inputs), (13, self.outputs))
                      for slaves, at in blocks]

    def _before(self, port: int) -> None:
        if port == 1 and self._in_flight:
            for inject in self._in_flight:
                inject()
            self._in_flight.clear()

    def in_flight(self, inject: Callable[[], None]) -> None:
        """Inject while the next frame is on the wire (after its copy on A went through)."""
        self._in_flight.append(inject)

    # -- data of one cycle ------------------------------------------------------------------

    def prepare(self) -> None:
        """New inputs in the slaves and new outputs in the master's image, for the next cycle."""
        k = self.k = self.k + 1
        pdio = self.seg.pdio
        self.want = want = [((b + k * 7) & 0xFF).astype(np.uint8) for b in self._base]
        i = 0
        for slaves, _at in self.inputs:
            pdio.set_inputs(slaves, want[i])
            i += 1
        for _slaves, at in self.outputs:
            self.image[at] = want[i]
            i += 1

    def stale(self, present: np.ndarray) -> list[int]:
        """Present slaves whose data this cycle did not carry (inputs at the master, outputs
        in the slave); ``present`` is a mask by position."""
        bad: list[int] = []
        i = 0
        for blocks, inputs in ((self.inputs, True), (self.outputs, False)):
            for slaves, at in blocks:
                want = self.want[i]
                i += 1
                got = self.image[at] if inputs else self.seg.pdio.outputs(slaves, at.shape[1])
                wrong = (got != want).any(axis=1) & present[slaves]
                if wrong.any():
                    bad.extend(slaves[wrong].tolist())
        return sorted(set(bad))


def _blocks(items: list[tuple[int, int, int]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(slaves, image byte indices per slave) for each data length among ``items``."""
    out = []
    for n in sorted({n for _, _, n in items}):
        chosen = [(p, at) for p, at, m in items if m == n]
        slaves = np.array([p for p, _ in chosen], np.int64)
        at = np.array([at for _, at in chosen], np.int64)[:, None] + np.arange(n)[None, :]
        out.append((slaves, at))
    return out


def run_experiment(slaves: int = 20, cycle: float = 0.001, seconds: float = 60.0,
                   faults: int = 100, seed: int = 1, in_flight: float = 0.2,
                   hold: tuple[float, float] | None = None, settle: float | None = None,
                   progress: Callable[[int, int], None] | None = None) -> ExperimentResult:
    """Run the experiment (see the module text) and return its counters and fault records.

    ``seconds`` is the run's length in virtual time; the ``faults`` are spread
    evenly over it (each held for a random time in ``hold`` seconds, then
    mended and watched for ``settle`` seconds at least before the next).
    By default a fault is held up to 0.3 s and watched 0.15 s, less when the
    faults come faster (at least 60 ms per fault).
    """
    per_fault = seconds / max(1, faults)
    if faults and per_fault < 0.06:
        raise ValueError(f"{faults} faults in {seconds:g} s: give each at least 60 ms")
    if hold is None:
        hold = (min(0.05, 0.1 * per_fault), min(0.3, 0.4 * per_fault))
    if settle is None:
        settle = min(0.15, max(0.045, 0.3 * per_fault))
    h = _Harness(slaves, cycle, seed)
    rng, runner, m = h.rng, h.runner, h.master
    result = ExperimentResult(slaves, cycle)
    total = int(round(seconds / cycle))
    slot = total // max(1, faults)
    settle_cycles = int(settle / cycle)
    if faults and slot < int(hold[1] / cycle) + settle_cycles + 2:
        raise ValueError(f"{faults} faults do not fit {seconds} s with holds up to {hold[1]} s")
    plan: list[tuple[int, int, str, int, bool]] = []  # (inject cycle, mend cycle, kind, where, flight)
    for i in range(faults):
        start = i * slot + rng.randrange(settle_cycles,
                                         max(settle_cycles + 1, slot - int(hold[1] / cycle) - 1))
        length = int(rng.uniform(*hold) / cycle)
        kind = FAULT_KINDS[rng.randrange(len(FAULT_KINDS))]
        where = rng.randrange(slaves - 1) if kind == "link" else rng.randrange(slaves)
        plan.append((start, start + length, kind, where, rng.random() < in_flight))
    # Walk up: SAFEOP, a few cycles of outputs, then OP.
    runner.supervising = False
    runner.run(cycles=5)
    m.set_state(AlState.OP)
    runner.supervising = True
    runner.run(cycles=20)
    state = _Run(h, result, plan, settle_cycles)
    runner.callback = state.after_cycle
    h.prepare()
    done = 0
    step = max(1, total // 100)
    while done < total:
        n = min(step, total - done)
        runner.run(cycles=n)
        done += n
        if progress is not None:
            progress(done, total)
    result.cycles = total
    state.finish()
    m.close()
    return result


class _Run:
    """The per-cycle bookkeeping of :func:`run_experiment`."""

    def __init__(self, h: _Harness, result: ExperimentResult,
                 plan: list[tuple[int, int, str, int, bool]], settle: int) -> None:
        self.h = h
        self.result = result
        self.plan = sorted(plan)
        self.settle = settle
        self.cycle = 0
        self.active: FaultRecord | None = None
        self.where = 0
        self.mend_at = -1
        self.watch_until = -1
        self.plugged_at: int | None = None
        self.pending_bad: list[int] = []
        self._seen_events = h.master.ring.published
        self.fresh = False
        self.present = np.ones(h.n, bool)

    def after_cycle(self, cyc: Cycle) -> None:
        h, r = self.h, self.result
        runner = h.runner
        self.cycle += 1
        c = self.cycle
        r.sent += 1
        if not cyc.lost:
            r.received += 1
        group = runner.groups[0]
        if not group.wkc_ok:
            r.wkc_wrong += 1
        f = self.active
        present = self.present
        present[:] = True
        if f is not None and f.kind in ("node", "hot swap"):
            present[self.where] = False
        stale = h.stale(present) if not cyc.lost else []
        if stale:
            r.stale += 1
        flagged = not group.present_ok and not cyc.lost
        if flagged:
            r.incomplete += 1
        bad = cyc.lost or bool(stale)
        if f is not None:
            f.flagged_cycles += flagged
            if bad:
                f.bad_cycles += 1
                if f.recovery_cycles == c - f.injected_cycle:
                    f.recovery_cycles += 1
                if not f.detail:
                    f.detail = (f"(cycle {c - f.injected_cycle}: lost {cyc.lost}, wkc "
                                f"{group.last_wkc}, stale {stale})")
            self._locate(f)
            self._plugged_back(f)
            if c == self.mend_at:
                self._mend(f)
            if self.mend_at < 0 and c >= self.watch_until and (
                    f.kind not in ("node", "hot swap") or f.back_in_op_ms is not None
                    or c >= self.watch_until + 2000):
                self.active = None
        if self.active is None and self.plan and c >= self.plan[0][0]:
            self._inject(*self.plan.pop(0)[1:])
        h.prepare()

    # -- faults -----------------------------------------------------------------------------

    def _inject(self, mend_cycle: int, kind: str, where: int, flight: bool) -> None:
        h, seg = self.h, self.h.seg
        n = h.n
        c = self.cycle
        if kind == "link":
            truth = f"between slave {where} port 1 and slave {where + 1} port 0"
            act: Callable[[], None] = lambda: seg.break_link(where, 1)  # noqa: E731
        elif kind == "port A":
            truth = "master port A (its cable to slave 0 port 0)"
            act = lambda: seg.master_port_fault(0)  # noqa: E731
        elif kind == "port B":
            truth = f"master port B (its cable to slave {n - 1} port 1)"
            act = lambda: seg.master_port_fault(1)  # noqa: E731
        elif kind == "node":
            truth = f"slave {where}"
            act = lambda: seg.power_off(where)  # noqa: E731
        else:
            truth = f"slave {where}"
            act = lambda: seg.remove_slave(where)  # noqa: E731
        f = FaultRecord(len(self.result.faults) + 1, kind, truth, c + 1, flight)
        self.result.faults.append(f)
        self.active = f
        self.where = where
        self.mend_at = c + 1 + (mend_cycle - (c + 1) if mend_cycle > c + 1 else 1)
        self.plugged_at = None
        self._seen_events = h.master.ring.published
        if flight:
            h.in_flight(act)
        else:
            act()

    def _mend(self, f: FaultRecord) -> None:
        seg, where = self.h.seg, self.where
        if f.kind == "link":
            seg.restore_link(where, 1)
        elif f.kind == "port A":
            seg.master_port_fault(0, broken=False)
        elif f.kind == "port B":
            seg.master_port_fault(1, broken=False)
        elif f.kind == "node":
            seg.power_on(where)
            self.plugged_at = self.cycle
        else:
            same = self.h.rng.random() < 0.5
            spec = None if same else self.h.device_spec(
                f"builtin:{_DEVICES[where % len(_DEVICES)]}", seg.slaves[where].name)
            seg.insert_slave(where, spec)
            self.plugged_at = self.cycle
        f.mended_cycle = self.cycle
        self.mend_at = -1
        self.watch_until = self.cycle + self.settle

    def _locate(self, f: FaultRecord) -> None:
        ring = self.h.master.ring
        if f.located is not None or ring.published == self._seen_events:
            return
        fresh = list(ring.events)[-(ring.published - self._seen_events):]
        self._seen_events = ring.published
        for ev in fresh:
            if not ev.cleared and ev.fault.kind != "unaddressed" and ev.fault.kind != "crc":
                f.located = ev.fault.where
                return

    def _plugged_back(self, f: FaultRecord) -> None:
        if self.plugged_at is None or f.back_in_op_ms is not None:
            return
        h = self.h
        esc = h.seg.escs[self.where]
        if esc.al_state() == AlState.OP and h.runner.groups[0].wkc_ok:
            f.back_in_op_ms = (self.cycle - self.plugged_at) * h.runner.period_ns / 1e6

    def finish(self) -> None:
        """Close the last fault's record."""


def crc_naming(topology: str, slave: int, port: int, rate: float = 1e-3, seed: int = 1,
               cycle: float = 0.001, limit_s: float = 5.0) -> tuple[int | None, int | None, str]:
    """A bad cable (CRC errors at ``rate`` per frame crossing it) while a master cycles:
    (cycles until its first corrupted frame, cycles until the master named it, the name).

    One-port master on ``topology`` (a tree as well as a line), in virtual time,
    the ring watch reading every 0.2 s and whenever a cycle goes wrong.
    """
    from pyethercat.link.pair import PairLink
    from pyethercat.sim.topology import load_topology
    from pyethercat.wire import registers as reg

    clock = VirtualClock()
    seg = load_topology(topology).build(clock=clock)
    m = Master(PairLink.responder_link(seg.process), clock=clock)
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    runner = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, cycle=cycle, clock=clock,
                          check_interval=0)
    runner.riders.append(RingWatch(m.ring, log=runner.log))
    runner.run(cycles=3)
    m.set_state(AlState.OP)
    runner.run(cycles=300)
    seen = m.ring.published
    seg.crc_error_rate(slave, port, rate, seed=seed)
    ports = [(slave, port)]
    peer = seg.ports.peer_key(slave, port)
    if peer is not None:
        ports.append(peer)
    first = named = None
    where = ""
    for k in range(1, int(limit_s / cycle) + 1):
        runner.run(cycles=1)
        if first is None and any(seg.slaves[s].read(reg.RX_ERROR_COUNTER + 2 * p, 1) != b"\0"
                                 for s, p in ports):
            first = k
        if m.ring.published > seen:
            fresh = list(m.ring.events)[-(m.ring.published - seen):]
            seen = m.ring.published
            crc = [e.fault for e in fresh if e.fault.kind == "crc" and not e.cleared]
            if crc:
                named, where = k, crc[0].where
                break
    m.close()
    return first, named, where
