"""``pyethercat dc``: distributed clocks of the segment, set up as ``run --dc`` does.

The command scans, latches the receive times, computes the delays and
offsets, writes 0x0920/0x0928, runs the static drift compensation and, with
``--sync0``, starts SYNC0 (and SYNC1) on every slave with a DC op mode. Then
it reads the DC registers back and prints one line per slave::

    # pos  station  dc          ref  entry  parent  delay_ns  offset_ns  diff_ns  sync
    0      0x1001   64-bit      *    0      -       0         -1234...   0        off

``dc`` is ``64-bit``/``32-bit``, ``latch-only`` (receive times, no system
time) or ``no``; ``diff_ns`` is |0x092C|; ``sync`` the cyclic unit as read
back (AssignActivate, SYNC0 cycle and shift, SYNC1 cycle register).
"""

from __future__ import annotations

from typing import Any

import click

from pyethercat.cli._connect import Connection
from pyethercat.cli._session import own_master
from pyethercat.cli._util import parse_int
from pyethercat.errors import ConfigError
from pyethercat.master.clocks import DcStatus
from pyethercat.master.dc import DEFAULT_STATIC_SYNC, DcReport, DcSettings
from pyethercat.master.master import Master

__all__ = ["configure_sync_from_options", "format_dc", "register", "wall_clock_for_sim"]

TABLE_HEADER = ("# pos  station  dc          ref  entry  parent  delay_ns  offset_ns"
                "             diff_ns  sync")


def wall_clock_for_sim(conn: Connection) -> None:
    """An in-process simulator keeps real time while DC runs (its clocks must move with ours)."""
    seg = conn.segment
    if seg is None:
        return
    from pyethercat.clock import WallClock

    seg.advance_clock = False
    seg.clock = WallClock()


def configure_sync_from_options(m: Master, cycle_ns: int, sync0_us: str | None,
                                sync1_us: str | None, shift_us: str | None) -> int:
    """SYNC settings from ``--sync0/--sync1/--shift`` (µs); returns the slaves configured.

    ``--sync1`` below the SYNC0 cycle is a delay after each SYNC0; a multiple
    of it makes SYNC1 fire every n-th SYNC0 cycle.
    """
    cycle0 = int(round(float(sync0_us) * 1000)) if sync0_us is not None else cycle_ns
    shift = int(round(float(shift_us) * 1000)) if shift_us is not None else 0
    kw: dict[str, int] = {}
    if sync1_us is not None:
        s1 = int(round(float(sync1_us) * 1000))
        if s1 < cycle0:
            kw["sync1_delay_ns"] = s1
        elif s1 % cycle0 == 0:
            kw["sync1_multiple"] = s1 // cycle0
        else:
            raise ConfigError(f"--sync1 {sync1_us} us: give a delay below the SYNC0 cycle "
                              f"({cycle0 / 1000:g} us) or a multiple of it")
    return len(m.dc.configure_sync(cycle0, shift, **kw))  # type: ignore[arg-type]


def _sync_text(st: DcStatus) -> str:
    aa = st.assign_activate
    if aa is None:
        return "-"
    if not aa.active:
        return "off"
    return (f"{aa.describe()} cycle0 {st.sync0_cycle} cycle1 {st.sync1_cycle} "
            f"start {st.start_time}")


def format_dc(report: DcReport, status: list[DcStatus]) -> str:
    """The text of ``pyethercat dc``: a summary, then one line per slave."""
    lines = []
    ref = report.reference_slave
    if ref is not None:
        lines.append(f"# reference clock: slave {ref.position} (0x{ref.station_address:04X}, "
                     f"{ref.name or '?'}), {ref.kind}")
    worst = report.worst_difference_ns
    lines.append(f"# static drift compensation: {report.static_sync} FRMW in "
                 f"{report.static_frames} frames; set-up took {report.duration_s * 1000:.0f} ms; "
                 f"worst |0x092C| {'-' if worst is None else worst} ns")
    lines.append(TABLE_HEADER)
    for r, st in zip(report.slaves, status, strict=True):
        parent = "-" if r.parent is None else f"{r.parent}:{r.parent_port}"
        delay = st.delay if st.delay is not None else r.delay_ns
        offset = st.offset if st.offset is not None and st.bits == 64 else r.offset_ns
        diff = st.difference if st.difference is not None else r.difference_ns
        kind = "before-ref" if r.before_reference else r.kind
        lines.append(
            f"{r.position:<6} 0x{r.station_address:04X}   {kind:<11} {'*' if r.reference else '-':<4} "
            f"{r.entry_port if r.supported else '-':<6} {parent:<7} "
            f"{'-' if delay is None or not r.system_time else delay:<9} "
            f"{'-' if offset is None else offset:<21} {'-' if diff is None else diff:<8} "
            f"{_sync_text(st) if r.system_time else '-'}")
    for w in report.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def register(cli: click.Group) -> None:
    """Add ``dc`` to the command line."""

    @cli.command("dc")
    @click.option("--reference", "reference", metavar="POS", default=None,
                  help="Ring position of the reference clock [default: first DC slave].")
    @click.option("--static", "static", default=DEFAULT_STATIC_SYNC, show_default=True,
                  type=click.IntRange(0, 10_000_000), metavar="N",
                  help="FRMW of the static drift compensation.")
    @click.option("--sync0", "sync0_us", default=None, metavar="US",
                  help="Start SYNC0 with this cycle (µs) on every slave with a DC op mode.")
    @click.option("--shift", "shift_us", default=None, metavar="US", help="SYNC0 shift (µs).")
    @click.option("--sync1", "sync1_us", default=None, metavar="US",
                  help="SYNC1: delay after SYNC0 (below its cycle) or a multiple of the cycle.")
    @click.option("--plot", "plot", default=None, metavar="FILE.png",
                  help="Plot |0x092C| per slave over the compensation (matplotlib).")
    @click.pass_obj
    def dc_cmd(obj: dict[str, Any], reference: str | None, static: int, sync0_us: str | None,
               shift_us: str | None, sync1_us: str | None, plot: str | None) -> None:
        """Set up distributed clocks and show each slave's DC state."""
        # DC set-up writes every slave's offsets and delays: not beside a running master.
        with own_master(obj) as conn:
            wall_clock_for_sim(conn)
            m = conn.master
            m.scan(reset=False)
            if not m.slaves:
                raise ConfigError("no slaves found")
            trace = max(1, static // 60) if plot and static else 0
            settings = DcSettings(reference=None if reference is None else parse_int(reference),
                                  static_sync=static, trace_every=trace)
            report = m.dc.setup(settings)
            if sync0_us is not None or sync1_us is not None or shift_us is not None:
                cycle_ns = int(round(float(sync0_us or 1000) * 1000))
                configure_sync_from_options(m, cycle_ns, sync0_us, sync1_us, shift_us)
                m.dc.apply_sync()
            click.echo(format_dc(report, m.dc.status()))
            if plot:
                from pyethercat.cli.dc_plot import plot_dc

                plot_dc(plot, report, title=f"DC set-up, {len(m.slaves)} slaves")
                click.echo(f"# plot written to {plot}")
