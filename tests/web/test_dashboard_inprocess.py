"""Dashboard pages whose segment the test must hold in its hands: a ring, AL errors, error rates, drives.

The master and the simulated segment run in this process on one virtual
clock; the dashboard is served from a thread (:func:`webdriving.serve_in_process`)
and headless Chromium reads it. A harness thread steps the cyclic loop in
virtual time, paced to about the wall clock so the pages see it move, and
holds the dashboard's lock while it does: the segment's faults and the
drives' motion are exact whatever the host's load, only the browser waits.

- the redundant ring on the Topology page (its return to master port B, a
  cable cut inside the ring, the slaves behind it reached through port B);
- the Slaves page's AL status code with its text and the error counters'
  rates (CRC errors on one cable, then none);
- the Drives page following two CiA 402 drives that the master moves in
  cyclic synchronous position (position, velocity, following error, scope).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from webdriving import SLOW, browser, fits, page, q, serve_in_process, severe_log, shot, wait

pytest.importorskip("starlette")

from pyethercat.clock import VirtualClock  # noqa: E402
from pyethercat.link.pair import PairLink  # noqa: E402
from pyethercat.master.cyclic import CyclicRunner  # noqa: E402
from pyethercat.master.master import Master  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"


class _Running:
    """The stepped runner as the dashboard sees it: a loop that runs (it is, in steps)."""

    running = True

    def __init__(self, runner: CyclicRunner) -> None:
        self._runner = runner

    def __getattr__(self, name: str) -> Any:
        return getattr(self._runner, name)


class SteppedLoop:
    """Steps ``runner`` in a thread: ``work()`` (default: ``cycles`` cycles) under ``lock``,
    then sleeps until the wall clock has caught up with the virtual one.

    Behind the wall clock (a loaded host) it does not hurry to catch up: virtual
    time then simply runs slower, and no cycle is late on it.
    """

    def __init__(self, runner: CyclicRunner, clock: VirtualClock, lock: threading.Lock,
                 cycles: int = 10) -> None:
        self.runner = runner
        self.clock = clock
        self.lock = lock
        self.work: Callable[[], None] = lambda: runner.run(cycles=cycles)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._main, name="stepped-loop", daemon=True)
        self.error: BaseException | None = None

    def _main(self) -> None:
        t0, v0 = time.monotonic(), self.clock.now_ns()
        try:
            while not self._stop.is_set():
                with self.lock:
                    self.work()
                ahead = (self.clock.now_ns() - v0) / 1e9 - (time.monotonic() - t0)
                if ahead > 0:
                    time.sleep(ahead)
                elif ahead < -0.05:
                    t0, v0 = time.monotonic(), self.clock.now_ns()
        except BaseException as exc:  # noqa: BLE001 - re-raised by stop()
            self.error = exc

    def __enter__(self) -> SteppedLoop:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(60)
        if self.error is not None:
            raise self.error


@dataclass
class Demo:
    segment: Any
    master: Master
    runner: CyclicRunner
    clock: VirtualClock
    lock: threading.Lock


def _demo(ring: bool) -> Demo:
    """The demo segment in OP on virtual time (as a ring: both master ports)."""
    from pyethercat.sim.ring import ring_link
    from pyethercat.sim.topology import load_topology

    clock = VirtualClock()
    seg = load_topology(DEMO).build(clock=clock)
    link = ring_link(seg, name="sim:ring") if ring else PairLink.responder_link(seg.process)
    m = Master(link, clock=clock)
    m.scan()
    cfg = m.configure()
    m.pd.bring_up(m.slaves, 2.0)
    # check_interval=0: no supervision, so a slave that fell out stays as the test left it.
    runner = CyclicRunner(m.scheduler, cfg, m.images, m.slaves, clock=clock, check_interval=0)
    runner.run(cycles=2)
    m.set_state("OP")
    runner.run(cycles=50)
    m.pd.runner = _Running(runner)  # type: ignore[assignment]
    return Demo(seg, m, runner, clock, threading.Lock())


@pytest.fixture
def chromium(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    yield from browser(tmp_path_factory)


def test_topology_draws_the_ring_and_a_cut_inside_it(chromium: Any, tmp_path: Path) -> None:
    """demo.toml as a ring: the return to port B; a cut between do8 and di2 is marked, and
    every slave stays in OP, the two behind the cut answering through port B."""
    demo = _demo(ring=True)
    d = chromium
    with serve_in_process(demo.master, "sim:ring", demo.lock) as url, \
            SteppedLoop(demo.runner, demo.clock, demo.lock):
        d.get(url)
        wait(d, lambda d: all(q(d, f"#node-{i}", "data-state") == "OP" for i in range(6)),
             timeout=SLOW)
        assert q(d, "path.edge.ring", "d") is not None
        assert "back to master port B" in (q(d, "#topo-svg") or "")
        wait(d, lambda d: "A:ok · B:ok" in (q(d, "#topo-svg .master") or ""), timeout=SLOW)
        assert q(d, "path.edge.broken", "d") is None
        assert [q(d, f"#node-{i}", "data-side") for i in range(6)] == ["A"] * 6
        shot(d, "topology-ring-closed", tmp_path, publish=False)

        with demo.lock:
            demo.segment.break_link(2, 1)  # file index 2: the do8 (ring position 3), port 1
        wait(d, lambda d: q(d, 'path.edge.broken[data-to="4"]', "d") is not None, timeout=SLOW)
        wait(d, lambda d: [q(d, f"#node-{i}", "data-side") for i in range(6)]
             == ["A"] * 4 + ["B"] * 2, timeout=SLOW,
             describe=lambda d: str([q(d, f"#node-{i}", "data-side") for i in range(6)]))
        # The ring carries on: every slave answers and stays in OP.
        assert all(q(d, f"#node-{i}", "data-state") == "OP" for i in range(6))
        assert q(d, "path.edge.broken", "data-to") == "4"  # the only cable marked
        assert "via B" in (q(d, "#node-4") or "") and "via B" not in (q(d, "#node-3") or "")
        wait(d, lambda d: "slave 3 port 1" in (q(d, "#faults .fault") or ""), timeout=SLOW,
             describe=lambda d: repr(q(d, "#faults")))
        assert "open" in (q(d, "#faults") or "")  # the ring's state, as the ring service names it
        wait(d, lambda d: q(d, '#node-3 circle[data-port="1"]', "data-link") == "down",
             timeout=SLOW)
        shot(d, "topology-ring", tmp_path)

        with demo.lock:
            demo.segment.restore_link(2, 1)
        wait(d, lambda d: q(d, "path.edge.broken", "d") is None
             and q(d, "#node-5", "data-side") == "A", timeout=SLOW)
    assert severe_log(d) == []


def test_slaves_page_shows_the_al_status_text_and_error_rates(chromium: Any,
                                                               tmp_path: Path) -> None:
    """A slave refused a state change (its AL status code and text); CRC errors on one
    cable show as counters and a rate, and the rate falls back to 0 once they stop."""
    from pyethercat.errors import EtherCATError

    demo = _demo(ring=False)
    d = chromium
    with serve_in_process(demo.master, "sim:demo", demo.lock) as url, \
            SteppedLoop(demo.runner, demo.clock, demo.lock):
        # The master walks the di2 down to INIT and asks for BOOT, which it does not
        # support: it stays in INIT with the error flag and AL status code 0x0013.
        with demo.lock, contextlib.suppress(EtherCATError):
            demo.master.set_state("BOOT", [4])
        d.get(url)
        page(d, "slaves")
        al = "#slave-row-4 td.alstatus"
        wait(d, lambda d: q(d, f"{al} span", "data-code") is not None, timeout=SLOW)
        code = int(q(d, f"{al} span", "data-code") or "0")
        text = q(d, al) or ""
        from pyethercat.wire.al import al_status_code_name

        assert code == 0x0013 and "0x0013" in text
        assert al_status_code_name(code) in text  # the code's text, not only its number
        assert "ERR" in (q(d, "#slave-row-4 .badge", "data-state") or "")
        for i in (0, 1, 2, 3, 5):
            assert q(d, f"#slave-row-{i} td.alstatus") == "–"

        # CRC errors on the cable into the di8's port 0 (ring position 2): every frame
        # that crosses it is damaged with this probability, counted by the di8 (invalid
        # frame) and forwarded-error counted by the slaves after it.
        rate = "#slave-row-2 td.rate"

        def errors_per_second(d: Any) -> float:
            text = q(d, rate) or ""
            return float(text) if text.replace(".", "", 1).isdigit() else float("nan")

        with demo.lock:
            demo.segment.crc_error_rate(1, 0, 0.02, seed=3)
        wait(d, lambda d: errors_per_second(d) > 0, timeout=SLOW)
        assert "nz" in (q(d, "#slave-row-2 td.portcell .counts", "class") or "")
        assert errors_per_second(d) > 0
        scroll, width = fits(d, "#page-slaves .tablewrap")
        assert scroll <= width
        shot(d, "slaves-errors", tmp_path, publish=False)
        with demo.lock:
            demo.segment.crc_error_rate(1, 0, 0.0)
        # Rates are per second since the previous reading: none new, none shown.
        wait(d, lambda d: errors_per_second(d) == 0, timeout=SLOW)
        assert "nz" in (q(d, "#slave-row-2 td.portcell .counts", "class") or "")  # counters stay
    assert severe_log(d) == []


#: The drives' PDOs for cyclic synchronous position, with the actual velocity beside them.
CSP_MAPPING: dict[int, Any] = {
    0x1C12: [(0x1600, [(0x6040, 0, 16), (0x6060, 0, 8), (0x607A, 0, 32)])],
    0x1C13: [(0x1A00, [(0x6041, 0, 16), (0x6061, 0, 8), (0x6064, 0, 32), (0x606C, 0, 32),
                       (0x60F4, 0, 32), (0x603F, 0, 16)])],
}
_REV = 65536  # encoder increments per revolution of the simulated motors
_EPOCH = 800_000_000_000_000_000  # the master's "now" at virtual time 0 (ns since 2000)


def test_drives_page_follows_drives_in_motion(chromium: Any, tmp_path: Path) -> None:
    """Two simulated C-series drives on DC, enabled in CSP by the master's DriveGroup, move
    back and forth: the page's position changes, the following error is a number, the
    scope fills."""
    from pyethercat.cli.demo_motion import motion_topology
    from pyethercat.master.cia402 import DriveGroup
    from pyethercat.master.dc import DcSettings
    from pyethercat.sim.topology import parse_topology
    from pyethercat.trajectory import s_curve

    clock = VirtualClock(1_000_000_000)
    seg = parse_topology(motion_topology(2)).build(clock=clock)
    m = Master(PairLink.responder_link(seg.process, name="sim:drives"), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + _EPOCH
    m.scan()
    m.set_state("PREOP")
    for s in m.slaves:
        s.set_pdo_mapping(CSP_MAPPING)
    m.configure()
    cycle = 0.002
    m.dc.setup(DcSettings(static_sync=500))
    m.dc.configure_sync(int(cycle * 1e9))
    m.pd.bring_up(m.slaves, 5.0)
    runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves,  # type: ignore[arg-type]
                          cycle=cycle, clock=clock, check_interval=0,
                          dc=m.dc.cycle(int(cycle * 1e9), "master", clock))
    runner.run(seconds=0.3)  # the phase lock settles
    m.request_state("OP")
    runner.run(seconds=0.1)
    group = DriveGroup(m, runner=runner)
    group.set_mode("csp", timeout=2.0)
    group.enable(timeout=2.0)
    m.pd.runner = _Running(runner)  # type: ignore[assignment]

    # Back and forth, 3 and 2 revolutions, a pause at each end, over and over.
    start = group.positions_actual().astype(np.float64)
    goal = start + np.array([3 * _REV, -2 * _REV])
    out = s_curve(start, goal, vmax=3 * _REV, amax=20 * _REV, jmax=300 * _REV, dt=cycle,
                  synchronized=True).position
    rest = int(0.3 / cycle)
    rows = np.vstack([out, np.repeat(out[-1:], rest, 0), out[::-1], np.repeat(out[:1], rest, 0)])
    lock = threading.Lock()
    loop = SteppedLoop(runner, clock, lock)
    k = 0

    def move() -> None:
        nonlocal k
        group.stream(rows[k:k + 10], record=False)
        k = (k + 10) % len(rows)

    loop.work = move
    d = chromium
    with serve_in_process(m, "sim:drives", lock) as url, loop:
        d.get(url)
        page(d, "drives")
        for i in (0, 1):
            wait(d, lambda d, i=i: "operation enabled" in (q(d, f"#drive-{i}") or ""),
                 timeout=SLOW)
        assert "CYCLIC_SYNC_POSITION" in (q(d, "#drive-0") or "")

        def shown(i: int, label: str) -> str:
            return str(d.execute_script(
                "for (const k of document.querySelectorAll(`#drive-${arguments[0]} .kv div`))"
                "  if (k.firstChild.textContent === arguments[1]) return k.lastChild.textContent;"
                "return null;", i, label))

        first = shown(0, "Position")
        wait(d, lambda d: shown(0, "Position") not in (first, "–"), timeout=SLOW)
        assert shown(0, "Position").lstrip("-").isdigit()
        for i in (0, 1):
            assert shown(i, "Following error").lstrip("-").isdigit()  # 0x60F4, mapped
            assert shown(i, "Velocity").lstrip("-").isdigit()

        def scope(i: int) -> list[list[float | None]]:
            return d.execute_script(  # type: ignore[no-any-return]
                "const c = S.charts[`chart-drive-${arguments[0]}`];"
                "return c ? [c.data[1], c.data[2]] : [[], []];", i)

        # The scope: a few seconds of positions that moved, following errors beside them.
        wait(d, lambda d: len({p for p in scope(0)[0] if p is not None}) >= 20, timeout=SLOW,
             describe=lambda d: f"{len(scope(0)[0])} points")
        positions, errors = scope(0)
        assert any(e is not None for e in errors)
        assert max(p for p in positions if p is not None) > min(p for p in positions if p is not None)
        shot(d, "drives", tmp_path)
    print(f"drives: {runner.stats.cycles} cycles, {runner.stats.late} late (virtual time)")
    assert severe_log(d) == []
