"""The master's distributed-clock service: set-up, SYNC0/SYNC1, the cyclic plan, status.

:class:`DistributedClocks` joins the sans-IO parts (:mod:`pyethercat.master.dc`,
:mod:`pyethercat.master.dc_loop`) to a scheduler and the scanned slaves::

    with Master.open(iface="eth1") as m:
        m.scan()
        report = m.dc.setup()                      # delays, offsets, static compensation
        m.dc.configure_sync(1_000_000, shift_ns=0)   # SYNC0 on every slave with a DC op mode
        m.run(cycle=0.001, seconds=10, dc="master")  # phase-locked to the reference clock

SYNC0/SYNC1 are written before PREOP -> SAFEOP (:meth:`before_safeop`): for
CoE slaves the sync mode 0x1C32/0x1C33 sub 1 first (2 = DC SYNC0 when the
slave gets SYNC pulses; a slave left in a DC mode is put back to 1 = SM
event when it does not), then the cyclic unit registers with a start time on
the cycle grid read from the reference clock just before.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from pyethercat.errors import ConfigError, EtherCATError, WorkingCounterError
from pyethercat.master.dc import (
    DcError,
    DcReport,
    DcSettings,
    DcSlaveInfo,
    Progress,
    SyncSettings,
    ecat_time_ns,
    run_dc_setup,
    sync_config_writes,
)
from pyethercat.master.dc_loop import DcCycle, DcMode
from pyethercat.master.slave import Slave
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.dc import AssignActivate, decode_time_difference, sync1_cycle_register
from pyethercat.wire.mailbox.objects import StandardObject, SyncMode, SyncModeSupported, SyncSub

if TYPE_CHECKING:
    from pyethercat.master.transitions import Step

__all__ = ["DcStatus", "DistributedClocks", "dc_slave_info", "sync_assign_activate"]

Transact = Callable[[Sequence[Datagram]], list[Datagram]]


class _TimeSource(Protocol):
    def now_ns(self) -> int: ...


def dc_slave_info(slave: Slave) -> DcSlaveInfo:
    """The set-up's view of a scanned slave."""
    return DcSlaveInfo(slave.position, slave.station_address, slave.esc.features,
                       frozenset(slave.active_ports), slave.name)


def sync_assign_activate(slave: Slave) -> int:
    """The AssignActivate of the slave's DC op mode: the one an ESI or ENI chose (also 0,
    an SM-synchronous or free-run mode: no pulses), else the first SII DC mode that
    activates the cyclic unit (0: the slave has none)."""
    eni = slave.dc_op_mode
    if eni is not None:
        return int(eni.assign_activate)
    if slave.sii is not None:
        for mode in slave.sii.dc_modes:
            if AssignActivate(mode.assign_activate).active:
                return int(mode.assign_activate)
    return 0


@dataclass(frozen=True)
class DcStatus:
    """The DC registers of one slave as read now (``None``: not implemented by it)."""

    position: int
    station_address: int
    name: str
    supported: bool
    bits: int | None
    system_time: int | None = None
    offset: int | None = None
    delay: int | None = None
    difference: int | None = None     # |0x092C|, ns
    speed_counter_diff: int | None = None
    activation: int | None = None     # 0x0980 (low byte) | 0x0981 << 8
    sync0_cycle: int | None = None
    sync1_cycle: int | None = None
    start_time: int | None = None
    pulse_length_ns: int | None = None

    @property
    def assign_activate(self) -> AssignActivate | None:
        return None if self.activation is None else AssignActivate(self.activation)


class DistributedClocks:
    """DC for one master (see the module text).

    ``transact`` sends a batch of datagrams and returns the replies;
    ``slaves`` returns the scanned slaves; ``master_time`` the master's
    time in ns since 2000 (the host's real-time clock by default; tests on
    virtual time pass their own).
    """

    def __init__(self, transact: Transact, slaves: Callable[[], list[Slave]], *,
                 master_time: Callable[[], int] = ecat_time_ns,
                 sleep: Callable[[float], None] | None = None,
                 ring_port: Callable[[], tuple[int, int] | None] | None = None) -> None:
        self._transact = transact
        self._slaves = slaves
        self.master_time = master_time
        self._sleep = sleep
        #: On a ring: the (position, port) cabled to the master's second port.
        self._ring_port = ring_port
        #: Result of the last :meth:`setup` (None before).
        self.report: DcReport | None = None
        #: SYNC settings per slave position, applied before SAFE-OP.
        self.sync: dict[int, SyncSettings] = {}

    # -- set-up -------------------------------------------------------------------------

    def setup(self, settings: DcSettings | None = None, *,
              progress: Progress | None = None) -> DcReport:
        """Measure delays, write offsets and delays, compensate the drift (:class:`DcSetup`)."""
        slaves = self._slaves()
        if not slaves:
            raise ConfigError("no slaves: scan first")
        kw = {} if self._sleep is None else {"sleep": self._sleep}
        infos = [dc_slave_info(s) for s in slaves]
        ring = self._ring_port() if self._ring_port is not None else None
        if ring is None:
            self.report = run_dc_setup(self._transact, infos, settings,
                                       master_time=self.master_time, progress=progress, **kw)
            return self.report
        # A ring: the frame that latches the receive times would leave at the master's
        # second port and pass no port on its way back. The ring port's loop is closed
        # for the set-up (the segment is a line then) and left out of the walk.
        pos, port = ring
        s = slaves[pos]
        info = infos[pos]
        infos[pos] = DcSlaveInfo(info.position, info.station_address, info.features,
                                 info.active_ports - {port}, info.name)
        loop = self._transact([Datagram.device(Command.FPRD, s.station_address,
                                               R.DL_CONTROL_LOOP, 1)])[0]
        old = loop.data[0] if loop.wkc == 1 else 0
        closed = (old & ~(3 << (2 * port))) | (int(R.LoopControl.CLOSED) << (2 * port))
        self._transact([Datagram.device(Command.FPWR, s.station_address, R.DL_CONTROL_LOOP,
                                        bytes([closed]))])
        try:
            self.report = run_dc_setup(self._transact, infos, settings,
                                       master_time=self.master_time, progress=progress, **kw)
        finally:
            self._transact([Datagram.device(Command.FPWR, s.station_address,
                                            R.DL_CONTROL_LOOP, bytes([old]))])
        return self.report

    def _need_report(self) -> DcReport:
        if self.report is None:
            self.setup()
        assert self.report is not None
        return self.report

    @property
    def reference(self) -> Slave | None:
        """The reference clock (after :meth:`setup`)."""
        if self.report is None or self.report.reference is None:
            return None
        return self._slaves()[self.report.reference]

    # -- SYNC0 / SYNC1 ------------------------------------------------------------------

    def configure_sync(self, cycle_ns: int, shift_ns: int = 0, *,
                       sync1_delay_ns: int | None = None, sync1_multiple: int | None = None,
                       sync1_shift_ns: int = 0, slaves: Sequence[Slave] | None = None,
                       assign_activate: int | None = None) -> dict[int, SyncSettings]:
        """Ask for SYNC0 (and SYNC1) pulses; they start before the next PREOP -> SAFEOP.

        ``slaves`` default to every slave with a system time and a DC op mode
        (its AssignActivate from the ESI or SII); ``assign_activate``
        overrides the value (0x0300 SYNC0, 0x0700 SYNC0 + SYNC1). SYNC1 is a
        delay after every SYNC0 (``sync1_delay_ns``) or fires every n-th SYNC0
        cycle (``sync1_multiple``, ``sync1_shift_ns`` after it). Returns the
        settings per position.
        """
        report = self._need_report()
        if cycle_ns <= 0:
            raise ConfigError(f"SYNC0 cycle time must be positive, got {cycle_ns} ns")
        want_sync1 = sync1_delay_ns is not None or sync1_multiple is not None
        cycle1 = sync1_cycle_register(cycle_ns, delay_ns=sync1_delay_ns, multiple=sync1_multiple,
                                      shift_ns=sync1_shift_ns) if want_sync1 else 0
        chosen = list(self._slaves()) if slaves is None else list(slaves)
        out: dict[int, SyncSettings] = {}
        for s in chosen:
            r = report.slaves[s.position]
            if not r.system_time or r.before_reference:
                if slaves is not None:
                    raise ConfigError(f"{s.describe()} has no DC system time: no SYNC pulses")
                continue
            aa = assign_activate if assign_activate is not None else sync_assign_activate(s)
            if not aa:
                if slaves is not None:
                    aa = int(AssignActivate.for_sync(True, want_sync1).value)
                else:
                    continue  # no DC op mode: the device does not use SYNC pulses
            if want_sync1 and not AssignActivate(aa).sync1:
                aa = int(AssignActivate.for_sync(True, True).value) | (aa & 0x00FF)
            out[s.position] = SyncSettings(aa, cycle_ns, shift_ns, cycle1)
        self.sync.update(out)
        return out

    def clear_sync(self) -> None:
        """No SYNC pulses any more at the next bring-up."""
        self.sync.clear()

    def reference_time(self) -> int:
        """The reference clock's system time now (FPRD 0x0910)."""
        ref = self.reference
        if ref is None:
            raise DcError("no reference clock: run the DC set-up first")
        size = 8 if ref.esc.dc_64bit else 4
        reply = self._transact([Datagram.device(Command.FPRD, ref.station_address,
                                                R.DC_SYSTEM_TIME, size)])[0]
        if reply.wkc != 1:
            raise WorkingCounterError(f"{ref.describe()}: reading the reference time", 1, reply.wkc)
        return int.from_bytes(reply.data, "little")

    def apply_sync(self, slaves: Sequence[Slave] | None = None) -> None:
        """Write the cyclic unit registers now (stop, cycles, start time, AssignActivate)."""
        chosen = list(self._slaves()) if slaves is None else list(slaves)
        chosen = [s for s in chosen if s.position in self.sync]
        if not chosen:
            return
        now = self.reference_time()
        dgs: list[Datagram] = []
        for s in chosen:
            st = self.sync[s.position]
            for addr, data in sync_config_writes(st, st.start_time(now), s.esc.dc_64bit):
                dgs.append(Datagram.device(Command.FPWR, s.station_address, addr, data))
        for d in self._transact(dgs):
            if d.wkc != 1:
                s = next(x for x in chosen if x.station_address == d.adp)
                raise WorkingCounterError(f"{s.describe()}: writing the DC cyclic unit at "
                                          f"0x{d.ado:04X}", 1, d.wkc)

    def stop_sync(self, slaves: Sequence[Slave] | None = None) -> None:
        """Switch the cyclic unit of the slaves off (0x0980/0x0981 = 0)."""
        chosen = [s for s in (self._slaves() if slaves is None else slaves) if s.dc_supported]
        if chosen:
            self._transact([Datagram.device(Command.FPWR, s.station_address,
                                            R.DC_CYCLIC_UNIT_CONTROL, bytes(2)) for s in chosen])

    def write_sync_modes(self, slaves: Sequence[Slave]) -> None:
        """0x1C32/0x1C33 sub 1 of CoE slaves: DC SYNC0 (2) with pulses, SM event (1) without.

        A slave that gets pulses but whose 0x1C32 sub 4 lacks DC SYNC0 is a
        configuration error. Slaves without these objects are left alone, as
        are slaves without pulses whose mode is not a DC one.
        """
        for s in slaves:
            if s.coe is None or not s.has_coe:
                continue
            try:
                supported = int(s.sdo_read(StandardObject.SM_OUTPUT_SYNC,
                                           SyncSub.SYNC_MODES_SUPPORTED, "uint16"))
                current = int(s.sdo_read(StandardObject.SM_OUTPUT_SYNC, SyncSub.SYNC_MODE,
                                         "uint16"))
            except EtherCATError:
                continue  # no 0x1C32: the device does not take a sync mode
            dc = s.position in self.sync
            if dc:
                if not supported & SyncModeSupported.DC_SYNC0:
                    raise ConfigError(f"{s.describe()}: SYNC pulses asked for, but 0x1C32:04 = "
                                      f"0x{supported:04X} offers no DC SYNC0 mode")
                mode = SyncMode.DC_SYNC0
            elif current in (SyncMode.DC_SYNC0, SyncMode.DC_SYNC1) and (
                    supported & SyncModeSupported.SYNCHRONOUS):
                mode = SyncMode.SM_EVENT
            else:
                continue
            for index in (StandardObject.SM_OUTPUT_SYNC, StandardObject.SM_INPUT_SYNC):
                try:
                    s.sdo_write(index, SyncSub.SYNC_MODE, int(mode), "uint16")
                except EtherCATError:
                    if index == StandardObject.SM_OUTPUT_SYNC:
                        raise

    def before_step(self, step: Step) -> None:
        """As a transition hook: :meth:`before_safeop` before PREOP -> SAFEOP."""
        if step.target == AlState.SAFEOP:
            self.before_safeop(step.slaves)

    def after_step(self, step: Step) -> None:
        """As a transition hook: nothing once a state is reached."""

    def before_safeop(self, slaves: Sequence[Slave]) -> None:
        """The PREOP -> SAFEOP hook: sync modes over CoE, then the cyclic unit."""
        if self.report is None and not self.sync:
            return
        self.write_sync_modes(slaves)
        self.apply_sync(slaves)

    # -- cyclic -----------------------------------------------------------------------

    def cycle(self, cycle_ns: int, mode: DcMode | str, clock: _TimeSource, *,
              lead_ns: int | None = None) -> DcCycle:
        """The per-cycle DC plan for a cyclic engine running on ``clock``."""
        report = self._need_report()
        ref = self.reference
        if ref is None or report.reference is None:
            raise DcError("no reference clock")
        m = DcMode.parse(mode) if isinstance(mode, str) else mode
        shifts = {st.shift0 for st in self.sync.values()}
        shift = shifts.pop() if len(shifts) == 1 else 0
        offset = self.master_time() - clock.now_ns()
        return DcCycle(m, ref.station_address, cycle_ns, wide=ref.esc.dc_64bit, shift_ns=shift,
                       lead_ns=lead_ns, clock_offset_ns=offset)

    # -- status -------------------------------------------------------------------------

    def status(self, slaves: Sequence[Slave] | None = None) -> list[DcStatus]:
        """The DC registers of every slave, read now in one batch (for ``pyethercat dc``)."""
        chosen = list(self._slaves()) if slaves is None else list(slaves)
        dgs: list[Datagram] = []
        for s in chosen:
            dgs.append(Datagram.device(Command.FPRD, s.station_address, R.DC_SYSTEM_TIME, 0x24))
            dgs.append(Datagram.device(Command.FPRD, s.station_address, R.DC_CYCLIC_UNIT_CONTROL,
                                       R.DC_SYNC1_CYCLE + 4 - R.DC_CYCLIC_UNIT_CONTROL))
        replies = self._transact(dgs) if dgs else []
        out = []
        for k, s in enumerate(chosen):
            bits = (64 if s.esc.dc_64bit else 32) if s.dc_supported else None
            a, b = replies[2 * k], replies[2 * k + 1]
            kw: dict[str, int | None] = {}
            if s.dc_supported and a.wkc == 1:
                st, _epu, off, delay, diff, _start, sdiff = struct.unpack("<QQqIIHh", a.data[:0x24])
                kw.update(system_time=st if bits == 64 else st & 0xFFFF_FFFF,
                          offset=off if bits == 64 else off & 0xFFFF_FFFF, delay=delay,
                          difference=decode_time_difference(diff), speed_counter_diff=sdiff)
            if s.dc_supported and b.wkc == 1:
                data = bytes(b.data)
                cu, act, pulse = struct.unpack_from("<BBH", data, 0)
                base = R.DC_CYCLIC_UNIT_CONTROL
                start = struct.unpack_from("<Q", data, R.DC_START_TIME - base)[0]
                c0, c1 = struct.unpack_from("<II", data, R.DC_SYNC0_CYCLE - base)
                kw.update(activation=cu | act << 8, pulse_length_ns=pulse * 10, sync0_cycle=c0,
                          sync1_cycle=c1, start_time=start if bits == 64 else start & 0xFFFF_FFFF)
            out.append(DcStatus(s.position, s.station_address, s.name, s.dc_supported, bits, **kw))
        return out
