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

import math
from dataclasses import dataclass
from typing import Any

import click

from pyethercat.cli._connect import Connection
from pyethercat.cli._session import own_master
from pyethercat.cli._util import number
from pyethercat.errors import ConfigError
from pyethercat.master.clocks import DcStatus
from pyethercat.master.dc import DEFAULT_STATIC_SYNC, DcReport, DcSettings
from pyethercat.master.master import Master

__all__ = ["SyncOptions", "configure_sync_from_options", "format_dc", "microseconds", "register",
           "sync_options", "wall_clock_for_sim"]

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


@dataclass(frozen=True)
class SyncOptions:
    """``--sync0/--sync1/--shift`` checked and in ns (see :func:`sync_options`)."""

    cycle0_ns: int
    shift_ns: int = 0
    sync1_delay_ns: int | None = None
    sync1_multiple: int | None = None


def microseconds(text: str, option: str) -> int:
    """A time in µs as typed after ``option`` (decimals allowed), in whole ns.

    :class:`ConfigError` for anything but a finite number.
    """
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{option} {text!r}: not a number of microseconds") from None
    if not math.isfinite(value):
        raise ConfigError(f"{option} {text!r}: not a number of microseconds")
    return int(round(value * 1000))


def sync_options(cycle_ns: int, sync0_us: str | None, sync1_us: str | None,
                 shift_us: str | None) -> SyncOptions:
    """Check ``--sync0/--sync1/--shift`` (µs) before the segment is touched.

    ``cycle_ns`` is the SYNC0 cycle when ``--sync0`` is not given. The shift
    lies within the SYNC0 cycle (0 up to below one cycle): the start time is
    put on the cycle grid plus the shift, so a shift of a cycle or more would
    be the same pulses under another name (IgH and SOEM take it the same
    way). ``--sync1`` below the SYNC0 cycle is a delay after each SYNC0; a
    multiple of it makes SYNC1 fire every n-th SYNC0 cycle.
    """
    cycle0 = microseconds(sync0_us, "--sync0") if sync0_us is not None else cycle_ns
    if cycle0 <= 0:
        raise ConfigError(f"--sync0 {sync0_us}: the SYNC0 cycle must be positive")
    shift = microseconds(shift_us, "--shift") if shift_us is not None else 0
    if not 0 <= shift < cycle0:
        raise ConfigError(f"--shift {shift_us} us: the shift must lie within the SYNC0 cycle "
                          f"(0 up to below {cycle0 / 1000:g} us)")
    if sync1_us is None:
        return SyncOptions(cycle0, shift)
    s1 = microseconds(sync1_us, "--sync1")
    if 0 <= s1 < cycle0:
        return SyncOptions(cycle0, shift, sync1_delay_ns=s1)
    if s1 > 0 and s1 % cycle0 == 0:
        return SyncOptions(cycle0, shift, sync1_multiple=s1 // cycle0)
    raise ConfigError(f"--sync1 {sync1_us} us: give a delay below the SYNC0 cycle "
                      f"({cycle0 / 1000:g} us) or a multiple of it")


def configure_sync_from_options(m: Master, options: SyncOptions) -> int:
    """Ask for the SYNC pulses ``options`` describe (:func:`sync_options`); returns the
    slaves configured."""
    return len(m.dc.configure_sync(options.cycle0_ns, options.shift_ns,
                                   sync1_delay_ns=options.sync1_delay_ns,
                                   sync1_multiple=options.sync1_multiple))


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
        # Bad values and an unwritable plot fail here, before the segment is touched.
        sync = None
        if sync0_us is not None or sync1_us is not None or shift_us is not None:
            sync = sync_options(1_000_000, sync0_us, sync1_us, shift_us)
        ref = None if reference is None else number(reference, "--reference")
        if plot:
            from pyethercat.cli.dc_plot import check_plot_path

            check_plot_path(plot)
        # DC set-up writes every slave's offsets and delays: not beside a running master.
        with own_master(obj) as conn:
            wall_clock_for_sim(conn)
            m = conn.master
            m.scan(reset=False)
            if not m.slaves:
                raise ConfigError("no slaves found")
            trace = max(1, static // 60) if plot and static else 0
            settings = DcSettings(reference=ref, static_sync=static, trace_every=trace)
            report = m.dc.setup(settings)
            if sync is not None:
                configure_sync_from_options(m, sync)
                m.dc.apply_sync()
            click.echo(format_dc(report, m.dc.status()))
            if plot:
                from pyethercat.cli.dc_plot import plot_dc

                plot_dc(plot, report, title=f"DC set-up, {len(m.slaves)} slaves")
                click.echo(f"# plot written to {plot}")
