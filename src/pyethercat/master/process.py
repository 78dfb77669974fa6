"""Process data on a ``Master``: configure from SII, bring up to OP, run cycles, recover.

``ProcessDataMixin`` gives :class:`~pyethercat.master.master.Master` its
process-data methods (it only needs ``scheduler``, ``slaves``, ``_lock``,
``_sleep`` and ``set_state`` of the master)::

    with Master.open(iface="eth1") as m:
        m.scan()
        m.configure()                       # SM/FMMU values, images, slave.inputs/outputs
        with m.start(cycle=0.001) as run:   # INIT -> PREOP -> SAFEOP -> cycles -> OP
            m.slaves[2].outputs["Output 1"] = 1
            time.sleep(1)
            print(m.slaves[3].inputs["Input 1"], run.stats.summary())

or in one call: ``stats = m.run(cycle=0.001, seconds=5, callback=fn)``, or
``for cycle in m.cycles(0.001): ...``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any

from pyethercat.clock import Clock, PerfClock
from pyethercat.errors import ConfigError, EtherCATError, WorkingCounterError
from pyethercat.master import scan as scanning
from pyethercat.master import states
from pyethercat.master.clocks import DistributedClocks
from pyethercat.master.config import (
    GroupSpec,
    Layout,
    ProcessDataConfig,
    SlaveSpec,
    configure,
)
from pyethercat.master.cyclic import Cycle, CycleStats, CyclicRunner
from pyethercat.master.dc_loop import DcMode
from pyethercat.master.image import ProcessImage, build_images
from pyethercat.master.slave import Slave
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.sii.model import WORD_VENDOR_ID

if TYPE_CHECKING:
    import threading

    from pyethercat.master.scheduler import Scheduler

__all__ = ["ProcessDataMixin", "slave_spec"]


def slave_spec(slave: Slave) -> SlaveSpec:
    """What the configuration needs from a scanned slave."""
    if slave.sii is None:
        raise ConfigError(f"{slave.describe()}: no SII was read, cannot configure process data")
    esc = slave.esc
    return SlaveSpec(slave.position, slave.station_address, slave.sii, esc.features,
                     esc.fmmu_count or 8, esc.sm_count or 8, slave.name,
                     getattr(slave, "pdo_mapping", None))


class ProcessDataMixin:
    """Process-data methods of the master (see the module text)."""

    scheduler: Scheduler
    slaves: list[Slave]
    _lock: threading.RLock
    process_data: ProcessDataConfig | None = None
    images: dict[str, ProcessImage]
    runner: CyclicRunner | None = None
    dc: DistributedClocks

    def _sleep(self, seconds: float) -> None: ...  # provided by Master

    def _state_hooks(self) -> dict[str, Any]:
        """Extra keyword arguments for ``states.set_state`` (CoE start-up commands)."""
        return {}

    def _before_configure(self) -> None:
        """Runs first in :meth:`configure` (the CoE mixin reads PDO mappings there)."""

    # -- configuration -----------------------------------------------------------------

    def configure(self, groups: Sequence[GroupSpec] | None = None,
                  layout: Layout | str = Layout.PACKED) -> ProcessDataConfig:
        """Compute SM/FMMU values and group images from the slaves' SII.

        Attaches ``slave.inputs`` / ``slave.outputs`` (:class:`SlaveIO`) and
        ``slave.config`` to every slave. Nothing is written yet (see
        :meth:`start`). ``groups`` default to one group of every slave.
        """
        with self._lock:
            if not self.slaves:
                raise ConfigError("no slaves: scan first")
            if groups is None:
                groups = [GroupSpec("main", None, layout)]
            self._before_configure()
            cfg = configure([slave_spec(s) for s in self.slaves], groups)
            self.process_data = cfg
            self.images = build_images(cfg)
            for s in self.slaves:
                sc = cfg.slaves[s.position]
                img = self.images.get(sc.group)
                s.config = sc
                s.inputs = img.slave_inputs(s.position) if img is not None else None
                s.outputs = img.slave_outputs(s.position) if img is not None else None
            return cfg

    def _writes(self, items: list[tuple[Slave, int, bytes]], what: str) -> None:
        if not items:
            return
        dgs = [Datagram.device(Command.FPWR, s.station_address, addr, data)
               for s, addr, data in items]
        replies = self.scheduler.transact(dgs)
        for (s, addr, _), r in zip(items, replies, strict=True):
            if r.wkc != 1:
                raise WorkingCounterError(f"{s.describe()}: writing {what} at 0x{addr:04X}", 1,
                                          r.wkc)

    def write_mailbox_config(self, slaves: Sequence[Slave] | None = None) -> None:
        """Write the mailbox sync managers (needed before PRE-OP), all slaves batched."""
        cfg = self._need_config()
        chosen = list(self.slaves) if slaves is None else list(slaves)
        self._writes([(s, a, d) for s in chosen for a, d in cfg.slaves[s.position].mailbox_writes()],
                     "mailbox sync manager")

    def write_process_data_config(self, slaves: Sequence[Slave] | None = None) -> None:
        """Write process-data SMs and FMMUs (needed before SAFE-OP), all slaves batched."""
        cfg = self._need_config()
        chosen = list(self.slaves) if slaves is None else list(slaves)
        self._writes([(s, a, d) for s in chosen
                      for a, d in cfg.slaves[s.position].process_data_writes()],
                     "sync manager/FMMU")

    def _need_config(self) -> ProcessDataConfig:
        if self.process_data is None:
            self.configure()
        assert self.process_data is not None
        return self.process_data

    def _bring_up(self, slaves: Sequence[Slave], timeout: float) -> None:
        """INIT -> (mailbox SMs) PREOP -> (SMs, FMMUs) SAFEOP for ``slaves``.

        The mailbox sync managers are written by the state machine's prepare
        step before INIT -> PREOP (``states.setup_mailboxes``, also inside the
        CoE hook); the process-data SMs and FMMUs in the prepare step before
        PREOP -> SAFEOP, so PREOP and SAFEOP are one ``set_state`` walk.
        """
        st = self.scheduler
        hooks = self._state_hooks()
        states.set_state(st, slaves, AlState.INIT, timeout, sleep=self._sleep, **hooks)
        before = hooks.pop("prepare", states.setup_mailboxes)

        def prepare(scheduler: Scheduler, step: AlState, group: Sequence[Slave]) -> None:
            if before is not None:
                before(scheduler, step, group)
            if step == AlState.SAFEOP:
                self.write_process_data_config(group)
                self.dc.before_safeop(group)

        states.set_state(st, slaves, AlState.SAFEOP, timeout, sleep=self._sleep,
                         prepare=prepare, **hooks)

    # -- running --------------------------------------------------------------------------

    def start(self, cycle: float = 0.001, *, target: AlState | str = AlState.OP,
              callback: Callable[[Cycle], None] | None = None, clock: Clock | None = None,
              check_interval: float = 0.1, recover: bool = True, timeout: float = 5.0,
              groups: Sequence[str] | None = None,
              frame_timeout: float | None = None, dc: DcMode | str | None = None,
              dc_lead: float | None = None) -> CyclicRunner:
        """Configure (if needed), bring every slave to SAFE-OP, start cycles, then go to ``target``.

        Returns the running :class:`CyclicRunner` (a context manager; ``stop()``
        ends it). OP is requested only once outputs flow, as slaves demand.
        ``dc`` ("master" or "reference", see :class:`DcMode`) adds distributed
        clocks: the set-up if it has not run, the reference's time in every
        frame, the phase lock or the reference write, the sync monitor;
        ``dc_lead`` (seconds, default half a cycle) is how long before SYNC0
        the frames pass the reference clock.
        """
        want = AlState.parse(target) if isinstance(target, str) else AlState(int(target))
        with self._lock:
            if self.runner is not None and self.runner.running:
                raise ConfigError("cyclic exchange is already running")
            cfg = self._need_config()
            clock = clock or PerfClock()
            plan = None
            if dc is not None:
                if self.dc.report is None:
                    self.dc.setup()
                lead = None if dc_lead is None else int(round(dc_lead * 1e9))
                plan = self.dc.cycle(int(round(cycle * 1e9)), dc, clock, lead_ns=lead)
            self._bring_up(self.slaves, timeout)
            runner = CyclicRunner(self.scheduler, cfg, self.images, self.slaves, cycle=cycle,
                                  clock=clock, callback=callback, check_interval=check_interval,
                                  target=want, recover=self._recover if recover else None,
                                  groups=groups, frame_timeout=frame_timeout, dc=plan)
            self.runner = runner
            # Supervision starts once the slaves are where they were asked to be: the
            # check would otherwise see SAFE-OP during the walk up and "recover" them.
            runner.supervising = want != AlState.OP
            runner.start()
            try:
                if want == AlState.OP:
                    states.set_state(self.scheduler, self.slaves, AlState.OP, timeout,
                                     sleep=self._sleep, **self._state_hooks())
            except BaseException:
                runner.stop()
                raise
            runner.supervising = True
            return runner

    def run(self, cycle: float = 0.001, seconds: float | None = None, *,
            callback: Callable[[Cycle], None] | None = None, background: bool = False,
            **options: Any) -> CycleStats | CyclicRunner:
        """Bring up and run cycles: for ``seconds`` (then stop and return the statistics),
        or with ``background=True`` return the running :class:`CyclicRunner` at once."""
        runner = self.start(cycle, callback=callback, **options)
        if background:
            return runner
        try:
            runner._stop.wait(seconds)
        finally:
            runner.stop()
        return runner.stats

    def cycles(self, cycle: float = 0.001, **options: Any) -> Iterator[Cycle]:
        """Start cyclic exchange and yield each cycle; closing the iterator stops it."""
        runner = self.start(cycle, **options)
        try:
            yield from runner.cycles()
        finally:
            runner.stop()

    def stop(self) -> None:
        """Stop the cyclic exchange, if it runs."""
        r = self.runner
        if r is not None:
            r.stop()

    # -- recovery (called from the runner's recovery thread) -----------------------------------

    def _recover(self, positions: list[int]) -> None:
        """Bring slaves that dropped out or vanished back to the requested state."""
        runner = self.runner
        target = runner.target if runner is not None else AlState.OP
        count = scanning.count_slaves(self.scheduler)
        if count < len(self.slaves):
            raise WorkingCounterError("segment still incomplete", len(self.slaves), count)
        full: list[Slave] = []
        resume: list[Slave] = []
        for p in positions:
            s = self.slaves[p]
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
            self._bring_up(full, 5.0)
            resume += full
        if resume:
            states.acknowledge_errors(self.scheduler, resume)
            states.set_state(self.scheduler, resume, target, 5.0, sleep=self._sleep,
                             **self._state_hooks())

    def _check_identity(self, slave: Slave) -> None:
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
