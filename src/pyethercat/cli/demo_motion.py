"""``pyethercat demo --motion``: simulated servo drives on DC follow S-curve moves.

The segment is N simulated CiA 402 drives (the C-series servo controller,
``builtin:seed002-drive``) in this process, the master and the drives on one
virtual clock, so every cycle is exact however busy the host is (with
``--iface``/``--udp`` the same runs on real drives, in real time). The master
maps their PDOs
for cyclic synchronous position (controlword, mode, target position /
statusword, mode display, position, following error, error code), sets up
distributed clocks with SYNC0 at the cycle time, brings them to OP, enables
them and streams jerk-limited moves to all of them at once
(``pyethercat.trajectory.s_curve``, ``master.cia402.DriveGroup``). It prints
the following error of every drive and writes a PNG: commanded and actual
position over time, and the following error the drives report (0x60F4).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from typing import Any

import numpy as np
import numpy.typing as npt
from rich.console import Console
from rich.table import Table

from pyethercat.cli._connect import connect
from pyethercat.cli._session import serving
from pyethercat.errors import ConfigError
from pyethercat.master.cia402 import DriveGroup, MotionRecord
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.dc import DcSettings
from pyethercat.master.master import Master
from pyethercat.trajectory import s_curve

__all__ = ["CSP_MAPPING", "motion_topology", "plot_motion", "run_motion"]

#: The PDOs a CSP master maps (written in PRE-OP; the drive's default assigns none).
CSP_MAPPING: dict[int, Any] = {
    0x1C12: [(0x1600, [(0x6040, 0, 16), (0x6060, 0, 8), (0x607A, 0, 32)])],
    0x1C13: [(0x1A00, [(0x6041, 0, 16), (0x6061, 0, 8), (0x6064, 0, 32), (0x60F4, 0, 32),
                       (0x603F, 0, 16)])],
}
_REV = 65536  # encoder increments per revolution of the simulated motors (0x608F)
_EPOCH = 800_000_000_000_000_000  # the simulated master's "now" at virtual time 0 (ns since 2000)
I64 = npt.NDArray[np.int64]


def motion_topology(drives: int) -> str:
    """A line of ``drives`` simulated servo drives."""
    return "".join(f'[[slave]]\nname = "axis{i + 1}"\ndevice = "builtin:seed002-drive"\n'
                   for i in range(drives))


def _moves(start: I64, drives: int, cycle: float) -> list[npt.NDArray[np.float64]]:
    """Back-and-forth S-curves of different lengths (1.5 to 4 revolutions), all axes together."""
    spans = np.linspace(1.5, 4.0, drives) * _REV * np.where(np.arange(drives) % 2, -1, 1)
    goals = [start + spans, start + spans * 0.25, start]
    out = []
    here = start.astype(np.float64)
    for goal in goals:
        traj = s_curve(here, goal, vmax=8 * _REV, amax=60 * _REV, jmax=1500 * _REV, dt=cycle,
                       synchronized=True)
        out.append(traj.position)
        here = goal.astype(np.float64)
    return out


def plot_motion(path: str, rec: MotionRecord, names: list[str], title: str) -> None:
    """Commanded vs actual position (revolutions) and the following error (increments)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ConfigError("demo --motion needs matplotlib: pip install 'pyethercat[plot]'") from None
    t = rec.t
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True,
                                      gridspec_kw={"height_ratios": [3, 2]})
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, name in enumerate(names):
        c = colors[i % len(colors)]
        top.plot(t, rec.commanded[:, i] / _REV, color=c, linewidth=2.5, alpha=0.35,
                 label=f"{name} commanded")
        top.plot(t, rec.actual[:, i] / _REV, color=c, linewidth=1.0, label=f"{name} actual")
        if rec.following_error is not None:
            bottom.plot(t, rec.following_error[:, i], color=c, linewidth=0.9, label=name)
    top.set_ylabel("position (revolutions)")
    top.set_title(title, fontsize=11)
    top.grid(True, alpha=0.3)
    top.legend(fontsize="x-small", ncol=2, loc="upper right")
    bottom.set_ylabel("following error 0x60F4 (increments)")
    if rec.following_error is not None and rec.following_error.size:
        peak = int(np.abs(rec.following_error).max())
        bottom.set_title(f"following error: peak {peak} increments "
                         f"(1 revolution = {_REV} increments)", fontsize=9)
    bottom.set_xlabel("time (s)")
    bottom.grid(True, alpha=0.3)
    bottom.legend(fontsize="x-small", ncol=min(4, len(names)), loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _virtual_segment(drives: int) -> tuple[Master, Any, Any]:
    """N drives in this process, master and segment on one virtual clock."""
    from pyethercat.clock import VirtualClock
    from pyethercat.link.pair import PairLink
    from pyethercat.sim.topology import parse_topology

    clock = VirtualClock(1_000_000_000)
    segment = parse_topology(motion_topology(drives)).build(clock=clock)
    m = Master(PairLink.responder_link(segment.process, name="sim:motion"), clock=clock)
    m.dc.master_time = lambda: clock.now_ns() + _EPOCH
    return m, segment, clock


def run_motion(obj: dict[str, Any], *, drives: int, cycle_us: int, plot: str | None,
               pcap: str | None, console: Console) -> None:
    """The demo (see the module docstring); raises :class:`ConfigError` when a drive faults."""
    if not 1 <= drives <= 64:
        raise ConfigError(f"demo --motion: --drives must be 1-64, got {drives}")
    if cycle_us < 250:
        raise ConfigError(f"demo --motion: the drives take cycles of 250 us or more, got {cycle_us}")
    if pcap is not None:
        raise ConfigError("demo --motion writes no capture (--pcap is for the IO demo)")
    cycle = cycle_us / 1e6
    obj = dict(obj or {})
    real = obj.get("iface") is not None or obj.get("udp") is not None
    if obj.get("sim") is not None:
        raise ConfigError("demo --motion makes its own simulated drives: no --sim")
    plot = plot or os.path.join(tempfile.gettempdir(), f"pyethercat-motion-{os.getpid()}.png")
    with contextlib.ExitStack() as stack:
        if real:
            conn = stack.enter_context(connect(obj))
            m = conn.master
            stack.enter_context(serving(obj, m))
            console.print(f"[bold]pyethercat demo --motion[/bold] on {obj.get('iface') or obj.get('udp')}")
        else:
            m, _segment, clock = _virtual_segment(drives)
            stack.callback(m.close)
            console.print(f"[bold]pyethercat demo --motion[/bold]: {drives} simulated servo drives "
                          "in this process, master and drives on one virtual clock (exact "
                          "cycles whatever the host does)")
        m.scan()
        m.set_state("PREOP")
        for s in m.slaves:
            s.set_pdo_mapping(CSP_MAPPING)
        m.configure()
        # a short static drift compensation: the cyclic one (FRMW every cycle) does the rest
        m.dc.setup(DcSettings(static_sync=500))
        m.dc.configure_sync(int(cycle * 1e9))
        if real:
            runner = m.start(cycle, dc="master")
            stack.callback(runner.stop)
            group = DriveGroup(m)
        else:
            m.pd.bring_up(m.slaves, 5.0)
            assert m.process_data is not None
            runner = CyclicRunner(m.scheduler, m.process_data, m.images, m.slaves, cycle=cycle,
                                  clock=clock, check_interval=0,
                                  dc=m.dc.cycle(int(cycle * 1e9), "master", clock))
            runner.run(seconds=0.3)  # the phase lock settles
            m.request_state("OP")
            runner.run(seconds=0.1)
            group = DriveGroup(m, runner=runner)
        group.set_mode("csp", timeout=2.0)
        group.enable(timeout=2.0)
        console.print(f"{len(group)} drives in Operation enabled, CSP, SYNC0 every {cycle_us} us; "
                      "moving")
        start = group.positions_actual()
        rows = np.vstack(_moves(start, len(group), cycle))
        t0 = time.monotonic()
        rec = group.stream(rows, settle=int(0.2 / cycle))
        took = time.monotonic() - t0
        assert rec is not None and rec.following_error is not None
        missed = [int(s.sdo_read(0x1C32, 0x0B, "uint16")) for s in m.slaves]
        reached = bool((group.statuswords() & 0x0400).all())
        group.disable(timeout=2.0)
        stats = runner.stats
    names = [f"axis{i + 1}" for i in range(len(group))]
    fe = np.abs(rec.following_error)
    table = Table(title="following error (0x60F4, increments)")
    for col in ("drive", "max |e|", "RMS e", "max |e| (deg)", "SM events missed"):
        table.add_column(col, justify="right")
    for i, name in enumerate(names):
        table.add_row(name, str(int(fe[:, i].max())),
                      f"{float(np.sqrt(np.mean(rec.following_error[:, i].astype(np.float64) ** 2))):.1f}",
                      f"{fe[:, i].max() * 360 / _REV:.3f}", str(missed[i]))
    console.print(table)
    console.print(f"{len(rec.commanded)} cycles ({len(rec.commanded) * cycle:.2f} s of motion) in "
                  f"{took:.2f} s; target reached at the end: {'yes' if reached else 'no'}; "
                  f"{stats.wkc_errors} WKC errors, {stats.lost_frames} lost frames")
    plot_motion(plot, rec, names,
                f"pyethercat demo --motion: {len(names)} simulated servo drives, CSP on DC "
                f"SYNC0 {cycle_us} us, S-curve moves")
    console.print(f"plot written to {plot}")
