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
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Self

from pyethercat.clock import Clock
from pyethercat.errors import ConfigError, StateTimeoutError, WorkingCounterError
from pyethercat.link.base import Link
from pyethercat.master import diag, states
from pyethercat.master import scan as scanning
from pyethercat.master.clocks import DistributedClocks
from pyethercat.master.coe_setup import CoeMasterMixin
from pyethercat.master.process import ProcessDataMixin
from pyethercat.master.scheduler import (
    DEFAULT_MAX_IN_FLIGHT,
    DEFAULT_RETRIES,
    DEFAULT_TIMEOUT,
    Scheduler,
)
from pyethercat.master.sii_write import SiiWriteReport, WriteTiming, with_alias, write_sii_image
from pyethercat.master.slave import Identity, Slave
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import MASTER_MAC, returned_source_mac
from pyethercat.wire.registers import RX_ERROR_COUNTER, SII_CONTROL, STATION_ALIAS, SiiControl
from pyethercat.wire.sii import SII_DEFAULT_MAX_BYTES

if TYPE_CHECKING:
    from pyethercat.master.control.server import ControlServer

__all__ = ["Master", "SlaveRef"]

#: A slave given by object or by ring position.
SlaveRef = Slave | int


class Master(CoeMasterMixin, ProcessDataMixin):
    """An EtherCAT master on one link.

    ``timeout``/``retries``/``max_in_flight`` configure the scheduler;
    ``clock`` is its time base: a :class:`~pyethercat.clock.VirtualClock` for
    links that answer synchronously inside ``send`` (the in-process pair link
    with a simulator as responder), where lost frames are known at once and
    waits move the virtual clock instead of sleeping. ``owns_link``:
    ``close`` closes the link too.
    """

    def __init__(self, link: Link, *, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = DEFAULT_RETRIES, max_in_flight: int = DEFAULT_MAX_IN_FLIGHT,
                 clock: Clock | None = None, src: bytes = MASTER_MAC,
                 station_base: int = scanning.DEFAULT_STATION_BASE, owns_link: bool = True) -> None:
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
        #: Distributed clocks: set-up, SYNC pulses, the cyclic plan (:class:`DistributedClocks`).
        self.dc = DistributedClocks(self.scheduler.transact, lambda: self.slaves)
        #: The control socket server, while one serves this master (see :meth:`open`).
        self.control: ControlServer | None = None

    # -- opening and closing ---------------------------------------------------------

    @classmethod
    def open(cls, iface: str | None = None, *, udp: str | None = None,
             link: Link | None = None, control: bool = True, **options: object) -> Master:
        """Open a master on a network interface (raw socket), a UDP peer or a given link.

        ``udp`` is ``HOST[:PORT]`` (port 34980 by default). Other keyword
        options go to :class:`Master`. With ``control`` (on an interface or
        UDP peer) the master serves its control socket, so the command line
        reaches it while it runs (:mod:`pyethercat.master.control`); a second
        master on the same link is refused with :class:`ConfigError`. When the
        socket cannot be made (no writable runtime directory) the master still
        opens, with a warning logged.
        """
        given = [x for x in (iface, udp, link) if x is not None]
        if len(given) != 1:
            raise ConfigError("give exactly one of iface, udp or link")
        if link is None:
            if iface is not None:
                from pyethercat.link.raw import RawLink

                link = RawLink(iface)
            else:
                from pyethercat.link.udp import UdpLink

                # UDP carries no MACs: make replies look returned (LA bit), as on a wire.
                src = options.get("src", MASTER_MAC)
                assert isinstance(src, bytes)
                link = UdpLink(peer=udp, rx_src=returned_source_mac(src))
        master = cls(link, **options)  # type: ignore[arg-type]
        if control and (iface is not None or udp is not None):
            from pyethercat.master.control.endpoint import link_spec
            from pyethercat.master.control.server import MasterRunningError, serve

            try:
                master.control = serve(master, link_spec(iface=iface, udp=udp))
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
        return master

    def close(self) -> None:
        """Stop the scheduler and (if owned) close the link. Idempotent."""
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

    def _sleep(self, seconds: float) -> None:
        self.scheduler.sleep(seconds)

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
            slaves = scanning.scan(self.scheduler, station_base=base, reset=reset,
                               read_sii=read_sii, progress=progress,
                               max_sii_bytes=max_sii_bytes)
            self.slaves = slaves
            self._attach_mailboxes(slaves)
            self.topology_consistent = scanning.build_topology(slaves)
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
                    states.wait_for_state(self.scheduler, slaves, AlState.INIT, timeout=2.0,
                                          sleep=self._sleep)
            if expected is not None:
                scanning.check_expected(slaves, expected)
            return slaves

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
        states.wait_for_state(self.scheduler, self._select(slaves), _state(state), timeout,
                              sleep=self._sleep)

    def set_state(self, state: AlState | int | str, slaves: Sequence[SlaveRef] | None = None,
                  timeout: float = states.DEFAULT_STATE_TIMEOUT, *,
                  ack_errors: bool = True,
                  prepare: states.PrepareStep | None = states.setup_mailboxes,
                  configure: bool = False, wait: bool = True) -> None:
        """Bring slaves to ``state`` through the standard path and wait for it.

        ``timeout`` applies to each step. Refusals raise
        :class:`~pyethercat.errors.AlStatusError` with the AL status code;
        slaves that take too long raise
        :class:`~pyethercat.errors.StateTimeoutError` naming them. ``prepare``
        runs before each step (default: mailbox sync managers from the SII
        before INIT -> PREOP/BOOT). With ``configure`` the process-data sync
        managers and FMMUs are written before PREOP -> SAFEOP (configuring
        from SII or CoE first if :meth:`configure` has not run), as a slave
        refuses SAFEOP without them; OP still needs cyclic process data.
        """
        with self._lock:
            finish = None
            if prepare is states.setup_mailboxes:
                # mailbox SMs plus the CoE start-up commands of each transition
                prepare, finish = self._prepare_step, self._finish_step
            if configure:
                prepare = self._with_process_data_config(prepare)
            states.set_state(self.scheduler, self._select(slaves), _state(state), timeout,
                             ack_errors=ack_errors, sleep=self._sleep, prepare=prepare,
                             finish=finish, wait=wait)

    def _with_process_data_config(self, inner: states.PrepareStep | None) -> states.PrepareStep:
        """``inner``, then the process-data SMs/FMMUs before the SAFEOP step."""

        def prepare(scheduler: Scheduler, step: AlState, group: Sequence[Slave]) -> None:
            if inner is not None:
                inner(scheduler, step, group)
            if step == AlState.SAFEOP:
                # Configured here, not earlier: CoE mappings are read in PREOP.
                self._need_config()
                self.write_process_data_config(group)
                self.dc.before_safeop(group)

        return prepare

    def acknowledge_errors(self, slaves: Sequence[SlaveRef] | None = None) -> list[Slave]:
        """Acknowledge error flags; returns the slaves that had one."""
        return states.acknowledge_errors(self.scheduler, self._select(slaves))

    # -- diagnostics --------------------------------------------------------------------

    def error_counters(self, slaves: Sequence[SlaveRef] | None = None
                       ) -> diag.ErrorCounterReport:
        """Error counters 0x0300-0x0313 of every slave, read in one multiple read."""
        chosen = self._select(slaves)
        results = diag.multiple_read(self.scheduler, [s.station_address for s in chosen],
                                     RX_ERROR_COUNTER, diag.ERROR_COUNTERS_SIZE)
        return diag.ErrorCounterReport(tuple(
            diag.decode_error_counters(s.position, s.station_address, r.data, r.ok)
            for s, r in zip(chosen, results, strict=True)))

    def clear_error_counters(self, slaves: Sequence[SlaveRef] | None = None) -> None:
        """Clear the error counters (a write to a counter group clears the group)."""
        self.write_many(RX_ERROR_COUNTER, bytes(diag.ERROR_COUNTERS_SIZE), slaves)

    # -- SII ------------------------------------------------------------------------------

    def _sii_access(self, slave: SlaveRef) -> scanning.SiiAccess:
        if isinstance(slave, Slave) or 0 <= slave < len(self.slaves):
            return scanning.SiiAccess.of(self.slave(slave))
        access = scanning.SiiAccess.at_position(slave)
        ctrl = self.read(slave, SII_CONTROL, 2)
        access.read_8 = bool(struct.unpack("<H", ctrl)[0] & SiiControl.READ_8_BYTES)
        return access

    def sii_read(self, slave: SlaveRef, *,
                 max_bytes: int = SII_DEFAULT_MAX_BYTES) -> bytes:
        """Read one slave's SII again, from word 0 to the category end marker."""
        with self._lock:
            access = self._sii_access(slave)
            result = scanning.read_sii_batch(self.scheduler, [access], max_bytes=max_bytes)[0]
            if isinstance(result, Exception):
                raise result
            return result

    def sii_write(self, slave: SlaveRef, image: bytes, *, reload: bool = True,
                  only_changed: bool = True, force: bool = False,
                  backup: Path | Callable[[bytes], Path] | None = None,
                  progress: scanning.Progress | None = None) -> SiiWriteReport:
        """Write an SII image into a slave's EEPROM, safely (see :mod:`pyethercat.master.sii_write`).

        The header checksum is computed here; the old content is read first
        (and saved to ``backup`` when given, before anything changes); an
        image of another identity (vendor, product, revision) is refused
        unless ``force``; every word is read back. With ``only_changed``
        equal words are skipped (EEPROM writes take milliseconds each).
        ``reload`` makes the ESC load its configuration words (alias...)
        afterwards. Raises :class:`~pyethercat.master.sii_write.SiiWriteError`
        naming the failed word.
        """
        with self._lock:
            access = self._sii_access(slave)
            report = write_sii_image(self.scheduler, access, image, force=force,
                                     only_changed=only_changed, reload=reload, backup=backup,
                                     timing=self._sii_timing(), sleep=self._sleep,
                                     now=self.scheduler.now, progress=progress)
            self._refresh_alias(slave, reload)
            return report

    def set_alias(self, slave: SlaveRef, alias: int, *,
                  backup: Path | Callable[[bytes], Path] | None = None,
                  force: bool = False) -> SiiWriteReport:
        """Write the station alias (SII word 4, with a new checksum) and reload it.

        The rest of the EEPROM stays as it is (only words 4 and 7 change).
        """
        with self._lock:
            access = self._sii_access(slave)
            current = scanning.read_sii_batch(self.scheduler, [access])[0]
            if isinstance(current, Exception) or len(current) < 16:
                current = scanning.read_sii_batch(self.scheduler, [access], length=16)[0]
                if isinstance(current, Exception):
                    raise current
            report = write_sii_image(self.scheduler, access, with_alias(current, alias),
                                     force=force, backup=backup, timing=self._sii_timing(),
                                     sleep=self._sleep, now=self.scheduler.now)
            self._refresh_alias(slave, True)
            return report

    def _sii_timing(self) -> WriteTiming:
        # In virtual time the simulated EEPROM's clock moves with the frames only.
        return WriteTiming.for_virtual_time() if self.scheduler.virtual else WriteTiming()

    def _refresh_alias(self, slave: SlaveRef, reloaded: bool) -> None:
        if reloaded and (isinstance(slave, Slave) or 0 <= slave < len(self.slaves)):
            s = self.slave(slave)
            s.alias = self.read_u16(s, STATION_ALIAS)


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

