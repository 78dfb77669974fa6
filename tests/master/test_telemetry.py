"""Telemetry of a master on the simulated demo segment: states, counters, images, events, rate.

The segment runs in process (a synchronous pair link); the cyclic runner is
stepped on virtual time, so every figure below comes from real frames.
"""

from __future__ import annotations

from pathlib import Path

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master import diag
from pyethercat.master.control.handlers import MasterContext, dispatch
from pyethercat.master.control.protocol import from_json, to_json
from pyethercat.master.control.telemetry_ops import PdoWrite, TelemetryRequest
from pyethercat.master.cyclic import CycleStats, CyclicRunner
from pyethercat.master.master import Master
from pyethercat.master.telemetry import Telemetry, TelemetrySnapshot, telemetry_of
from pyethercat.wire.al import AlState

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _running_master():
    from pyethercat.sim.topology import load_topology

    seg = load_topology(DEMO).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    r = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=VirtualClock(), check_interval=0)
    m.pd.runner = r
    r.run(cycles=2)
    m.set_state("OP")
    r.run(cycles=50)
    return seg, m, r


def test_recent_samples_are_the_last_ones_in_order():
    st = CycleStats(1000, capacity=8)
    for k in range(13):
        st.record_start(k * 1000, k * 1000 + k, 500)
        st.record_round_trip(k)
    periods, rtts = st.recent(5)
    assert list(rtts) == [8, 9, 10, 11, 12]
    assert list(periods) == [1001] * 5
    assert list(st.recent(100)[1]) == [5, 6, 7, 8, 9, 10, 11, 12]  # capacity bounds it
    assert st.recent(0)[0].size == 0


def test_snapshot_of_a_cycling_segment_has_states_counters_and_images():
    seg, m, r = _running_master()
    clock = _Clock()
    t = Telemetry(m, clock=clock)
    snap = t.snapshot()
    assert [s.position for s in snap.slaves] == list(range(6))
    assert all(s.state == AlState.OP and s.answered and not s.error for s in snap.slaves)
    # DL status: the coupler has ports 0, 1 and 3 open; the last terminal only port 0.
    coupler, last = snap.slaves[0], snap.slaves[5]
    assert coupler.dl_status is not None and last.dl_status is not None
    assert coupler.counters is not None and len(coupler.counters) == diag.ERROR_COUNTERS_SIZE
    assert snap.cycle.cycles == r.stats.cycles > 50 and snap.cycle.period_us == 1000.0
    assert snap.cycle.window > 0 and snap.cycle.wkc_errors == 0
    g = snap.groups[0]
    assert g.wkc == g.expected_wkc and bytes(m.images[g.name].buffer) == g.image
    # A CRC error on the di8's port 0 shows in its counters at the next reading.
    seg.corrupt_frames(1, 0, count=1)  # the di8: simulator index 1, ring position 2
    r.run(cycles=5)
    clock.t += 1.0
    again = t.snapshot()
    before = diag.decode_error_counters(2, 0, coupler.counters)
    assert before.total == 0
    after = diag.decode_error_counters(2, 0, again.slaves[2].counters or b"")
    assert after.ports[0].rx_errors + after.ports[0].invalid_frames >= 1


def test_snapshots_are_rate_bounded_and_cached():
    _seg, m, r = _running_master()
    clock = _Clock()
    t = Telemetry(m, clock=clock, max_rate=20)
    first = t.snapshot()
    r.run(cycles=10)
    assert t.snapshot().cycle.cycles == first.cycle.cycles  # within 50 ms: the same one
    assert t.taken == 1
    clock.t += 0.06
    assert t.snapshot().cycle.cycles == first.cycle.cycles + 10
    assert t.taken == 2


def test_events_are_numbered_and_read_after_a_number():
    _seg, m, r = _running_master()
    t = Telemetry(m, clock=_Clock())
    r.log("first")
    r.log("second")
    snap = t.snapshot()
    texts = [e.text for e in snap.events]
    assert texts[-2:] == ["first", "second"]
    last = snap.events[-1].seq
    t.record_foe(0, "fw.bin", 12, "write")
    newer = t.snapshot(last)
    assert [e.kind for e in newer.events] == ["foe"]
    assert t.foe_files(0)[0].name == "fw.bin"


def test_snapshot_crosses_the_control_protocol_and_outputs_are_written_by_name():
    _seg, m, r = _running_master()
    ctx = MasterContext(m, "sim:demo")
    snap = dispatch(ctx, TelemetryRequest())
    assert isinstance(snap, TelemetrySnapshot)
    back = from_json(TelemetrySnapshot, to_json(snap))
    assert back == snap
    assert telemetry_of(m) is telemetry_of(m)
    dispatch(ctx, PdoWrite(3, "Output 4", True))
    r.run(cycles=3)
    assert m.slaves[2].inputs["Input 4"] is True  # the do8 is wired back to the di8
