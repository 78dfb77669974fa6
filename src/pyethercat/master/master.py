"""``pyethercat.Master``: the object a user holds.

A master owns one link and one :class:`~pyethercat.master.scheduler.Scheduler`
on it. ``scan()`` fills ``master.slaves``; register access, states, SII
access and diagnostics work on those slaves (or on ring positions before a
scan). Every public call is thread-safe: single datagram batches go straight
to the (thread-safe) scheduler, multi-step sequences (scan, SII write, state
changes) hold the master's lock.

    with Master.open(iface="eth1") as master:
        master.scan()
        for s in master.slaves:
            print(s.position, s.name, s.al_state_name)
        master.set_state("PREOP")
"""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Self, TypeVar, Unpack

from pyethercat.clock import Clock
from pyethercat.errors import (
    ConfigError,
    EtherCATError,
    StateTimeoutError,
    WorkingCounterError,
)
from pyethercat.link.base import Link
from pyethercat.master import diag, states
from pyethercat.master import scan as scanning
from pyethercat.master.clocks import DistributedClocks
from pyethercat.master.coe import CoeClient, DTypeLike, EmergencyEvent, PdoSpec, StartupCommand
from pyethercat.master.coe_setup import CoeSetup
from pyethercat.master.config import CrossLink, GroupSpec, Layout, MappedPdo, ProcessDataConfig
from pyethercat.master.cyclic import Cycle, CycleStats, CyclicRunner
from pyethercat.master.eeprom import SiiService, SiiTarget
from pyethercat.master.hotswap import GroupPresence, HotConnectGroup, HotSwap
from pyethercat.master.image import ProcessImage, SlaveIO
from pyethercat.master.mailbox import DEFAULT_MAILBOX_TIMEOUT, DropOldestQueue, Mailbox
from pyethercat.master.mailboxes import MailboxService
from pyethercat.master.process import ProcessData, StartOptions
from pyethercat.master.ring import Diagnosis, RingService
from pyethercat.master.ringwatch import RingWatch
from pyethercat.master.scheduler import (
    DEFAULT_MAX_IN_FLIGHT,
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT,
    Scheduler,
)
from pyethercat.master.sii_write import SiiWriteReport
from pyethercat.master.slave import Identity, Slave
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.master.transitions import TransitionHook, Transitions
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import MASTER_MAC
from pyethercat.wire.mailbox.datatypes import Value
from pyethercat.wire.registers import RX_ERROR_COUNTER
from pyethercat.wire.sii import SII_DEFAULT_MAX_BYTES

if TYPE_CHECKING:
    from pyethercat.master.control.server import ControlServer

__all__ = ["Master", "SlaveRef"]

#: A slave given by object or by ring position.
SlaveRef = Slave | int
C = TypeVar("C")


class _SlaveServices:
    """What the slave handles of one master ask for (:class:`~pyethercat.master.slave.SlaveServices`)."""

    def __init__(self, mailboxes: MailboxService, pd: ProcessData, coe: CoeSetup) -> None:
        self._mailboxes, self._pd, self._coe = mailboxes, pd, coe

    def mailbox_of(self, position: int) -> Mailbox | None:
        return self._mailboxes.mailbox_of(position)

    def client_of(self, position: int, kind: type[C]) -> C | None:
        return self._mailboxes.client_of(position, kind)

    def io_of(self, slave: SlaveInfo, outputs: bool) -> SlaveIO:
        return self._pd.io_of(slave, outputs)

    def map_pdos(self, slave: SlaveInfo,
                 mapping: Mapping[int, Sequence[PdoSpec]]) -> dict[int, list[MappedPdo]]:
        return self._coe.set_pdo_mapping(slave, mapping)


class Master:
    """An EtherCAT master on one link: a façade over its services.

    ``timeout``/``retries``/``max_in_flight`` configure the scheduler;
    ``clock`` is its time base: a :class:`~pyethercat.clock.VirtualClock` for
    links that answer synchronously inside ``send`` (the in-process pair link
    with a simulator as responder), where lost frames are known at once and
    waits move the virtual clock instead of sleeping. ``owns_link``:
    ``close`` closes the link too.

    The services, each usable on its own: ``scheduler`` (frames),
    ``transitions`` (state changes and their hooks), ``mailboxes`` (mailboxes
    and protocol clients), ``coe_setup`` (start-up commands, CoE PDO
    mapping), ``pd`` (process data and the cyclic runner), ``dc``
    (distributed clocks).
    """

    def __init__(self, link: Link, *, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = DEFAULT_RETRIES, max_in_flight: int = DEFAULT_MAX_IN_FLIGHT,
                 clock: Clock | None = None, src: bytes = MASTER_MAC,
                 station_base: int = scanning.DEFAULT_STATION_BASE, owns_link: bool = True,
                 mailbox_timeout: float = DEFAULT_MAILBOX_TIMEOUT) -> None:
        self.link = link
        self.scheduler = Scheduler(link, timeout=timeout, retries=retries,
                                   max_in_flight=max_in_flight, src=src, clock=clock)
        self.station_base = station_base
        self.owns_link = owns_link
        #: Slaves in ring order, filled by :meth:`scan`.
        self.slaves: list[Slave] = []
        #: Whether the last scan's topology walk explained every slave.
        self.topology_consistent = True
        self._lock = threading.RLock()
        self._closed = False
        self.transitions = Transitions(self.scheduler)
        self.mailboxes = MailboxService(self.scheduler, runner=lambda: self.pd.runner,
                                        timeout=mailbox_timeout)
        #: Distributed clocks: set-up, SYNC pulses, the cyclic plan (:class:`DistributedClocks`).
        self.dc = DistributedClocks(self.scheduler.transact, lambda: self.slaves,
                                    sleep=self.scheduler.sleep,
                                    ring_port=lambda: self.ring.ring_end)
        self.coe_setup = CoeSetup(self.mailboxes,
                                  bring_to_preop=self._to_preop,
                                  mapping_changed=lambda: self.pd.invalidate())
        self.pd = ProcessData(self.scheduler, self.transitions, lambda: self.slaves, self.dc,
                              lock=self._lock,
                              before_configure=self.coe_setup.read_missing_mappings)
        # Around every state change: mailbox SMs and exchange state, then start-up commands.
        self.transitions.add_hook(self.mailboxes)
        self.transitions.add_hook(self.coe_setup)
        self.sii = SiiService(self.scheduler, self._lock)
        #: Ring ports, fault localisation and fault events (:class:`RingService`).
        self.ring = RingService(self.scheduler, lambda: self.slaves,
                                now_ns=lambda: int(self.scheduler.now() * 1e9))
        # Every cyclic loop carries the ring watch: events through the IRQ field, faults.
        self.pd.rider_factories.append(lambda runner: _ring_watch(self, runner))
        #: Slaves that come back (power-cycled, hot-swapped) are identified and configured.
        self.hotswap = HotSwap(self.scheduler, self.pd, self.dc, lambda: self.slaves,
                               now_ns=lambda: int(self.scheduler.now() * 1e9),
                               make_slave=self._make_slave, mailboxes=self.mailboxes,
                               ring=self.ring)
        self.pd.recovery = self.hotswap.recover
        self._services = _SlaveServices(self.mailboxes, self.pd, self.coe_setup)
        #: The control socket server, while one serves this master (see :meth:`open`).
        self.control: ControlServer | None = None

    # -- opening and closing ---------------------------------------------------------

    @classmethod
    def open(cls, where: str | None = None, *, iface: str | None = None,
             udp: str | None = None, link: Link | None = None,
             timeout: float = DEFAULT_TIMEOUT, retries: int = DEFAULT_RETRIES,
             max_in_flight: int = DEFAULT_MAX_IN_FLIGHT, clock: Clock | None = None,
             src: bytes = MASTER_MAC, station_base: int = scanning.DEFAULT_STATION_BASE,
             mailbox_timeout: float = DEFAULT_MAILBOX_TIMEOUT, control: bool = True,
             redundant: str | None = None, redundant_iface: str | None = None,
             redundant_udp: str | None = None) -> Master:
        """Open a master on a link named as :func:`pyethercat.link.open_link` takes it.

        ``where`` is ``"raw:eth1"`` (or just ``"eth1"``), ``"udp:HOST[:PORT]"``,
        ``"unix:PATH"``...; ``iface="eth1"`` and ``udp="HOST[:PORT]"`` are the
        same as ``raw:`` and ``udp:``; ``link`` is a link made elsewhere.
        Give exactly one. The other options go to :class:`Master`. With
        ``control`` (on an interface or UDP peer) the master serves its control
        socket, so the command line reaches it while it runs
        (:mod:`pyethercat.master.control`); a second master on the same link
        is refused with :class:`ConfigError`. When the socket cannot be made (no
        writable runtime directory) the master still opens, with a warning logged.

        A ring (cable redundancy, ``docs/redundancy.md``): ``redundant`` names
        the second port as ``where`` does (``redundant_iface="eth2"`` and
        ``redundant_udp=...`` are the same as ``raw:``/``udp:``), the port
        cabled to the last slave's free port; both ports become one
        :class:`~pyethercat.link.redundant.RedundantLink`.
        """
        link, name = _open_links(where, iface, udp, link,
                                 (redundant, redundant_iface, redundant_udp))
        master = cls(link, timeout=timeout, retries=retries, max_in_flight=max_in_flight,
                     clock=clock, src=src, station_base=station_base,
                     mailbox_timeout=mailbox_timeout)
        if control and name is not None:
            _serve_control(master, name)
        return master

    def close(self) -> None:
        """Stop cyclic exchange in order (if it runs), the scheduler, the owned link; idempotent."""
        if not self._closed:
            with contextlib.suppress(EtherCATError):
                self.pd.stop()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if self.control is not None:
                self.control.close()
                self.control = None
            self.scheduler.close()
            if self.owns_link:
                self.link.close()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran (the master sends nothing more)."""
        return self._closed

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Master on {self.link.name}: {len(self.slaves)} slaves>"

    # -- helpers ----------------------------------------------------------------------

    def slave(self, ref: SlaveRef) -> Slave:
        """The scanned slave at a position (or the slave itself)."""
        if isinstance(ref, Slave):
            return ref
        if not 0 <= ref < len(self.slaves):
            raise ConfigError(f"no slave at position {ref} ({len(self.slaves)} slaves scanned)")
        return self.slaves[ref]

    def slave_by_alias(self, alias: int) -> Slave:
        """The slave whose station alias is ``alias``."""
        for s in self.slaves:
            if s.alias == alias:
                return s
        raise ConfigError(f"no slave with alias {alias}")

    def slave_by_station(self, station_address: int) -> Slave:
        """The slave with configured station address ``station_address``."""
        for s in self.slaves:
            if s.station_address == station_address:
                return s
        raise ConfigError(f"no slave with station address 0x{station_address:04X}")

    def _select(self, slaves: Sequence[SlaveRef] | None) -> list[Slave]:
        return list(self.slaves) if slaves is None else [self.slave(s) for s in slaves]

    def _addressing(self, ref: SlaveRef) -> tuple[Command, Command, int, str]:
        """(read command, write command, ADP, label): FPxx for scanned slaves, APxx otherwise."""
        if isinstance(ref, Slave):
            return Command.FPRD, Command.FPWR, ref.station_address, ref.describe()
        if 0 <= ref < len(self.slaves):
            s = self.slaves[ref]
            return Command.FPRD, Command.FPWR, s.station_address, s.describe()
        if not 0 <= ref <= 0xFFFF:
            raise ConfigError(f"slave position {ref} out of range")
        return Command.APRD, Command.APWR, (-ref) & 0xFFFF, f"slave {ref}"

    # -- scanning ---------------------------------------------------------------------

    def count_slaves(self) -> int:
        """Number of slaves that answer a broadcast read."""
        return scanning.count_slaves(self.scheduler)

    def scan(self, *, expected: Sequence[Identity | scanning.ExpectedSlave] | None = None,
             progress: scanning.Progress | None = None, station_base: int | None = None,
             reset: bool = True, read_sii: bool = True,
             max_sii_bytes: int = SII_DEFAULT_MAX_BYTES) -> list[Slave]:
        """Find every slave, give it a station address, read its SII, rebuild the topology.

        ``reset`` first brings all slaves to INIT (acknowledging errors);
        ``expected`` (identities by position) raises
        :class:`~pyethercat.errors.TopologyMismatchError` on a difference.
        ``progress(stage, done, total)`` is called as the scan goes.
        """
        with self._lock:
            base = self.station_base if station_base is None else station_base
            slaves = scanning.scan(self.scheduler, make=self._make_slave, station_base=base,
                                   reset=reset, read_sii=read_sii, progress=progress,
                                   max_sii_bytes=max_sii_bytes)
            self.slaves = slaves
            self.mailboxes.attach(slaves)
            self.topology_consistent = scanning.build_topology(slaves)
            self.ring.learn()
            if reset and slaves:
                # A chip in device emulation (no firmware: EK1100, EL1004) copies AL
                # control into AL status, so the reset's INIT + acknowledge reads back
                # as INIT + error flag until INIT is written without the acknowledge
                # bit; the wait below would sit out its whole timeout.
                echo = [s for s in slaves if s.device_emulation and s.al_error]
                if echo:
                    states.request_state(self.scheduler, echo, AlState.INIT)
                # Slaves that take longer show up in the listing; set_state() reports them.
                with contextlib.suppress(StateTimeoutError):
                    states.wait_for_state(self.scheduler, slaves, AlState.INIT, timeout=2.0)
            if expected is not None:
                scanning.check_expected(slaves, expected)
            return slaves

    def _to_preop(self, slaves: Sequence[SlaveInfo]) -> None:
        self.set_state(AlState.PREOP, [s.position for s in slaves])

    def _make_slave(self, position: int, station_address: int) -> Slave:
        return Slave(position, station_address, self._services)

    def check_expected(self, expected: Sequence[Identity | scanning.ExpectedSlave]) -> None:
        """Compare the scanned slaves with an expected configuration."""
        scanning.check_expected(self.slaves, expected)

    # -- register access --------------------------------------------------------------

    def read(self, slave: SlaveRef, address: int, size: int) -> bytes:
        """Read ``size`` bytes at ``address`` of one slave; the slave must answer."""
        rd, _, adp, label = self._addressing(slave)
        reply = self.scheduler.transact_one(Datagram.device(rd, adp, address, size))
        if reply.wkc != 1:
            raise WorkingCounterError(f"{label}: read of {size} bytes at 0x{address:04X}", 1,
                                      reply.wkc)
        return bytes(reply.data)

    def write(self, slave: SlaveRef, address: int, data: bytes) -> None:
        """Write ``data`` at ``address`` of one slave; the slave must take it."""
        _, wr, adp, label = self._addressing(slave)
        reply = self.scheduler.transact_one(Datagram.device(wr, adp, address, bytes(data)))
        if reply.wkc != 1:
            raise WorkingCounterError(f"{label}: write of {len(data)} bytes at 0x{address:04X}",
                                      1, reply.wkc)

    def read_u16(self, slave: SlaveRef, address: int) -> int:
        """Read a 16-bit little-endian register of one slave (see :meth:`read`)."""
        value: int = struct.unpack("<H", self.read(slave, address, 2))[0]
        return value

    def read_many(self, address: int, size: int,
                  slaves: Sequence[SlaveRef] | None = None) -> list[diag.MultiReadResult]:
        """The multiple read: one register range of many slaves in as few frames as fit.

        Results carry each slave's working counter; nothing is raised for a
        slave that did not answer.
        """
        chosen = self._select(slaves)
        return diag.multiple_read(self.scheduler, [s.station_address for s in chosen],
                                  address, size)

    def write_many(self, address: int, data: bytes | Sequence[bytes],
                   slaves: Sequence[SlaveRef] | None = None) -> list[int]:
        """Write one register range of many slaves (same data or one item each); WKCs back."""
        chosen = self._select(slaves)
        return diag.multiple_write(self.scheduler, [s.station_address for s in chosen],
                                   address, data)

    def broadcast_read(self, address: int, size: int) -> tuple[bytes, int]:
        """BRD: the OR of every slave's bytes and the number of slaves that answered."""
        reply = self.scheduler.transact_one(Datagram.device(Command.BRD, 0, address, size))
        return bytes(reply.data), reply.wkc

    def broadcast_write(self, address: int, data: bytes) -> int:
        """BWR to every slave; returns the working counter."""
        reply = self.scheduler.transact_one(Datagram.device(Command.BWR, 0, address, data))
        return reply.wkc

    def transact(self, datagrams: Sequence[Datagram]) -> list[Datagram]:
        """Send raw datagrams through the scheduler (batched) and return the replies."""
        return self.scheduler.transact(datagrams)

    # -- states -------------------------------------------------------------------------

    def read_states(self, slaves: Sequence[SlaveRef] | None = None
                    ) -> list[states.AlStatusReading]:
        """AL status of the slaves in one multiple read (updates ``al_state`` etc.)."""
        return states.read_al_status(self.scheduler, self._select(slaves))

    def request_state(self, state: AlState | int | str,
                      slaves: Sequence[SlaveRef] | None = None, *, ack: bool = False) -> None:
        """Write a state request to the slaves without waiting."""
        states.request_state(self.scheduler, self._select(slaves), _state(state), ack)

    def wait_state(self, state: AlState | int | str, slaves: Sequence[SlaveRef] | None = None,
                   timeout: float = states.DEFAULT_STATE_TIMEOUT) -> None:
        """Wait until the slaves are in ``state`` (AlStatusError / StateTimeoutError otherwise)."""
        states.wait_for_state(self.scheduler, self._select(slaves), _state(state), timeout)

    def set_state(self, state: AlState | int | str, slaves: Sequence[SlaveRef] | None = None,
                  timeout: float = states.DEFAULT_STATE_TIMEOUT, *,
                  ack_errors: bool = True, hooks: Sequence[TransitionHook] | None = None,
                  configure: bool = False, wait: bool = True) -> None:
        """Bring slaves to ``state`` through the standard path and wait for it.

        ``timeout`` applies to each step. Refusals raise
        :class:`~pyethercat.errors.AlStatusError` with the AL status code;
        slaves that take too long raise
        :class:`~pyethercat.errors.StateTimeoutError` naming them. The
        master's transition hooks run around each step (mailbox sync
        managers before INIT -> PREOP/BOOT, CoE start-up commands); ``hooks``
        replaces them for this call (``()``: none). With ``configure`` the
        process-data sync managers and FMMUs (and DC) are written before
        PREOP -> SAFEOP (configuring from SII or CoE first if :meth:`configure`
        has not run), as a slave refuses SAFEOP without them; OP still needs
        cyclic process data. Without ``wait`` the last step is requested and not
        waited for.
        """
        with self._lock:
            extra = self.pd.bring_up_hooks if configure else ()
            self.transitions.set_state(self._select(slaves), _state(state), timeout,
                                       ack_errors=ack_errors, hooks=hooks, extra=extra,
                                       wait=wait)

    def acknowledge_errors(self, slaves: Sequence[SlaveRef] | None = None) -> list[Slave]:
        """Acknowledge error flags; returns the slaves that had one."""
        return states.acknowledge_errors(self.scheduler, self._select(slaves))

    # -- diagnostics --------------------------------------------------------------------

    def error_counters(self, slaves: Sequence[SlaveRef] | None = None
                       ) -> diag.ErrorCounterReport:
        """Error counters 0x0300-0x0313 of every slave, read in one multiple read."""
        return diag.read_error_counters(self.scheduler, [(s.position, s.station_address)
                                                         for s in self._select(slaves)])

    def hot_connect(self, name: str, alias: int, size: int = 1) -> GroupPresence:
        """Declare a hot connect group: the slave carrying ``alias`` and the ``size - 1``
        behind it may go and come back while cycling, or be absent at the scan and be
        configured when it appears (see :mod:`pyethercat.master.hotswap`)."""
        return self.hotswap.add_group(HotConnectGroup(name, alias, size))

    def diagnose(self) -> Diagnosis:
        """Locate faults: which master port, cable or node failed, which cable corrupts frames.

        One multiple read of DL status and error counters (see
        :class:`~pyethercat.master.ring.RingService`); found and cleared
        faults also become events in ``master.ring.events``.
        """
        return self.ring.diagnose()

    def clear_error_counters(self, slaves: Sequence[SlaveRef] | None = None) -> None:
        """Clear the error counters (a write to a counter group clears the group)."""
        self.write_many(RX_ERROR_COUNTER, bytes(diag.ERROR_COUNTERS_SIZE), slaves)

    # -- mailboxes and CoE (the mailbox and CoE services) -------------------------------

    @property
    def emergencies(self) -> DropOldestQueue[EmergencyEvent]:
        """Emergencies of every slave (oldest dropped when 1024 are waiting)."""
        return self.mailboxes.emergencies

    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None:
        """Call ``callback(event)`` for every emergency of every slave."""
        self.mailboxes.on_emergency(callback)

    def poll_mailboxes(self) -> int:
        """Fetch whatever the slaves posted unasked (emergencies); returns how many came."""
        return self.mailboxes.poll(self.slaves)

    def coe(self, slave: SlaveRef) -> CoeClient:
        """The CoE client of a slave; :class:`ConfigError` when it has no mailbox."""
        return self.coe_setup.client(self.slave(slave))

    @property
    def startup_commands(self) -> list[StartupCommand]:
        """Every start-up command, in the order they run within a transition."""
        return self.coe_setup.startup_commands

    def add_startup_command(self, slave: SlaveRef, transition: str, index: int,
                            subindex: int, data: bytes | Value, complete_access: bool = False,
                            *, dtype: DTypeLike | None = None, comment: str = "",
                            timeout: float | None = None) -> StartupCommand:
        """Have an SDO download done at a state transition (ESI ``InitCmd``).

        ``transition`` is ``"IP"``, ``"PS"``, ``"SO"``, ``"SP"``, ``"OS"``...;
        ``data`` raw bytes, or a value encoded as ``dtype``.
        """
        return self.coe_setup.add(self.slave(slave), transition, index, subindex, data,
                                  complete_access, dtype=dtype, comment=comment,
                                  timeout=timeout)

    def remove_startup_commands(self, slave: SlaveRef | None = None,
                                predicate: Callable[[StartupCommand], bool] | None = None,
                                ) -> int:
        """Remove start-up commands (of one slave, matching ``predicate``); returns how many."""
        pos = None if slave is None else (slave.position if isinstance(slave, Slave) else slave)
        return self.coe_setup.remove(pos, predicate)

    def read_coe_pdo_mappings(self, slaves: Sequence[SlaveRef] | None = None, *,
                              bring_to_preop: bool = True) -> dict[int, dict[int, list[MappedPdo]]]:
        """Read the PDO assignment and mapping of CoE slaves (see :class:`CoeSetup`)."""
        return self.coe_setup.read_pdo_mappings(self._select(slaves),
                                                bring_to_preop=bring_to_preop)

    @property
    def coe_pdo_config(self) -> bool:
        """Read PDO mappings over CoE (instead of the SII) for slaves that speak CoE."""
        return self.coe_setup.pdo_config

    @coe_pdo_config.setter
    def coe_pdo_config(self, value: bool) -> None:
        self.coe_setup.pdo_config = value

    # -- process data (the process-data service) ---------------------------------------

    @property
    def process_data(self) -> ProcessDataConfig | None:
        """The process-data configuration (None before :meth:`configure`)."""
        return self.pd.config

    @property
    def images(self) -> dict[str, ProcessImage]:
        """The group images of the configuration, by group name."""
        return self.pd.images

    @property
    def runner(self) -> CyclicRunner | None:
        """The cyclic runner of the last :meth:`start`."""
        return self.pd.runner

    def configure(self, groups: Sequence[GroupSpec] | None = None,
                  layout: Layout | str = Layout.PACKED,
                  cross: Sequence[CrossLink] | None = None) -> ProcessDataConfig:
        """Compute SM/FMMU values and group images (see :meth:`ProcessData.configure`);
        ``cross``: slaves whose inputs drive later slaves' outputs in the frame."""
        return self.pd.configure(groups, layout, cross)

    def write_mailbox_config(self, slaves: Sequence[SlaveRef] | None = None) -> None:
        """Write the mailbox sync managers (needed before PRE-OP), all slaves batched."""
        self.pd.write_mailbox_config(None if slaves is None else self._select(slaves))

    def write_process_data_config(self, slaves: Sequence[SlaveRef] | None = None) -> None:
        """Write process-data SMs and FMMUs (needed before SAFE-OP), all slaves batched."""
        self.pd.write_process_data_config(None if slaves is None else self._select(slaves))

    def start(self, cycle: float = 0.001, **options: Unpack[StartOptions]) -> CyclicRunner:
        """Configure (if needed), bring every slave to SAFE-OP, start cycles, go to ``target``.

        Options and the orderly stop that ends the exchange: :meth:`ProcessData.start`;
        ``isolated`` runs the loop in a process of its own (docs/realtime.md).
        """
        return self.pd.start(cycle, **options)

    def run(self, cycle: float = 0.001, seconds: float | None = None, *,
            background: bool = False, **options: Unpack[StartOptions]) -> CycleStats | CyclicRunner:
        """Bring up and run cycles for ``seconds`` (see :meth:`ProcessData.run`)."""
        return self.pd.run(cycle, seconds, background=background, **options)

    def cycles(self, cycle: float = 0.001, **options: Unpack[StartOptions]) -> Iterator[Cycle]:
        """Start cyclic exchange and yield each cycle; closing the iterator stops it."""
        return self.pd.cycles(cycle, **options)

    def stop(self, final_state: AlState | str | None = None) -> None:
        """Stop the cyclic exchange in order (safe outputs, SAFEOP, ``final_state``)."""
        self.pd.stop(final_state)

    def safe_outputs(self, slave: SlaveRef) -> SlaveIO:
        """A slave's safe outputs: what an orderly stop sends (zero unless set here)."""
        return self.pd.safe_outputs(slave)

    # -- SII (the SII service) -------------------------------------------------------------

    def sii_read(self, slave: SlaveRef, *, max_bytes: int = SII_DEFAULT_MAX_BYTES) -> bytes:
        """Read one slave's SII again, from word 0 to the category end marker."""
        return self.sii.read(_sii_target(self, slave), max_bytes=max_bytes)

    def sii_write(self, slave: SlaveRef, image: bytes, *, reload: bool = True,
                  only_changed: bool = True, force: bool = False,
                  backup: Path | Callable[[bytes], Path] | None = None,
                  progress: scanning.Progress | None = None) -> SiiWriteReport:
        """Write an SII image into a slave's EEPROM, safely (see :mod:`pyethercat.master.sii_write`).

        Checksum computed, old content saved to ``backup`` first, another identity
        refused unless ``force``, every word read back; ``only_changed`` skips equal
        words, ``reload`` reloads the configuration words. Raises
        :class:`~pyethercat.master.sii_write.SiiWriteError` naming the failed word.
        """
        return self.sii.write(_sii_target(self, slave), image, reload=reload,
                              only_changed=only_changed, force=force, backup=backup,
                              progress=progress)

    def set_alias(self, slave: SlaveRef, alias: int, *,
                  backup: Path | Callable[[bytes], Path] | None = None,
                  force: bool = False) -> SiiWriteReport:
        """Write the station alias (SII word 4, checksum word 7; nothing else) and reload it."""
        return self.sii.set_alias(_sii_target(self, slave), alias, backup=backup, force=force)


def _ring_watch(master: Master, runner: CyclicRunner) -> RingWatch:
    """The ring watch a loop carries; slaves it finds gone update the hot connect groups."""
    master.hotswap.log = runner.log
    return RingWatch(master.ring, log=runner.log,
                     on_reading=lambda d, absent: master.hotswap.update_groups(absent, d))


def _sii_target(master: Master, slave: SlaveRef) -> SiiTarget:
    """The scanned slave, or the position of an unscanned one."""
    if isinstance(slave, Slave) or 0 <= slave < len(master.slaves):
        return master.slave(slave)
    if not 0 <= slave <= 0xFFFF:
        raise ConfigError(f"slave position {slave} out of range")
    return slave


def _state(state: AlState | int | str) -> AlState:
    if isinstance(state, str):
        try:
            return AlState.parse(state)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    try:
        return AlState(int(state))
    except ValueError:
        raise ConfigError(f"unknown AL state 0x{int(state):02X}") from None



def _open_links(where: str | None, iface: str | None, udp: str | None, link: Link | None,
                seconds: tuple[str | None, str | None, str | None]) -> tuple[Link, str | None]:
    """The link ``Master.open`` was asked for, and its name (None for a given link)."""
    from pyethercat.link.registry import open_link

    given = [x for x in (where, iface, udp, link) if x is not None]
    if len(given) != 1:
        raise ConfigError("give exactly one of a link name, iface, udp or link")
    redundant, redundant_iface, redundant_udp = seconds
    second = [x for x in seconds if x is not None]
    if len(second) > 1:
        raise ConfigError("give one second port: redundant, redundant_iface or redundant_udp")
    if link is not None:
        if second:
            raise ConfigError("a given link cannot take a second port: give a RedundantLink")
        return link, None
    name = where if where is not None else (f"raw:{iface}" if iface is not None
                                            else f"udp:{udp}")
    opened = open_link(name)
    if second:
        from pyethercat.link.redundant import RedundantLink

        other = redundant if redundant is not None else (
            f"raw:{redundant_iface}" if redundant_iface is not None else f"udp:{redundant_udp}")
        try:
            opened = RedundantLink(opened, open_link(other))
        except BaseException:
            opened.close()
            raise
    return opened, name


def _serve_control(master: Master, name: str) -> None:
    """Serve the master's control socket for the link ``name`` (if that link has one)."""
    spec = _control_spec(name)
    if spec is None:
        return
    from pyethercat.master.control.server import MasterRunningError, serve

    try:
        master.control = serve(master, spec)
    except MasterRunningError:
        master.close()
        raise
    except ConfigError as exc:
        # No socket (a read-only runtime directory...): the master works, the
        # command line just cannot reach it.
        logging.getLogger("pyethercat.master").warning(
            "no control socket for this master: %s", exc)
    except BaseException:
        master.close()
        raise


def _control_spec(link_name: str) -> str | None:
    """The control socket's link spec for a link opened by name (None: no control socket)."""
    from pyethercat.master.control.endpoint import link_spec

    scheme, _, rest = link_name.partition(":")
    if scheme == "ring" and "," in rest:
        # A ring is reached as its port A is (the command line names A in --iface/--udp).
        return _control_spec(rest.partition(",")[0])
    if scheme == "raw" and rest:
        return link_spec(iface=rest, udp=None)
    if scheme == "udp" and rest:
        return link_spec(iface=None, udp=rest)
    if ":" not in link_name:
        return link_spec(iface=link_name, udp=None)
    return None
