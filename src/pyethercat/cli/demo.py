"""``pyethercat demo``: the main job on the built-in simulated segment (``make demo``).

Without options it needs no hardware and no root: it starts the simulated
segment of ``examples/demo.toml`` (a coupler, IO terminals including a 2-bit
one, a tree branch) in a child process, joined over a Unix socketpair, and
then does what a master does with a real segment: scan (slave table and
topology), configure process data from SII, bring every slave to OP, run
1 ms cycles for a few seconds with a live view while toggling outputs that
the segment wires back to inputs (and checks they come back bit-exactly),
print a summary and leave a pcap of the whole run. Ctrl-C (or SIGTERM)
ends the cycles early in the same orderly way as ``run`` (safe outputs,
SAFEOP, ``--final-state``), and the summary and the capture's name are
printed all the same.

``pyethercat demo --iface IF`` (or ``--udp``) does the same on a real
segment; the loop-back check then needs ``--topology`` naming the wiring.

``pyethercat demo --redundancy`` runs the cable-redundancy experiment
instead (``cli.ring_experiment``): a simulated 20-slave ring at 1 kHz for 60
s of virtual time with 100 random single faults, and prints what the
application saw (sent and received cycles, stale data), where the master
located each fault and how long slaves plugged back took to be in OP.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.tree import Tree

from pyethercat.cli._connect import connect
from pyethercat.cli._lifecycle import FINAL_STATES, StopSignals, cycle_until
from pyethercat.cli._session import serving
from pyethercat.cli.run_cmds import format_summary, live_view
from pyethercat.errors import ConfigError
from pyethercat.master.cyclic import Cycle
from pyethercat.master.master import Master
from pyethercat.master.slave_info import PORT_ORDER, SlaveInfo

__all__ = ["register", "find_demo_topology", "Loopback", "loopbacks_from_topology"]


def find_demo_topology() -> Path:
    """``examples/demo.toml`` of the source tree, else the copy in the package data."""
    here = Path(__file__).resolve()
    for base in (Path.cwd(), *here.parents):
        candidate = base / "examples" / "demo.toml"
        if candidate.is_file():
            return candidate
    packaged = resources.files("pyethercat").joinpath("data/demo.toml")
    if packaged.is_file():
        return Path(str(packaged))
    raise ConfigError("demo topology not found (examples/demo.toml or pyethercat/data/demo.toml)")


@dataclass(frozen=True)
class Loopback:
    """Output bits of one slave wired to input bits of another (ring positions)."""

    src: int
    src_bit: int
    dst: int
    dst_bit: int
    bits: int
    label: str


def _ring_order(topo: Any) -> list[str]:
    """Slave names in the order a frame meets them (ports 0 -> 3 -> 1 -> 2)."""
    children: dict[str, dict[int, str]] = {}
    for s in topo.slaves:
        if s.parent is not None:
            children.setdefault(s.parent, {})[s.port or 1] = s.name
    order: list[str] = []

    def visit(name: str) -> None:
        order.append(name)
        for port in PORT_ORDER[1:]:
            child = children.get(name, {}).get(port)
            if child is not None:
                visit(child)

    if topo.slaves:
        visit(topo.slaves[0].name)
    return order


def loopbacks_from_topology(path: Path, master: Master) -> list[Loopback]:
    """The topology's wires as ring positions, kept where the scanned identities agree."""
    from pyethercat.sim.topology import load_topology

    topo = load_topology(path)
    order = _ring_order(topo)
    pos = {name: i for i, name in enumerate(order)}
    by_name = {s.name: s for s in topo.slaves}
    out: list[Loopback] = []
    for w in topo.wires:
        a, b = pos.get(w.src), pos.get(w.dst)
        if a is None or b is None or max(a, b) >= len(master.slaves):
            continue
        ok = True
        for name, p in ((w.src, a), (w.dst, b)):
            info = by_name[name].info
            ident = master.slaves[p].identity
            ok = ok and (ident.vendor_id, ident.product_code) == (info.vendor_id, info.product_code)
        if ok:
            out.append(Loopback(a, w.src_bit, b, w.dst_bit, w.bits,
                                f"{w.src}:{w.src_bit} -> {w.dst}:{w.dst_bit} ({w.bits} bit)"))
    return out


def _bit(buf: bytearray | memoryview, bit: int) -> int:
    return (buf[bit >> 3] >> (bit & 7)) & 1


def _set_bit(buf: bytearray | memoryview, bit: int, value: int) -> None:
    if value:
        buf[bit >> 3] |= 1 << (bit & 7)
    else:
        buf[bit >> 3] &= ~(1 << (bit & 7)) & 0xFF


#: Whole exchanges a pattern needs at least to come back: the first takes the outputs
#: out (a wire copies them to the input buffer as the frame leaves the output slave),
#: the next reads the inputs.
_ROUND_TRIP = 2


class _Toggler:
    """Cycle callback: a new output pattern every ``hold`` cycles, checked on the inputs."""

    def __init__(self, master: Master, loops: list[Loopback], hold: int = 50) -> None:
        self.master = master
        self.loops = loops
        self.hold = hold
        self.step = 0
        self.checked = 0
        self.mismatches = 0
        #: Checks left out because the pattern could not have come back whole.
        self.skipped = 0
        self.last = ""
        # Whether the wired slaves were supervised "ok" at the last check (a slave that
        # fell out of OP, e.g. into its watchdog, ignores its outputs meanwhile).
        self._settled = True
        #: Whole exchanges (every working counter right, inputs copied) since the pattern.
        self._whole = 0
        cfg = master.process_data
        assert cfg is not None
        self.out_slaves = sorted(p for p, sc in cfg.slaves.items() if sc.output_bits)
        self._places: list[tuple[Loopback, bytearray | memoryview, int, int]] = []
        for lp in loops:
            src, dst = cfg.slaves[lp.src], cfg.slaves[lp.dst]
            if src.group != dst.group or src.output_bit_offset < 0 or dst.input_bit_offset < 0:
                continue
            img = master.images[src.group]
            self._places.append((lp, img.buffer, src.output_bit_offset + lp.src_bit,
                                 dst.input_bit_offset + lp.dst_bit))

    def pattern(self, step: int, width: int) -> int:
        # A walking one, then a counter: every bit goes both ways.
        if step % 2:
            return (step * 0x9E37) & ((1 << width) - 1)
        return 1 << ((step // 2) % width)

    def __call__(self, cycle: Cycle) -> None:
        if cycle.wkc_ok and not cycle.lost:
            self._whole += 1
        if cycle.index % self.hold:
            return
        runner = self.master.runner
        healthy = runner is None or all(
            runner.health[p].status == "ok" for lp in self.loops for p in (lp.src, lp.dst)
            if p in runner.health)
        settled, self._settled = self._settled and healthy, healthy
        if self.step and (not settled or self._whole < _ROUND_TRIP):
            # The pattern had no `hold` healthy cycles, or too few whole exchanges (inputs
            # come only from those), to come back: check it next time.
            self.skipped += 1
            return
        # Check the previous pattern (it had `hold` cycles to come back), then set a new one.
        if self.step:
            for lp, buf, out_bit, in_bit in self._places:
                want = [_bit(buf, out_bit + i) for i in range(lp.bits)]
                got = [_bit(buf, in_bit + i) for i in range(lp.bits)]
                self.checked += 1
                if want != got:
                    self.mismatches += 1
                    self.last = f"mismatch on {lp.label}: wrote {want}, read {got}"
        self.step += 1
        self._whole = 0
        for lp, buf, out_bit, _ in self._places:
            value = self.pattern(self.step, lp.bits)
            for i in range(lp.bits):
                _set_bit(buf, out_bit + i, (value >> i) & 1)
        if not self._places:
            # No known wiring: still toggle every output so a real segment shows life.
            for p in self.out_slaves:
                outs = getattr(self.master.slaves[p], "outputs")  # noqa: B009 - set by configure()
                for n, name in enumerate(outs):
                    var = outs.variable(name)
                    if var.bit_length == 1:
                        var.set((self.step >> (n % 8)) & 1)

    def text(self) -> list[str]:
        if not self._places:
            return ["outputs toggled (no wiring known: loop-back not checked)"]
        line = (f"loop-back checks: {self.checked}, mismatches: {self.mismatches} "
                f"({len(self._places)} wires)")
        if self.skipped:
            line += f"; {self.skipped} left out (the segment was recovering)"
        return [line] + ([self.last] if self.last else [])


def slave_table(master: Master) -> Table:
    """The slave list as a rich table."""
    t = Table(title=f"{len(master.slaves)} slaves", show_edge=False)
    for col in ("pos", "address", "state"):
        t.add_column(col, no_wrap=True)
    # Whole SII names (up to 64 characters); only a narrow terminal cuts them.
    t.add_column("name", no_wrap=True, overflow="ellipsis")
    for col in ("vendor", "product", "out bits", "in bits"):
        t.add_column(col, no_wrap=True)
    cfg = master.process_data
    for s in master.slaves:
        sc = cfg.slaves.get(s.position) if cfg is not None else None
        t.add_row(str(s.position), s.address_text, s.al_state_name, s.name or "?",
                  f"0x{s.identity.vendor_id:08X}", f"0x{s.identity.product_code:08X}",
                  str(sc.output_bits if sc else "-"), str(sc.input_bits if sc else "-"))
    return t


def topology_tree(master: Master) -> Tree:
    """Which slave hangs on which port of which parent."""
    root = Tree("master")

    def add(node: Tree, s: SlaveInfo, via: str) -> None:
        branch = node.add(f"{via}{s.position}: {s.name or '?'} ({s.topology_kind})")
        for port in PORT_ORDER[1:]:
            child = s.children.get(port)
            if child is not None:
                add(branch, child, f"port {port} -> ")

    firsts = [s for s in master.slaves if s.parent is None]
    for s in firsts[:1] or master.slaves[:1]:
        add(root, s, "")
    return root


def register(cli: click.Group) -> None:
    """Add ``demo`` to the command line."""

    @cli.command("demo")
    @click.option("--seconds", default=None, type=float,
                  help="How long to run cycles [5; 60 with --redundancy].")
    @click.option("--cycle", "cycle_us", default=1000, show_default=True, type=int, metavar="US",
                  help="Cycle time in microseconds.")
    @click.option("--topology", default=None, metavar="TOML",
                  help="Topology to simulate (default: examples/demo.toml); with --iface, "
                       "the wiring to check.")
    @click.option("--pcap", default=None, metavar="FILE",
                  help="Capture file (default: pyethercat-demo.pcapng in a temp directory).")
    @click.option("--redundancy", is_flag=True,
                  help="The cable-redundancy experiment: a simulated ring, random single faults.")
    @click.option("--faults", default=100, show_default=True, type=click.IntRange(0, 10000),
                  help="With --redundancy: how many faults.")
    @click.option("--slaves", default=20, show_default=True, type=click.IntRange(3, 500),
                  help="With --redundancy: slaves in the ring.")
    @click.option("--seed", default=1, show_default=True, type=int,
                  help="With --redundancy: seed of the fault draw.")
    @click.option("--motion", is_flag=True,
                  help="Simulated servo drives on DC follow S-curve moves (CSP); prints the "
                       "following error and writes a plot.")
    @click.option("--drives", default=4, show_default=True, type=int, metavar="N",
                  help="--motion: how many drives.")
    @click.option("--plot", default=None, metavar="FILE.png",
                  help="--motion: where the plot goes (default: a temp directory).")
    @click.option("--final-state", "final_state", default="PREOP", show_default=True,
                  type=click.Choice(FINAL_STATES, case_sensitive=False),
                  help="State the slaves are left in at the end.")
    @click.pass_obj
    def demo_cmd(obj: dict[str, Any], seconds: float | None, cycle_us: int,
                 topology: str | None, pcap: str | None, redundancy: bool, faults: int,
                 slaves: int, seed: int, motion: bool, drives: int, plot: str | None,
                 final_state: str) -> None:
        """Run the main job: scan, configure, OP, 1 ms cycles with loop-back checks, pcap.

        With --redundancy: the cable-redundancy experiment on a simulated ring.
        With --motion: simulated servo drives on DC SYNC0 follow S-curve moves."""
        if redundancy and motion:
            raise ConfigError("demo: --redundancy or --motion, not both")
        if redundancy:
            run_redundancy_demo(seconds if seconds is not None else 60.0, cycle_us, faults,
                                slaves, seed)
            return
        if motion:
            from pyethercat.cli.demo_motion import run_motion

            if topology is not None:
                raise ConfigError("demo --motion makes its own segment of drives: no --topology")
            run_motion(obj, drives=drives, cycle_us=cycle_us, plot=plot, pcap=pcap,
                       console=Console() if sys.stdout.isatty() else Console(width=140))
            return
        seconds = 5.0 if seconds is None else seconds
        # Off a terminal (make demo | tee, CI logs) rich would squeeze tables
        # into 80 columns and cut names; give it room instead.
        if seconds <= 0:
            raise ConfigError(f"demo: --seconds must be positive, got {seconds:g}")
        if cycle_us <= 0:
            raise ConfigError(f"demo: --cycle must be a positive number of microseconds, "
                              f"got {cycle_us}")
        console = Console() if sys.stdout.isatty() else Console(width=140)
        obj = dict(obj or {})
        if obj.get("sim") is not None and topology is not None:
            raise ConfigError("demo: give the simulated segment once: --sim TOPOLOGY (before "
                              "the command) or --topology, not both")
        real = obj.get("iface") is not None or obj.get("udp") is not None
        topo_path = Path(topology) if topology else (None if real else find_demo_topology())
        if not real:
            if obj.get("sim") is None:
                obj["sim"] = str(topo_path)
            else:
                topo_path = Path(obj["sim"])
        if pcap is None:
            pcap = os.path.join(tempfile.gettempdir(), f"pyethercat-demo-{os.getpid()}.pcapng")
        where = obj.get("iface") or obj.get("udp") or f"simulated segment {topo_path} (child process)"
        console.print(f"[bold]pyethercat demo[/bold] on {where}")
        t0 = time.monotonic()
        why = ""
        with StopSignals() as signals, connect(obj, child=not real, pcap=pcap) as conn, \
                serving(obj, conn.master):
            m = conn.master
            m.scan()
            t_scan = time.monotonic() - t0
            m.configure()
            console.print(f"scan: {len(m.slaves)} slaves in {t_scan * 1000:.0f} ms")
            console.print(slave_table(m))
            console.print(topology_tree(m))
            loops = loopbacks_from_topology(topo_path, m) if topo_path is not None else []
            toggler = _Toggler(m, loops, hold=max(1, int(0.05 / (cycle_us / 1e6))))
            t1 = time.monotonic()
            runner = m.start(cycle_us / 1e6, callback=toggler, final_state=final_state.upper())
            signals.cycling_with(runner)
            console.print(f"all {len(m.slaves)} slaves in OP after "
                          f"{(time.monotonic() - t1) * 1000:.0f} ms; running {seconds:g} s "
                          f"of {cycle_us} us cycles")
            try:
                with Live(live_view(m, runner, toggler.text), console=console,
                          refresh_per_second=4) as live:
                    why = cycle_until(runner, signals, seconds, 0.0,
                                      lambda: live.update(live_view(m, runner, toggler.text)))
            finally:
                runner.stop()
            console.print()
            console.print(format_summary(runner))
            for line in toggler.text():
                console.print(line)
            if runner.stop_report:
                console.print(runner.stop_report)
            if why == "signal":
                console.print(f"ended early by {signals.received}")
        console.print(f"capture written to {pcap} (pyethercat decode {pcap})")
        if toggler.mismatches:
            raise ConfigError(f"loop-back check failed: {toggler.mismatches} mismatches "
                              f"in {toggler.checked} checks")
        if toggler._places and not toggler.checked and why != "signal":
            raise ConfigError("loop-back not checked: "
                              + (f"the segment was recovering at all {toggler.skipped} checks"
                                 if toggler.skipped else "the run was too short"))


def run_redundancy_demo(seconds: float, cycle_us: int, faults: int, slaves: int,
                        seed: int) -> None:
    """``demo --redundancy``: the experiment with a progress bar, then its report."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from pyethercat.cli.ring_experiment import run_experiment

    if seconds <= 0 or cycle_us <= 0:
        raise ConfigError("demo --redundancy: --seconds and --cycle must be positive")
    console = Console() if sys.stdout.isatty() else Console(width=140)
    console.print(f"[bold]pyethercat demo --redundancy[/bold]: a ring of {slaves} simulated "
                  f"slaves, {cycle_us} us cycles for {seconds:g} s (virtual time), "
                  f"{faults} random single faults")
    t0 = time.monotonic()
    with Progress(TextColumn("{task.description}"), BarColumn(), TimeRemainingColumn(),
                  console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("cycling", total=1.0)
        try:
            result = run_experiment(slaves=slaves, cycle=cycle_us / 1e6, seconds=seconds,
                                    faults=faults, seed=seed,
                                    progress=lambda done, total: bar.update(
                                        task, completed=done / total))
        except ValueError as exc:
            raise ConfigError(f"demo --redundancy: {exc}") from None
    for line in result.lines():
        console.print(line, highlight=False)
    console.print(f"({time.monotonic() - t0:.1f} s of wall-clock time)")
