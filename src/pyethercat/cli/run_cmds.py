"""``pyethercat pdos`` and ``pyethercat run``: process data from the command line.

``pdos [-p POS]`` lists each slave's sync managers, PDOs and entries (as
IgH's ``ethercat pdos`` does) plus where the master maps them: the logical
address and bit of every block. ``run [--cycle US] [--seconds S]`` brings the
segment to OP and runs the cyclic exchange with a live view (states, working
counters, cycle statistics, the link) refreshed in place. The run survives
link loss (the view says "link DOWN"; slaves come back to OP when it
returns). Ctrl-C or SIGTERM ends it early; every end is an orderly stop
(safe outputs, SAFEOP, ``--final-state``) followed by the statistics, and
the exit status is 1 when the segment did not come back.
``run --eni FILE`` starts from an ENI file instead of an SII scan (identities
checked, PDO assignment and InitCmds from the file, its cycle time the default).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import click
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from pyethercat.cli._connect import connect
from pyethercat.cli._lifecycle import (
    FINAL_STATES,
    SETTLE,
    StopSignals,
    cycle_until,
    segment_lost_error,
)
from pyethercat.cli._select import selection_options
from pyethercat.cli._session import open_session, serving
from pyethercat.cli._util import parse_int
from pyethercat.errors import ConfigError
from pyethercat.master.config import PdoDirection, ProcessDataConfig
from pyethercat.master.control import messages as msg
from pyethercat.master.cyclic import JITTER_BINS_US, CyclicRunner
from pyethercat.master.engine.runner import IsolatedRunner
from pyethercat.master.master import Master
from pyethercat.master.slave import Slave
from pyethercat.wire.al import state_name
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.registers import AL_ERROR_FLAG
from pyethercat.wire.sii.model import SyncManagerType

__all__ = ["register", "format_pdos", "live_view", "format_summary"]

_SM_KIND: dict[int, str] = {SyncManagerType.MAILBOX_OUT: "mailbox out", SyncManagerType.MAILBOX_IN: "mailbox in",
            SyncManagerType.OUTPUTS: "outputs", SyncManagerType.INPUTS: "inputs"}


def _type_name(code: int) -> str:
    try:
        return DataType(code).name
    except ValueError:
        return f"type 0x{code:04X}" if code else "-"


def format_pdos(slaves: Sequence[Slave], cfg: ProcessDataConfig, positions: list[int]) -> str:
    """The text of ``pyethercat pdos`` for the given slave positions."""
    lines: list[str] = []
    for p in positions:
        s = slaves[p]
        sc = cfg.slaves[p]
        lines.append(f"=== slave {p} ({s.address_text}, {s.name or '?'}) ===")
        if not sc.sync_managers:
            lines.append("  no sync managers")
        for sm in sc.sync_managers:
            kind = _SM_KIND.get(sm.sm_type, f"type {sm.sm_type}")
            lines.append(f"SM{sm.index}: PhysAddr 0x{sm.start:04X}, Size {sm.length:4d}, "
                         f"Control 0x{sm.control:02X}, Enable {sm.activate}, {kind}")
            for pdo in sm.pdos:
                tag = "RxPDO" if pdo.direction is PdoDirection.OUTPUTS else "TxPDO"
                lines.append(f"  {tag} 0x{pdo.index:04X} \"{pdo.name}\"")
                for e in pdo.entries:
                    if e.index == 0:
                        lines.append(f"    (gap) {e.bit_length} bit")
                        continue
                    lines.append(f"    PDO entry 0x{e.index:04X}:{e.subindex:02X}, "
                                 f"{e.bit_length:2d} bit, {_type_name(e.data_type)}, \"{e.name}\"")
        for f in sc.fmmus:
            what = "outputs" if f.fmmu_type & 2 else "inputs"
            lines.append(f"FMMU{f.index}: logical 0x{f.logical_start:08X}.{f.logical_start_bit}"
                         f"-{f.logical_stop_bit} ({f.length} byte{'s' if f.length != 1 else ''}, "
                         f"{f.bit_length} bit) <-> 0x{f.physical_start:04X}.{f.physical_start_bit}"
                         f" {what}")
        for w in sc.warnings:
            lines.append(f"note: {w}")
    for g in cfg.groups:
        if not positions or any(cfg.slaves[p].group == g.name for p in positions):
            kinds = ", ".join(f"{d.command.name} 0x{d.logical_address:08X}+{d.length} "
                              f"WKC {d.expected_wkc}" for d in g.datagrams) or "no datagrams"
            lines.append(f"group {g.name}: {g.output_bytes} output + {g.input_bytes} input bytes "
                         f"at 0x{g.logical_base:08X} ({g.layout.value}); {kinds}")
    return "\n".join(lines)


def _fmt(v: float, digits: int = 1) -> str:
    return "-" if math.isnan(v) else f"{v:.{digits}f}"


def live_view(master: Master, runner: CyclicRunner, extra: Callable[[], list[str]] | None = None
              ) -> Group:
    """A rich renderable: slaves and states, groups and WKC, cycle statistics, events."""
    slaves = Table(title="slaves", expand=False, show_edge=False)
    for col in ("pos", "address"):
        slaves.add_column(col, no_wrap=True)
    # Whole SII names (up to 64 characters); only a narrow terminal cuts them.
    slaves.add_column("name", no_wrap=True, overflow="ellipsis")
    for col in ("state", "supervision"):
        slaves.add_column(col, no_wrap=True)
    for s in master.slaves:
        h = runner.health.get(s.position)
        current = runner.slave_state(s.position)
        if h is None:
            state = Text(s.al_state_name)
        elif current is not None:
            state = Text(state_name(current))
        else:
            # Never a stale state as if it were current.
            last = state_name(h.state | (AL_ERROR_FLAG if h.error else 0)) if h.state else ""
            state = Text("unknown" + (f" (was {last})" if last else ""), style="yellow")
        status = h.status if h else "-"
        style = "green" if status == "ok" else ("yellow" if status == "lost" else "red")
        slaves.add_row(str(s.position), s.address_text, s.name or "?", state,
                       Text(status, style=style))
    st = runner.stats
    jit = st.jitter_us()
    rtt = st.round_trip_us()
    per = st.period_us()
    stats = Table(title="cycles", show_header=False, show_edge=False)
    stats.add_column("what")
    stats.add_column("value")
    stats.add_row("link", _link_text(runner))
    stats.add_row("cycles", f"{st.cycles} at {st.period_ns / 1000:g} us")
    stats.add_row("period mean/min/max us",
                  f"{_fmt(per['mean'])} / {_fmt(per['min'])} / {_fmt(per['max'])}")
    stats.add_row("jitter p50/p99/max us",
                  f"{_fmt(jit['p50'])} / {_fmt(jit['p99'])} / {_fmt(jit['p100'])}")
    stats.add_row("round trip p50/p99 us", f"{_fmt(rtt['p50'])} / {_fmt(rtt['p99'])}")
    stats.add_row("jitter histogram", _histogram_text(st.histogram))
    stats.add_row("late / overruns / skipped", f"{st.late} / {st.overruns} / {st.skipped}")
    stats.add_row("loop", loop_text(runner))
    stats.add_row("WKC errors / lost frames", f"{st.wkc_errors} / {st.lost_frames}")
    for g in runner.groups:
        ok = Text("ok", style="green") if g.wkc_ok else Text("BAD", style="red")
        age = g.image.input_age
        stale = Text(f" inputs {age} cycles old", style="yellow") if age else Text("")
        stats.add_row(f"group {g.name} WKC",
                      Text.assemble(f"{g.total_wkc}/{g.expected_wkc} ", ok, stale))
    parts: list[Any] = [slaves, stats]
    lines = list(extra()) if extra is not None else []
    dc = runner.dc_status_line()
    if dc is not None:
        lines.append(dc)
    recent = [e.text for e in list(runner.events)[-4:]]
    # Located faults stand until cleared, however much the event log scrolls.
    lines += [f"fault now: {f}" for f in runner.fault_board.lines
              if not any(f in line for line in recent)]
    lines += recent
    if lines:
        parts.append(Text("\n".join(lines)))
    return Group(*parts)


def _histogram_text(counts: Sequence[int]) -> str:
    """Non-empty bins of the period-jitter histogram: ``<1us 9012  <2us 85 ...``."""
    names = [f"<{b}us" for b in JITTER_BINS_US] + [f">={JITTER_BINS_US[-1]}us"]
    return "  ".join(f"{n} {c}" for n, c in zip(names, counts, strict=True) if c) or "-"


def loop_text(runner: CyclicRunner) -> str:
    """Where the loop runs and with what priority and CPU share."""
    if isinstance(runner, IsolatedRunner):
        return runner.engine_line()
    fifo = runner.thread_priority
    return f"thread of this process, {f'SCHED_FIFO {fifo}' if fifo else 'normal priority'}"


def _link_text(runner: CyclicRunner) -> Text:
    st = runner.stats
    if not st.link_up:
        return Text(f"DOWN for {runner.down_for():.1f} s ({st.down_cycles} cycles lost)",
                    style="bold red")
    if st.link_downs:
        return Text(f"up; down {st.link_downs}x before ({st.down_ns / 1e9:.2f} s, "
                    f"{st.down_cycles} cycles lost)", style="yellow")
    return Text("up", style="green")


def format_summary(runner: CyclicRunner) -> str:
    """A few lines summarising a run."""
    st = runner.stats
    jit = st.jitter_us((50, 90, 99, 99.9, 100))
    rtt = st.round_trip_us()
    per = st.period_us()
    down = (st.down_ns + st.down_for_ns(st.last_ns or 0)) / 1e9
    return "\n".join([
        f"cycles: {st.cycles} at {st.period_ns / 1000:g} us (mean period {_fmt(per['mean'], 2)} us)",
        "jitter us: " + ", ".join(f"{k} {_fmt(v)}" for k, v in jit.items()),
        f"round trip us: p50 {_fmt(rtt['p50'])}, p99 {_fmt(rtt['p99'])}",
        f"late cycles: {st.late}, overruns: {st.overruns} (callback {st.callback_overruns}), "
        f"skipped: {st.skipped}",
        f"WKC errors: {st.wkc_errors}, lost frames: {st.lost_frames}",
        f"link: {'up' if st.link_up else 'DOWN'} at the end; down {st.link_downs} times, "
        f"{down:.2f} s, {st.down_cycles} cycles lost",
    ] + ([dc] if (dc := runner.dc_status_line()) is not None else []))


def _isolate_for_web(m: Master) -> bool:
    """Whether ``run --web`` moves the loop into the isolated engine (it does when it can).

    The dashboard's requests (telemetry snapshots, register reads, SDOs,
    their JSON) are served by this process's control-socket thread. A loop
    thread in the same interpreter waits for the GIL behind them: its p99
    jitter went from 2 us to 3 ms with two browsers open. In a process of
    its own the loop only carries their datagrams (docs/web.md).
    """
    from pyethercat.master.engine.launch import link_can_move

    why = link_can_move(m.scheduler.link)
    if why is None:
        click.echo("run --web: the cyclic loop runs in a process of its own (as --isolated), "
                   "out of reach of the dashboard's requests")
        return True
    click.echo(f"run --web: the cyclic loop stays in this process beside the dashboard's "
               f"requests ({why}); its jitter rises while browsers are open")
    return False


def register(cli: click.Group) -> None:
    """Add ``pdos`` and ``run`` to the command line."""

    @cli.command("pdos")
    @selection_options
    @click.pass_obj
    def pdos_cmd(obj: dict[str, Any], position: str | None, alias: str | None) -> None:
        """Sync managers, PDOs and entries of every slave, and their logical mapping."""
        with open_session(obj) as session:
            cfg = session.call(msg.GetConfig(compute=True)).config
            slaves = session.slaves()
            positions = [p for p in session.select(position, alias) if p < len(slaves)]
            if position is not None and not positions:
                raise ConfigError(f"no slave at position {position}: the segment has "
                                  f"{len(slaves)} slaves")
        assert cfg is not None
        click.echo(format_pdos(slaves, cfg, positions))

    @cli.command("run")
    @click.option("--cycle", "cycle_us", default=None, metavar="US",
                  help="Cycle time in microseconds [default: the ENI's, else 1000].")
    @click.option("--seconds", default=None, type=float, metavar="S",
                  help="Stop after S seconds (default: until Ctrl-C or SIGTERM).")
    @click.option("--pcap", default=None, metavar="FILE", help="Record every frame to FILE.")
    @click.option("--layout", type=click.Choice(["packed", "byte"]), default="packed",
                  show_default=True, help="Bit-packed or byte-aligned process image.")
    @click.option("--eni", "eni_file", default=None, metavar="FILE",
                  help="Start from this ENI file (no SII scan; see 'eni export').")
    @click.option("--dc", "dc", is_flag=True,
                  help="Distributed clocks: set-up, SYNC0 on slaves with a DC op mode, "
                       "the reference time in every frame.")
    @click.option("--sync0", "sync0_us", default=None, metavar="US",
                  help="SYNC0 cycle (µs) [default: the cycle time]; implies --dc.")
    @click.option("--sync1", "sync1_us", default=None, metavar="US",
                  help="SYNC1: delay after SYNC0 (below its cycle) or a multiple of it; implies --dc.")
    @click.option("--shift", "shift_us", default=None, metavar="US",
                  help="SYNC0 shift on the cycle grid (µs); implies --dc.")
    @click.option("--dc-mode", "dc_mode", type=click.Choice(["master", "reference"]),
                  default="master", show_default=True,
                  help="master: the cycle follows the reference clock; reference: the "
                       "reference clock follows the master's time.")
    @click.option("--plot", "plot", default=None, metavar="FILE.png",
                  help="Plot the period and jitter distribution (log scale); with --dc also "
                       "the set-up's convergence, the sync monitor, the phase lock and "
                       "(simulator) the SYNC0 spread (matplotlib).")
    @click.option("--isolated", is_flag=True,
                  help="Run the cyclic loop in a process of its own, out of reach of this "
                       "process's threads (docs/realtime.md).")
    @click.option("--realtime", "priority", type=click.IntRange(0, 99), default=None,
                  metavar="PRIO", help="SCHED_FIFO priority of the loop (default: 40 for "
                                       "--isolated, none otherwise; root or CAP_SYS_NICE).")
    @click.option("--cpu", type=click.IntRange(0), default=None, metavar="N",
                  help="With --isolated: pin the loop's process to CPU N.")
    @click.option("--eoe", is_flag=True,
                  help="Bring up the EoE switch: a TAP interface joining the host's IP stack "
                       "and every EoE slave (root or CAP_NET_ADMIN).")
    @click.option("--eoe-tap", default="eoe0", show_default=True, metavar="NAME",
                  help="Name of the TAP interface (with --eoe-per-slave: the name prefix).")
    @click.option("--eoe-host-ip", default=None, metavar="ADDR/PREFIX",
                  help="The host's address on the TAP, e.g. 192.168.100.1/24.")
    @click.option("--eoe-per-slave", is_flag=True,
                  help="One TAP per EoE slave, named <prefix>s<position> (IgH's eoe0s1), "
                       "instead of one switched TAP.")
    @click.option("--hot-connect", "hot_connect", multiple=True, metavar="NAME=ALIAS[:SIZE]",
                  help="A hot connect group: the slave with ALIAS and SIZE-1 behind it may go "
                       "and come back while cycling, or be absent at the start and be "
                       "configured when it appears (repeatable).")
    @click.option("--final-state", "final_state", default="PREOP", show_default=True,
                  type=click.Choice(FINAL_STATES, case_sensitive=False),
                  help="State the slaves are left in when the run ends.")
    @click.option("--give-up", "give_up", default=60.0, show_default=True, type=float,
                  metavar="S", help="End with an error once no frame came back for S seconds "
                                    "(0: keep waiting).")
    @click.option("--web", "web", is_flag=True,
                  help="Serve the diagnostics dashboard (see 'pyethercat web') beside the "
                       "loop; the loop then runs isolated (as --isolated) where the link "
                       "can move.")
    @click.option("--web-bind", default="127.0.0.1:8080", show_default=True, metavar="HOST:PORT",
                  help="With --web: address to listen on.")
    @click.option("--web-token", default=None, metavar="TOKEN",
                  help="With --web: token for every request ('generate' makes one); needed "
                       "for a non-loopback --web-bind.")
    @click.option("--web-allow-writes", is_flag=True,
                  help="With --web: the token's holder may write outputs and SDOs.")
    @click.pass_obj
    def run_cmd(obj: dict[str, Any], cycle_us: str | None, seconds: float | None,
                pcap: str | None, layout: str, eni_file: str | None, dc: bool,
                sync0_us: str | None, sync1_us: str | None, shift_us: str | None,
                dc_mode: str, plot: str | None, eoe: bool, eoe_tap: str,
                eoe_host_ip: str | None, eoe_per_slave: bool,
                hot_connect: tuple[str, ...], final_state: str, give_up: float,
                isolated: bool, priority: int | None, cpu: int | None,
                web: bool, web_bind: str, web_token: str | None,
                web_allow_writes: bool) -> None:
        """Bring the segment to OP and run cyclic exchange with a live view."""
        web_access = None
        if web:
            from pyethercat.cli.web_cmds import resolve_access

            if obj.get("direct"):
                raise ConfigError("run --web reaches the master through its control socket: "
                                  "not with --direct")
            # A refused address (non-loopback without a token) stops here, before the segment.
            web_access = resolve_access(web_bind, web_token, web_allow_writes)
        dc = dc or any(x is not None for x in (sync0_us, sync1_us, shift_us))
        eni = None
        if eni_file is not None:
            from pyethercat.esi.eni import load_eni

            eni = load_eni(eni_file)  # a broken file fails before the segment is touched
        if cycle_us is not None:
            cycle = _whole_microseconds(cycle_us) / 1e6
        elif eni is not None and eni.cycle_time_us:
            cycle = eni.cycle_time_us / 1e6
        else:
            cycle = 1e-3
        if cycle <= 0:
            raise ConfigError(f"cycle time must be positive, got {cycle_us} us")
        if seconds is not None and seconds <= 0:
            raise ConfigError(f"run: --seconds must be positive, got {seconds:g}")
        if give_up < 0:
            raise ConfigError(f"run: --give-up must be 0 (never) or positive, got {give_up:g}")
        if cpu is not None and not isolated:
            raise ConfigError("run: --cpu pins the isolated loop's process: give --isolated")
        sync = None
        if dc:
            from pyethercat.cli.dc_cmds import sync_options

            sync = sync_options(int(round(cycle * 1e9)), sync0_us, sync1_us, shift_us)
        if plot:
            from pyethercat.cli.dc_plot import check_plot_path

            check_plot_path(plot)
        # Off a terminal rich would squeeze the table into 80 columns: give it room.
        console = Console() if sys.stdout.isatty() else Console(width=140)
        with StopSignals() as signals, connect(obj, pcap=pcap) as conn, \
                serving(obj, conn.master):
            m = conn.master
            # an in-process simulator keeps real time while the master cycles in real time
            # (its drives, watchdogs and DC clocks move with the cycle's clock)
            from pyethercat.cli.dc_cmds import wall_clock_for_sim

            wall_clock_for_sim(conn)
            # (only an in-process simulator knows when each SYNC0 pulse really fired)
            spread = None
            if plot and sync is not None and conn.segment is not None:
                from pyethercat.cli.dc_plot import Sync0Spread

                spread = Sync0Spread(conn.segment)
            if eni is not None:
                from pyethercat.master.esi_config import start_from_eni

                start_from_eni(m, eni)
            else:
                m.scan()
            m.configure(layout=layout)
            for spec in hot_connect:
                m.hot_connect(*_hot_connect_spec(spec))
            if sync is not None:
                from pyethercat.cli.dc_cmds import configure_sync_from_options
                from pyethercat.master.dc import DcSettings

                m.dc.setup(DcSettings(trace_every=250 if plot else 0))
                configure_sync_from_options(m, sync)
            if web_access is not None and not isolated:
                isolated = _isolate_for_web(m)
            runner = m.start(cycle, dc=dc_mode if dc else None, final_state=final_state.upper(),
                             isolated=isolated, realtime=priority, cpu=cpu)
            signals.cycling_with(runner)
            eoe_run = None
            extra = None
            if eoe:
                from pyethercat.cli.eoe_cmds import eoe_rows, format_eoe
                from pyethercat.master.eoe_switch import start_eoe

                try:
                    eoe_run = start_eoe(m, runner, tap=eoe_tap, host_ip=eoe_host_ip,
                                        per_slave=eoe_per_slave)
                except BaseException:
                    runner.stop()
                    raise
                run = eoe_run

                def extra() -> list[str]:
                    return format_eoe(eoe_rows(run.clients, run.bridge.names, True,
                                               time.monotonic() - run.started))
            web_child = None
            if web_access is not None:
                from pyethercat.cli.web_cmds import start_child

                try:
                    web_child = start_child(obj, web_access)
                except BaseException:
                    if eoe_run is not None:
                        eoe_run.close()
                    runner.stop()
                    raise
                click.echo(f"dashboard: {web_child.url}")
            console.print(f"{len(m.slaves)} slaves in OP, cycling every {cycle * 1e6:g} us "
                          f"(Ctrl-C ends the run; slaves then go to {final_state.upper()})")
            try:
                with Live(live_view(m, runner, extra), console=console, refresh_per_second=4,
                          transient=False) as live:
                    def refresh() -> None:
                        live.update(live_view(m, runner, extra))
                        if spread is not None:
                            spread.sample()

                    why = cycle_until(runner, signals, seconds, give_up, refresh)
                    if spread is not None:
                        spread.sample()
                # Judged while the slaves are still cycling (the stop takes them down).
                failure = segment_lost_error(runner, m, 0.0 if why == "gave up" else SETTLE)
            finally:
                if web_child is not None:
                    web_child.close()
                if eoe_run is not None:
                    eoe_run.close()
                runner.stop()
            # The live table's last line has no line end (off a terminal the summary
            # would start on it).
            console.print()
            click.echo(format_summary(runner))
            if plot and runner.dc is not None:
                from pyethercat.cli.dc_plot import plot_dc

                plot_dc(plot, m.dc.report, runner.dc,
                        sync0_spread=spread.series() if spread is not None else None,
                        title=f"run --dc ({dc_mode} mode), {len(m.slaves)} slaves, "
                              f"{cycle * 1e6:g} us cycle")
                click.echo(f"plot written to {plot}")
            elif plot:
                from pyethercat.cli.cycle_plot import plot_cycles

                plot_cycles(plot, runner.stats, title=f"run, {len(m.slaves)} slaves, "
                            f"{cycle * 1e6:g} us cycle ({loop_text(runner)})")
                click.echo(f"plot written to {plot}")
            if eoe_run is not None and extra is not None:
                click.echo("\n".join(extra()))
            if runner.stop_report:
                click.echo(runner.stop_report)
            if why == "signal":
                click.echo(f"ended by {signals.received}")
            if failure is not None:
                raise failure


def _whole_microseconds(text: str) -> int:
    """``--cycle US``: whole microseconds (``0x`` hex accepted), as IgH and SOEM take them."""
    try:
        return int(text, 0)
    except ValueError:
        raise ConfigError(f"--cycle {text!r}: give the cycle time in whole microseconds "
                          "(e.g. 500 or 1000)") from None


def _hot_connect_spec(text: str) -> tuple[str, int, int]:
    """``NAME=ALIAS[:SIZE]`` of ``run --hot-connect``."""
    name, sep, rest = text.partition("=")
    alias, _, size = rest.partition(":")
    if not sep or not name or not alias:
        raise ConfigError(f"--hot-connect {text!r}: use NAME=ALIAS[:SIZE], e.g. tool=0x100:3")
    return name, parse_int(alias), parse_int(size) if size else 1
