"""The ring watch riding in the cyclic loop: events noticed through the IRQ field, named a cycle later.

In-process simulator, virtual time, one clock for master, loop and
segment. The watch must not poll for what the IRQ field tells: a slave
that changes state or loses a link is named in the cycle after the one
whose reply carried the event; a cable corrupting frames (1e-3 of the
frames crossing it, a branch of a tree) is named a cycle or two after its
first corrupted frame, well within a second.
"""

from __future__ import annotations

from pathlib import Path

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.master import Master
from pyethercat.master.ringwatch import RingWatch
from pyethercat.sim.ring import ring_link
from pyethercat.sim.topology import load_topology
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


def start(ring: bool, interval: float = 10.0, cycle: float = 0.001,
          frames: list[bytes] | None = None):
    clock = VirtualClock()
    seg = load_topology(DEMO).build(clock=clock)

    def respond(frame: bytes) -> bytes | None:
        if frames is not None:
            frames.append(frame)
        return seg.process(frame)

    link = ring_link(seg) if ring else PairLink.responder_link(respond)
    m = Master(link, clock=clock)
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0,
                     recover=m.pd.recover, cycle=cycle)
    # A long interval: whatever is found below was found because the loop noticed it.
    w = RingWatch(m.ring, interval=interval, log=r.log)
    r.riders.append(w)
    r.run(cycles=3)
    m.set_state(AlState.OP)
    w.refresh()  # the master's own state reads took the events of the walk up
    r.run(cycles=3)
    w.events.clear()
    return seg, m, r, w


def test_a_state_change_is_named_in_the_next_cycle() -> None:
    seg, m, r, w = start(ring=False)
    r.run(cycles=5)
    seg.slaves[1].esc.set_al_error(0x001B, AlState.SAFEOP)  # the di8 (bus position 2)
    r.run(cycles=3)
    (ev,) = [e for e in w.events if e.kind == "al"]
    assert ev.position == 2 and ev.text == "slave 2: OP -> SAFEOP + error, 0x001B"
    assert ev.named_cycle == ev.noticed_cycle + 1


def test_a_pulled_cable_is_named_by_both_ends_in_the_next_cycle() -> None:
    seg, m, r, w = start(ring=True)
    r.run(cycles=5)
    seg.break_link(1, 1)  # di8 (bus 2) port 1 to do8 (bus 3) port 0
    r.run(cycles=3)
    dl = [(e.position, e.text) for e in w.events if e.kind == "dl"]
    assert dl == [(2, "slave 2 port 1: link lost"), (3, "slave 3 port 0: link lost")]
    assert all(e.named_cycle == e.noticed_cycle + 1 for e in w.events)
    assert any("fault: link between slave 2 port 1 and slave 3 port 0" in e.text for e in r.events)
    # both halves keep exchanging: the working counter never dropped
    assert r.stats.wkc_errors == 0


def test_without_the_event_mask_nothing_is_noticed_until_the_interval() -> None:
    seg, m, r, w = start(ring=False)
    m.broadcast_write(R.ECAT_EVENT_MASK, b"\x00\x00")
    r.run(cycles=5)
    seg.slaves[1].esc.set_al_error(0x001B, AlState.SAFEOP)
    r.run(cycles=3)
    # the working counter still tells something is wrong, but not who (no IRQ): the
    # watch reads once, and reading AL status is what names the slave
    assert [e.position for e in w.events if e.kind == "al"] in ([2], [])


def test_a_bad_cable_in_a_tree_is_named_within_a_cycle_or_two_of_its_first_crc_error() -> None:
    seg, m, r, w = start(ring=False, interval=0.2)
    r.run(cycles=300)
    published = m.ring.published
    # the branch cable: coupler port 3 to the do8 at bus position 1 (sim index 5)
    seg.crc_error_rate(0, 3, 1e-3, seed=3)
    first_error = named = None
    for cycle in range(1, 3001):
        r.run(cycles=1)
        if first_error is None and seg.slaves[5].read(R.RX_ERROR_COUNTER, 1) != b"\x00" or \
                first_error is None and seg.slaves[0].read(R.RX_ERROR_COUNTER + 6, 1) != b"\x00":
            first_error = cycle
        fresh = list(m.ring.events)[-(m.ring.published - published):] \
            if m.ring.published > published else []
        if named is None and any(e.fault.kind == "crc" for e in fresh):
            named = cycle
            break
    assert first_error is not None and named is not None
    assert named - first_error <= 2
    (f,) = [e.fault for e in m.ring.events if e.fault.kind == "crc"]
    assert f.where == "bad cable between slave 0 port 3 and slave 1 port 0"
    assert named <= 1000, f"named after {named} cycles"


def test_cycles_that_keep_failing_ask_for_readings_at_a_bounded_duty() -> None:
    # Reading and evaluating every slave is work in the loop's thread. Cycles that
    # keep failing without a slave saying why (frames lost on the way: no IRQ) ask for
    # readings, but each waits ten times the last one's cost: a reading of 3 ms here
    # allows one per 30 ms at most. (Without the wait, a reading after every failed
    # cycle: on a real clock the readings made cycles late, which failed them, which
    # asked for more readings.)
    seg, m, r, w = start(ring=False)
    clock = r.clock
    evaluate = w._evaluate

    def costly(runner, pending):  # noqa: ANN001, ANN202
        evaluate(runner, pending)
        clock.advance(3_000_000)

    w._evaluate = costly  # type: ignore[method-assign]
    seg.drop_probability(0.2, seed=7)  # a fifth of the frames lost from now on
    r.run(cycles=5)
    before = w.diagnoses
    start_ns = clock.now_ns()
    r.run(cycles=300)
    span_ms = (clock.now_ns() - start_ns) / 1e6
    assert r.stats.lost_frames > 30  # the cycles did keep failing
    readings = w.diagnoses - before
    assert 1 <= readings <= span_ms / 30 + 1


def test_the_interval_reading_rides_a_tenth_of_each_cycles_wire_time() -> None:
    # Reading every slave at once put three datagrams per slave into the next cyclic
    # frames: at 4 kHz and 100 slaves five cycles late every interval. The interval's
    # reading is paced: at 10 kHz a cycle carries 125 bytes of it (10 us of wire).
    frames: list[bytes] = []
    seg, m, r, w = start(ring=False, interval=0.002, cycle=0.0001, frames=frames)
    before = w.diagnoses
    del frames[:]
    r.run(cycles=200)  # 20 ms: ten interval readings
    readings = w.diagnoses - before
    assert 8 <= readings <= 11
    assert w.last is not None and len(w.last.readings) == 6
    assert all(x.al_status == AlState.OP for x in w.last.readings)
    carried = [sum(d.size for d in decode_frame(f).datagrams if d.command == Command.FPRD)
               for f in frames]
    # one slave's three reads are 64 bytes: at most two slaves' per cycle
    assert max(carried) <= 128 and sum(1 for c in carried if c) >= 3 * readings
    # no frames of their own: every frame of the run is a cycle's
    assert all(any(d.command == Command.LRW for d in decode_frame(f).datagrams) for f in frames)
    # something noticed while a paced reading runs is still named within a few cycles
    seg.slaves[1].esc.set_al_error(0x001B, AlState.SAFEOP)
    r.run(cycles=6)
    (ev,) = [e for e in w.events if e.kind == "al"]
    assert ev.position == 2 and ev.named_cycle - ev.noticed_cycle <= 4
