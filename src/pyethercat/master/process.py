"""Process data of a master: configure from SII or CoE, bring up to OP, run cycles, recover.

:class:`ProcessData` is the master's process-data service; the
:class:`~pyethercat.master.master.Master` passes its calls through::

    with Master.open(iface="eth1") as m:
        m.scan()
        m.configure()                       # SM/FMMU values, images, slave.inputs/outputs
        with m.start(cycle=0.001) as run:   # INIT -> PREOP -> SAFEOP -> cycles -> OP
            m.slaves[2].outputs["Output 1"] = 1
            time.sleep(1)
            print(m.slaves[3].inputs["Input 1"], run.stats.summary())

or in one call: ``stats = m.run(cycle=0.001, seconds=5, callback=fn)``, or
``for cycle in m.cycles(0.001): ...``.

The process-data sync managers and FMMUs are written before PREOP -> SAFEOP
by the service itself, as a :class:`~pyethercat.master.transitions.TransitionHook`
that the bring-up (and ``master.set_state(..., configure=True)``) adds to the
state walk, followed by the hooks given as ``safeop_hooks`` (distributed clocks).

Every way of ending the exchange (``stop()``, leaving the ``with`` block,
the end of ``run``, closing the master) is an orderly stop: safe outputs
(``m.safe_outputs(pos)``, zero by default) for a few cycles, SAFEOP while
the cycles still run, then ``final_state`` (PREOP by default).
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypedDict, Unpack

from pyethercat.clock import Clock, PerfClock
from pyethercat.errors import ConfigError, EtherCATError, WorkingCounterError
from pyethercat.master import scan as scanning
from pyethercat.master import states
from pyethercat.master.clocks import DistributedClocks
from pyethercat.master.config import (
    CrossLink,
    GroupConfig,
    GroupSpec,
    Layout,
    ProcessDataConfig,
    SlaveDescription,
    configure,
)
from pyethercat.master.cross import apply_cross_traffic
from pyethercat.master.cyclic import Cycle, CycleStats, CyclicRunner, check_final_state
from pyethercat.master.dc_loop import DcMode
from pyethercat.master.image import ProcessImage, SlaveIO, build_images
from pyethercat.master.scheduler import Scheduler
from pyethercat.master.slave import Slave
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.master.transitions import Step, TransitionHook, Transitions
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.sii.model import WORD_VENDOR_ID

__all__ = ["ProcessData", "StartOptions", "slave_description"]


class StartOptions(TypedDict, total=False):
    """The keyword options of :meth:`ProcessData.start` (and of ``Master.start/run/cycles``)."""

    target: AlState | str
    callback: Callable[[Cycle], None] | None
    clock: Clock | None
    check_interval: float
    recover: bool
    timeout: float
    groups: Sequence[str] | None
    frame_timeout: float | None
    dc: DcMode | str | None
    dc_lead: float | None
    dc_monitor: float
    dc_limit: float
    link_timeout: float | None
    final_state: AlState | str
    safe_cycles: int
    isolated: bool
    realtime: int | None
    cpu: int | None
    lock_memory: bool


#: SCHED_FIFO priority the isolated engine asks for by default (below the kernel's
#: interrupt threads, 50, so that the network card is served first).
_DEFAULT_PRIORITY = 40


def slave_description(slave: SlaveInfo) -> SlaveDescription:
    """What the configuration needs from a scanned slave."""
    if slave.sii is None:
        raise ConfigError(f"{slave.describe()}: no SII was read, cannot configure process data")
    esc = slave.esc
    return SlaveDescription(slave.position, slave.station_address, slave.sii, esc.features,
                            esc.fmmu_count or 8, esc.sm_count or 8, slave.name,
                            slave.pdo_mapping)


class ProcessData:
    """Process-data configuration, bring-up and the cyclic runner (see the module text).

    ``slaves`` returns the master's slaves; ``transitions`` walks them through
    the states; ``before_configure`` runs first in every :meth:`configure`
    (reading PDO mappings over CoE); ``dc`` is the distributed-clock service
    (its hook runs after the SM/FMMU writes before SAFE-OP).
    """

    def __init__(self, scheduler: Scheduler, transitions: Transitions,
                 slaves: Callable[[], list[Slave]], dc: DistributedClocks, *,
                 lock: threading.RLock,
                 before_configure: Callable[[Sequence[SlaveInfo]], None] = lambda _s: None,
                 ) -> None:
        self.scheduler = scheduler
        self.transitions = transitions
        self.dc = dc
        self._slaves = slaves
        self._lock = lock
        self._before_configure = before_configure
        #: The configuration of the last :meth:`configure` (None: none, or invalidated).
        self.config: ProcessDataConfig | None = None
        #: The group images of that configuration, by group name.
        self.images: dict[str, ProcessImage] = {}
        #: The cyclic runner of the last :meth:`start` (None before).
        self.runner: CyclicRunner | None = None
        #: Make the riders of every runner :meth:`start` makes (the master's ring watch).
        self.rider_factories: list[Callable[[CyclicRunner], Any]] = []
        #: Cross traffic of the next :meth:`configure` (``master.cross``).
        self.cross: list[CrossLink] = []
        #: What brings slaves back for the runner (the master's hot swap), else :meth:`recover`.
        self.recovery: Callable[[list[int]], None] | None = None
        self._io: dict[int, tuple[SlaveIO | None, SlaveIO | None]] = {}

    # -- configuration -----------------------------------------------------------------

    def configure(self, groups: Sequence[GroupSpec] | None = None,
                  layout: Layout | str = Layout.PACKED,
                  cross: Sequence[CrossLink] | None = None) -> ProcessDataConfig:
        """Compute SM/FMMU values and group images from the slaves' SII (or CoE mapping).

        Gives every slave its ``config`` and its ``inputs``/``outputs`` views.
        Nothing is written yet (see :meth:`start`). ``groups`` default to one
        group of every slave. ``cross``: slaves whose inputs drive later
        slaves' outputs within the frame (``master.cross``; default: those
        given before, e.g. by an ENI).
        """
        with self._lock:
            slaves = self._slaves()
            if not slaves:
                raise ConfigError("no slaves: scan first")
            if groups is None:
                groups = [GroupSpec("main", None, layout)]
            self._before_configure(slaves)
            cfg = configure([slave_description(s) for s in slaves], groups)
            if cross is not None:
                self.cross = list(cross)
            if self.cross:
                apply_cross_traffic(cfg, self.cross)
            self.config = cfg
            self.images = build_images(cfg)
            self._io.clear()
            for s in slaves:
                sc = cfg.slaves[s.position]
                s.config = sc
                img = self.images.get(sc.group)
                self._io[s.position] = ((img.slave_inputs(s.position), img.slave_outputs(s.position))
                                        if img is not None else (None, None))
            return cfg

    def add_group(self, name: str, slaves: Sequence[Slave]) -> GroupConfig:
        """Configure ``slaves`` (found after :meth:`configure`: a hot connect group that
        appeared) as a process-data group of their own, laid after the other groups in
        the logical address space; the others' layout and images stay as they are."""
        with self._lock:
            cfg = self.need_config()
            if any(g.name == name for g in cfg.groups):
                raise ConfigError(f"a process-data group named {name!r} exists already")
            self._before_configure(slaves)
            base = max(g.logical_end for g in cfg.groups) if cfg.groups else None
            layout = cfg.groups[0].layout if cfg.groups else Layout.PACKED
            part = configure([slave_description(s) for s in slaves],
                             [GroupSpec(name, None, layout, base)])
            cfg.groups.extend(part.groups)
            cfg.slaves.update(part.slaves)
            # (in place: a running loop holds this dict)
            self.images.update(build_images(part))
            img = self.images[name]
            for s in slaves:
                s.config = part.slaves[s.position]
                self._io[s.position] = (img.slave_inputs(s.position), img.slave_outputs(s.position))
            return part.group(name)

    def use_images(self, images: dict[str, ProcessImage]) -> None:
        """Give the slaves' ``inputs``/``outputs`` views into these images (the isolated
        engine's shared ones while it runs, private ones again after)."""
        self.images = images
        cfg = self.config
        if cfg is None:
            return
        for pos in list(self._io):
            sc = cfg.slaves.get(pos)
            img = images.get(sc.group) if sc is not None else None
            if img is not None:
                self._io[pos] = (img.slave_inputs(pos), img.slave_outputs(pos))

    def _check_isolated(self, clock: Clock | None) -> None:
        """Refuse ``isolated=True`` where the engine cannot run (see :meth:`start`)."""
        from pyethercat.master.engine.launch import link_can_move

        why = link_can_move(self.scheduler.link)
        if why is not None:
            raise ConfigError(f"isolated=True: {why}")
        if clock is not None:
            raise ConfigError("isolated=True: the engine keeps its own time (give no clock)")

    def invalidate(self) -> None:
        """Forget the configuration (a PDO mapping changed): the next start configures anew."""
        self.config = None

    def io_of(self, slave: SlaveInfo, outputs: bool) -> SlaveIO:
        """A slave's view into its group image; :class:`ConfigError` before a configuration."""
        views = self._io.get(slave.position)
        if views is None:
            raise ConfigError(f"slave {slave.position} ({slave.address_text}): no process "
                              "image yet, call master.configure() first")
        view = views[1] if outputs else views[0]
        if view is None:
            raise ConfigError(f"slave {slave.position} ({slave.address_text}) is in no "
                              "process-data group")
        return view

    def need_config(self) -> ProcessDataConfig:
        """The configuration, made now if there is none."""
        if self.config is None:
            self.configure()
        assert self.config is not None
        return self.config

    def _writes(self, items: list[tuple[SlaveInfo, int, bytes]], what: str) -> None:
        if not items:
            return
        dgs = [Datagram.device(Command.FPWR, s.station_address, addr, data)
               for s, addr, data in items]
        replies = self.scheduler.transact(dgs)
        for (s, addr, _), r in zip(items, replies, strict=True):
            if r.wkc != 1:
                raise WorkingCounterError(f"{s.describe()}: writing {what} at 0x{addr:04X}", 1,
                                          r.wkc)

    def write_mailbox_config(self, slaves: Sequence[SlaveInfo] | None = None) -> None:
        """Write the mailbox sync managers (needed before PRE-OP), all slaves batched."""
        cfg = self.need_config()
        chosen = list(self._slaves()) if slaves is None else list(slaves)
        self._writes([(s, a, d) for s in chosen for a, d in cfg.slaves[s.position].mailbox_writes()],
                     "mailbox sync manager")

    def write_process_data_config(self, slaves: Sequence[SlaveInfo] | None = None) -> None:
        """Write process-data SMs and FMMUs (needed before SAFE-OP), all slaves batched."""
        cfg = self.need_config()
        chosen = list(self._slaves()) if slaves is None else list(slaves)
        self._writes([(s, a, d) for s in chosen
                      for a, d in cfg.slaves[s.position].process_data_writes()],
                     "sync manager/FMMU")

    # -- the transition hook (added to the walks that bring process data up) -------------

    def before_step(self, step: Step) -> None:
        """Before PREOP -> SAFEOP: the process-data SMs and FMMUs (configured now if needed).

        Configured here, not earlier: CoE mappings are read in PRE-OP.
        """
        if step.target == AlState.SAFEOP:
            self.need_config()
            self.write_process_data_config(step.slaves)

    def after_step(self, step: Step) -> None:
        """Nothing to do once a state is reached."""

    @property
    def bring_up_hooks(self) -> list[TransitionHook]:
        """What a walk to SAFE-OP adds to the master's standing hooks: SMs/FMMUs, then DC."""
        return [self, self.dc]

    def bring_up(self, slaves: Sequence[Slave], timeout: float) -> None:
        """INIT -> (mailbox SMs) PREOP -> (SMs, FMMUs, DC) SAFEOP for ``slaves``."""
        self.transitions.set_state(slaves, AlState.INIT, timeout)
        self.transitions.set_state(slaves, AlState.SAFEOP, timeout, extra=self.bring_up_hooks)

    # -- running --------------------------------------------------------------------------

    def start(self, cycle: float = 0.001, *, target: AlState | str = AlState.OP,
              callback: Callable[[Cycle], None] | None = None, clock: Clock | None = None,
              check_interval: float = 0.1, recover: bool = True, timeout: float = 5.0,
              groups: Sequence[str] | None = None,
              frame_timeout: float | None = None, dc: DcMode | str | None = None,
              dc_lead: float | None = None, dc_monitor: float = 0.1,
              dc_limit: float = 1e-6, link_timeout: float | None = None,
              final_state: AlState | str = AlState.PREOP,
              safe_cycles: int = 3, isolated: bool = False,
              realtime: int | None = None, cpu: int | None = None,
              lock_memory: bool = True) -> CyclicRunner:
        """Configure (if needed), bring every slave to SAFE-OP, start cycles, then go to ``target``.

        Returns the running :class:`CyclicRunner` (a context manager; ``stop()``
        ends it in order: safe outputs for ``safe_cycles`` cycles, SAFEOP,
        then ``final_state``). OP is requested only once outputs flow, as
        slaves demand. ``link_timeout``: see :class:`CyclicRunner`.
        ``dc`` ("master" or "reference", see :class:`DcMode`) adds distributed
        clocks: the set-up if it has not run, the reference's time in every
        frame, the phase lock or the reference write, the sync monitor;
        ``dc_lead`` (seconds, default half a cycle) is how long before SYNC0
        the frames pass the reference clock; the sync monitor reads 0x092C
        every ``dc_monitor`` seconds (0: never) and reports "sync unstable"
        above ``dc_limit`` seconds.

        ``isolated=True`` runs the loop in a process of its own
        (:class:`~pyethercat.master.engine.runner.IsolatedRunner`, docs/realtime.md):
        nothing of this process (threads burning CPU, C calls holding the GIL)
        moves its deadlines. It needs a link over one socket (not a ring's two
        ports, not an in-process simulator) and no ``clock``; the ``callback``
        then runs in this process after the engine's cycles, not inside them,
        and the loop's riders (the ring watch) stay out. The engine asks for
        SCHED_FIFO ``realtime`` (default 40; 0: none), the CPU ``cpu`` and
        locked memory, and logs what it could not get. By default the loop is
        a thread of this process (``realtime`` then applies to that thread).
        """
        want = AlState.parse(target) if isinstance(target, str) else AlState(int(target))
        check_final_state(final_state)  # before anything is touched
        if isolated:
            self._check_isolated(clock)
        with self._lock:
            if self.runner is not None and self.runner.running:
                raise ConfigError("cyclic exchange is already running")
            cfg = self.need_config()
            slaves = self._slaves()
            clock = clock or PerfClock()
            plan = None
            if dc is not None:
                if self.dc.report is None:
                    self.dc.setup()
                lead = None if dc_lead is None else int(round(dc_lead * 1e9))
                plan = self.dc.cycle(int(round(cycle * 1e9)), dc, clock, lead_ns=lead)
                plan.monitor.period_ns = int(round(dc_monitor * 1e9))
                plan.monitor.limit_ns = int(round(dc_limit * 1e9))
            self.bring_up(slaves, timeout)
            if isolated:
                from pyethercat.master.engine.runner import IsolatedRunner

                runner: CyclicRunner = IsolatedRunner(
                    self.scheduler, cfg, self.images, slaves, cycle=cycle, callback=callback,
                    check_interval=check_interval, target=want,
                    recover=(self.recovery or self.recover) if recover else None, groups=groups,
                    frame_timeout=frame_timeout, dc=plan, link_timeout=link_timeout,
                    leave=self._leave, final_state=final_state, safe_cycles=safe_cycles,
                    priority=_DEFAULT_PRIORITY if realtime is None else realtime, cpu=cpu,
                    lock_memory=lock_memory, use_images=self.use_images)
            else:
                runner = CyclicRunner(self.scheduler, cfg, self.images, slaves, cycle=cycle,
                                      clock=clock, callback=callback,
                                      check_interval=check_interval, target=want,
                                      recover=(self.recovery or self.recover) if recover else None,
                                      groups=groups, frame_timeout=frame_timeout, dc=plan,
                                      link_timeout=link_timeout, leave=self._leave,
                                      final_state=final_state, safe_cycles=safe_cycles)
                runner.riders.extend(make(runner) for make in self.rider_factories)
                runner.thread_priority = 0 if realtime is None else realtime
            self.runner = runner
            # Supervision starts once the slaves are where they were asked to be: the
            # check would otherwise see SAFE-OP during the walk up and "recover" them.
            runner.supervising = want != AlState.OP
            runner.start()
            try:
                if want == AlState.OP:
                    self.transitions.set_state(slaves, AlState.OP, timeout)
            except BaseException:
                runner.stop(timeout=min(timeout, 2.0))
                raise
            runner.supervising = True
            return runner

    def run(self, cycle: float = 0.001, seconds: float | None = None, *,
            background: bool = False, **options: Unpack[StartOptions]) -> CycleStats | CyclicRunner:
        """Bring up and run cycles: for ``seconds`` (then stop and return the statistics),
        or with ``background=True`` return the running :class:`CyclicRunner` at once."""
        runner = self.start(cycle, **options)
        if background:
            return runner
        try:
            runner._stop.wait(seconds)
        finally:
            runner.stop()
        return runner.stats

    def cycles(self, cycle: float = 0.001, **options: Unpack[StartOptions]) -> Iterator[Cycle]:
        """Start cyclic exchange and yield each cycle; closing the iterator stops it."""
        runner = self.start(cycle, **options)
        try:
            yield from runner.cycles()
        finally:
            runner.stop()

    def stop(self, final_state: AlState | str | None = None) -> None:
        """Stop the cyclic exchange in order, if it runs (see :meth:`CyclicRunner.stop`)."""
        r = self.runner
        if r is not None:
            r.stop(final_state)

    def safe_outputs(self, slave: Slave | int) -> SlaveIO:
        """A slave's safe outputs: what an orderly stop sends (zero unless set here)."""
        pos = slave.position if isinstance(slave, Slave) else int(slave)
        cfg = self.need_config()
        sc = cfg.slaves.get(pos)
        if sc is None or sc.group not in self.images:
            raise ConfigError(f"slave {pos} has no process data")
        return self.images[sc.group].slave_safe_outputs(pos)

    def _leave(self, state: AlState, positions: list[int], timeout: float) -> None:
        """Take slaves down to ``state`` (an orderly stop's steps; hooks as on the way up)."""
        slaves = self._slaves()
        chosen = [slaves[p] for p in positions if 0 <= p < len(slaves)]
        self.transitions.set_state(chosen, state, timeout)

    # -- recovery (called from the runner's recovery thread) -----------------------------------

    def recover(self, positions: list[int]) -> None:
        """Bring slaves that dropped out or vanished back to the requested state."""
        runner = self.runner
        target = runner.target if runner is not None else AlState.OP
        slaves = self._slaves()
        count = scanning.count_slaves(self.scheduler)
        if count < len(slaves):
            raise WorkingCounterError("segment still incomplete", len(slaves), count)
        full: list[Slave] = []
        resume: list[Slave] = []
        for p in positions:
            s = slaves[p]
            reply = self.scheduler.transact_one(
                Datagram.device(Command.FPRD, s.station_address, reg.AL_STATUS, 2))
            if reply.wkc == 1:
                state = struct.unpack("<H", reply.data)[0] & reg.AL_STATE_MASK
                (resume if state >= AlState.SAFEOP else full).append(s)
                continue
            # No answer at its address: power-cycled (address reset to 0) or replaced.
            got = self.scheduler.transact_one(
                Datagram.positional(Command.APRD, p, reg.STATION_ADDRESS, 2))
            if got.wkc != 1:
                raise WorkingCounterError(f"{s.describe()}: no answer at its position", 1, got.wkc)
            w = self.scheduler.transact_one(Datagram.positional(
                Command.APWR, p, reg.STATION_ADDRESS, struct.pack("<H", s.station_address)))
            if w.wkc != 1:
                raise WorkingCounterError(f"{s.describe()}: station address not taken", 1, w.wkc)
            self._check_identity(s)
            full.append(s)
        if full:
            self.bring_up(full, 5.0)
            resume += full
        if resume:
            states.acknowledge_errors(self.scheduler, resume)
            self.transitions.set_state(resume, target, 5.0)

    def _check_identity(self, slave: SlaveInfo) -> None:
        """After a power cycle: is it still the same device (SII words 8-0xB)?"""
        try:
            image = scanning.read_sii_batch(self.scheduler, [scanning.SiiAccess.of(slave)],
                                            length=0x18)[0]
        except EtherCATError:
            return
        if isinstance(image, Exception) or len(image) < 0x18:
            return
        vendor, product = struct.unpack_from("<II", image, 2 * WORD_VENDOR_ID)
        ident = slave.identity
        if (vendor, product) != (ident.vendor_id, ident.product_code):
            raise ConfigError(f"{slave.describe()} came back as vendor 0x{vendor:08X} product "
                              f"0x{product:08X}, expected {ident}: not reconfigured")
