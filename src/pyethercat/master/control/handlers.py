"""What a master does for each control request.

:func:`dispatch` runs a request against a :class:`MasterContext`: a running
master serving its control socket, or a short-lived master the command line
opened itself (``direct``: it scans on first need, without resetting the
slaves). Both paths run the same handler, so a command shows the same
output either way. Handlers use only the master's thread-safe public calls:
a running cyclic loop keeps its timing, the requests travel as acyclic
datagrams beside it.

A new operation registers its handler with :func:`handler`.
"""

from __future__ import annotations

import dataclasses
import os
import struct
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar

from pyethercat.errors import ConfigError, EtherCATError, SdoAbort
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master import diag
from pyethercat.master.bootstrap import BootMaster, bootstrap_update, foe_client
from pyethercat.master.cia402 import DriveMaster
from pyethercat.master.coe import CoeClient, StartupCommand
from pyethercat.master.config import ProcessDataConfig
from pyethercat.master.control import messages as msg
from pyethercat.master.control.protocol import PROTOCOL_VERSION, ControlRequest
from pyethercat.master.control.snapshot import snapshot
from pyethercat.master.cyclic import CyclicRunner
from pyethercat.master.hotswap import HotSwap
from pyethercat.master.listing import alias_positions
from pyethercat.master.process import ProcessData
from pyethercat.master.scan import Progress
from pyethercat.master.sii_write import SiiWriteReport
from pyethercat.master.slave import Slave
from pyethercat.master.soe import SoeClient
from pyethercat.master.states import AlStatusReading
from pyethercat.master.telemetry import TelemetryMaster, telemetry_of
from pyethercat.version import __version__
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import MAX_PAYLOAD, OVERHEAD, Command, Datagram
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.registers import RX_ERROR_COUNTER, STATION_ALIAS, FmmuType

__all__ = ["MasterContext", "ServedMaster", "handler", "dispatch"]

Q = TypeVar("Q", bound=ControlRequest)
_HANDLERS: dict[type[ControlRequest], Callable[[MasterContext, Any], Any]] = {}
#: Timeouts in a row after which ``sdo_list`` stops asking the slave.
_SDO_LIST_TIMEOUTS = 3
#: Rate windows of ``master`` (seconds), as IgH's 10 s / 1 min / 5 min.
RATE_WINDOWS = (10.0, 60.0, 300.0)


class ServedMaster(TelemetryMaster, DriveMaster, BootMaster, Protocol):
    """What the control socket's handlers use of a master
    (:class:`~pyethercat.master.master.Master` is one; the handlers pass it on to the
    telemetry, drive groups and the bootstrap update, hence the bases).

    A protocol rather than the class, so that the control layer does not import
    ``master.master``, which starts the control server.
    """

    pd: ProcessData
    hotswap: HotSwap
    topology_consistent: bool

    @property
    def startup_commands(self) -> list[StartupCommand]: ...
    def scan(self, *, progress: Progress | None = ..., reset: bool = ...) -> list[Slave]: ...
    def count_slaves(self) -> int: ...
    def set_state(self, state: AlState | int | str, slaves: Sequence[Slave | int] | None = ...,
                  timeout: float = ..., *, configure: bool = ..., wait: bool = ...) -> None: ...
    def read_states(self, slaves: Sequence[Slave | int] | None = ...
                    ) -> list[AlStatusReading]: ...
    def acknowledge_errors(self, slaves: Sequence[Slave | int] | None = ...) -> list[Slave]: ...
    def read(self, slave: Slave | int, address: int, size: int) -> bytes: ...
    def read_u16(self, slave: Slave | int, address: int) -> int: ...
    def write(self, slave: Slave | int, address: int, data: bytes) -> None: ...
    def read_many(self, address: int, size: int, slaves: Sequence[Slave | int] | None = ...
                  ) -> list[diag.MultiReadResult]: ...
    def clear_error_counters(self, slaves: Sequence[Slave | int] | None = ...) -> None: ...
    def sii_read(self, slave: Slave | int) -> bytes: ...
    def sii_write(self, slave: Slave | int, image: bytes, *, only_changed: bool = ...,
                  force: bool = ..., backup: Path | None = ...) -> SiiWriteReport: ...
    def set_alias(self, slave: Slave | int, alias: int, *, backup: Path | None = ...,
                  force: bool = ...) -> SiiWriteReport: ...
    def configure(self) -> ProcessDataConfig: ...


class MasterContext:
    """A master and what serving it needs: its link name and how to find its slaves.

    ``direct``: a master the client opened for one command; it scans (without
    reset) when a request first needs the slaves. Otherwise the master's own
    scan is used as it is.
    """

    def __init__(self, master: ServedMaster, link: str, *, direct: bool = False,
                 progress: Progress | None = None) -> None:
        self.master = master
        self.link = link
        self.direct = direct
        self.progress = progress
        self.started = time.time()
        #: Called with the progress of FoE transfers this context serves (the command
        #: line's bar, when it serves its own requests).
        self.transfer_progress: Callable[[Any], None] | None = None
        self._t0 = time.monotonic()
        self._scanned = False
        #: (monotonic time, frames sent, received, lost), sampled for the rates.
        self.samples: deque[tuple[float, int, int, int]] = deque(maxlen=4096)
        self.sample()

    # -- slaves ---------------------------------------------------------------------------

    @property
    def scanned(self) -> bool:
        """Whether the slaves are known (a running master's own scan, or ours)."""
        return self._scanned or not self.direct

    def mark_scanned(self) -> None:
        self._scanned = True

    def slaves(self) -> list[Slave]:
        """The scanned slaves (a direct master scans now, once)."""
        if self.direct and not self._scanned:
            self.master.scan(reset=False, progress=self.progress)
            self._scanned = True
        return self.master.slaves

    def slave(self, position: int) -> Slave:
        slaves = self.slaves()
        if not 0 <= position < len(slaves):
            raise ConfigError(_no_slave(position, len(slaves)))
        return slaves[position]

    def select(self, positions: list[int] | None) -> list[Slave]:
        return self.slaves() if positions is None else [self.slave(p) for p in positions]

    def position(self, position: int) -> Slave | int:
        """A slave to address: the scanned object, or (direct, unscanned) a checked position."""
        if self.scanned:
            return self.slave(position)
        count = self.master.count_slaves()
        if not 0 <= position < count:
            raise ConfigError(_no_slave(position, count))
        return position

    def mailbox_slave(self, position: int, what: str, *, boot: bool = False) -> Slave:
        """The slave at ``position`` with a usable mailbox (``what``: the protocol wanted).

        Direct (no running master), a slave in INIT (or in BOOT, unless ``boot`` says
        the protocol works there, as FoE does) is taken to PRE-OP first: it has no
        mailbox before (the sync managers come from its SII). A running master keeps
        its slaves where they are.
        """
        s = self.slave(position)
        if not s.has_mailbox:
            raise ConfigError(f"{s.describe()} has no mailbox: no {what}")
        if s.al_state in ((AlState.INIT, AlState.NONE) if boot
                          else (AlState.INIT, AlState.BOOT, AlState.NONE)):
            if not self.direct:
                raise ConfigError(f"{s.describe()} is in {s.al_state_name}: no mailbox there "
                                  "(the running master keeps it in that state)")
            self.master.set_state(AlState.PREOP, [s])
        return s

    def coe(self, position: int, what: str = "CoE") -> CoeClient:
        """The CoE client of the slave at ``position`` (see :meth:`mailbox_slave`)."""
        s = self.mailbox_slave(position, what)
        if s.coe is None:
            raise ConfigError(f"{s.describe()} has no mailbox: no {what}")
        return s.coe

    @property
    def runner(self) -> CyclicRunner | None:
        runner = getattr(self.master, "runner", None)
        return runner if runner is not None and runner.running else None

    # -- statistics -----------------------------------------------------------------------

    @property
    def uptime(self) -> float:
        return time.monotonic() - self._t0

    def sample(self) -> None:
        st = self.master.scheduler.stats
        self.samples.append((time.monotonic(), st.frames_sent, st.frames_received,
                             st.frames_lost))

    def rates(self) -> msg.RateSet:
        self.sample()
        now, sent, recv, lost = self.samples[-1]
        out: list[list[float]] = [[], [], []]
        for window in RATE_WINDOWS:
            base = self.samples[0]
            for s in self.samples:
                if s[0] >= now - window:
                    base = s
                    break
            span = now - base[0]
            if span < 1.0:
                span = 0.0  # too short to say (a direct master lives for one command)
            for k, (a, b) in enumerate(((sent, base[1]), (recv, base[2]), (lost, base[3]))):
                out[k].append((a - b) / span if span > 0 else 0.0)
        return msg.RateSet(tx=out[0], rx=out[1], lost=out[2])


def _no_slave(position: int, count: int) -> str:
    return f"no slave at position {position}: the segment has {count} slave{'s' if count != 1 else ''}"


def handler(request_type: type[Q]) -> Callable[[Callable[[MasterContext, Q], Any]],
                                              Callable[[MasterContext, Q], Any]]:
    """Decorator: ``fn(ctx, request) -> reply`` serves ``request_type``."""

    def register(fn: Callable[[MasterContext, Q], Any]) -> Callable[[MasterContext, Q], Any]:
        _HANDLERS[request_type] = fn
        return fn

    return register


def dispatch(ctx: MasterContext, req: ControlRequest) -> Any:
    """Run ``req`` against the master; returns its reply (errors propagate)."""
    fn = _HANDLERS.get(type(req))
    if fn is None:
        raise ConfigError(f"this master does not serve {req.op!r}")
    return fn(ctx, req)


# --- who is there ----------------------------------------------------------------------


@handler(msg.Hello)
def _hello(ctx: MasterContext, req: msg.Hello) -> msg.HelloReply:
    return msg.HelloReply(__version__, PROTOCOL_VERSION, os.getpid(), ctx.link,
                          len(ctx.master.slaves), ctx.runner is not None, ctx.started)


@handler(msg.Roster)
def _roster(ctx: MasterContext, req: msg.Roster) -> msg.RosterReply:
    m = ctx.master
    if ctx.scanned:
        return msg.RosterReply([s.alias for s in ctx.slaves()])
    count = m.count_slaves()
    aliases: list[int] = []
    per_frame = MAX_PAYLOAD // (OVERHEAD + 2)
    for first in range(0, count, per_frame):
        replies = m.transact([Datagram.positional(Command.APRD, p, STATION_ALIAS, b"\0\0")
                              for p in range(first, min(count, first + per_frame))])
        aliases += [struct.unpack("<H", r.data)[0] if r.wkc == 1 else 0 for r in replies]
    return msg.RosterReply(aliases)


@handler(msg.ListSlaves)
def _slaves(ctx: MasterContext, req: msg.ListSlaves) -> msg.SlaveList:
    fresh = not ctx.scanned
    slaves = ctx.slaves()
    if slaves and not fresh:
        ctx.master.read_states()
    return msg.SlaveList([snapshot(s) for s in slaves], ctx.master.topology_consistent)


# --- states ------------------------------------------------------------------------------


def _state_list(ctx: MasterContext, slaves: list[Slave]) -> msg.StateList:
    readings = ctx.master.read_states(slaves) if slaves else []
    return msg.StateList([msg.SlaveState(s.position, r.station_address, r.state, r.error,
                                         r.code if r.error else 0, r.answered)
                          for s, r in zip(slaves, readings, strict=True)])


@handler(msg.ReadStates)
def _states(ctx: MasterContext, req: msg.ReadStates) -> msg.StateList:
    return _state_list(ctx, ctx.select(req.positions))


@handler(msg.RequestState)
def _request_state(ctx: MasterContext, req: msg.RequestState) -> msg.StateList:
    try:
        target = AlState(req.state)
    except ValueError:
        raise ConfigError(f"unknown AL state 0x{req.state:02X}") from None
    chosen = ctx.select(req.positions)
    if chosen:
        ctx.master.set_state(target, chosen, timeout=req.timeout, configure=True, wait=req.wait)
    return _state_list(ctx, chosen)


@handler(msg.AckErrors)
def _ack(ctx: MasterContext, req: msg.AckErrors) -> msg.Positions:
    done = ctx.master.acknowledge_errors(ctx.select(req.positions))
    return msg.Positions([s.position for s in done])


# --- registers and SII -------------------------------------------------------------------


@handler(msg.RegRead)
def _reg_read(ctx: MasterContext, req: msg.RegRead) -> msg.Data:
    return msg.Data(ctx.master.read(ctx.position(req.position), req.address, req.size))


@handler(msg.RegWrite)
def _reg_write(ctx: MasterContext, req: msg.RegWrite) -> msg.Done:
    ctx.master.write(ctx.position(req.position), req.address, req.data)
    return msg.Done()


@handler(msg.SiiRead)
def _sii_read(ctx: MasterContext, req: msg.SiiRead) -> msg.Data:
    return msg.Data(ctx.master.sii_read(ctx.position(req.position)))


def _sii_result(ctx: MasterContext, where: Slave | int, report: SiiWriteReport) -> msg.SiiWriteResult:
    alias = ctx.master.read_u16(where, STATION_ALIAS)
    return msg.SiiWriteResult(report.words, list(report.written), report.checksum,
                              report.checksum_fixed,
                              str(report.backup) if report.backup is not None else None,
                              list(report.identity_changes), report.retries, alias)


@handler(msg.SiiWrite)
def _sii_write(ctx: MasterContext, req: msg.SiiWrite) -> msg.SiiWriteResult:
    where = ctx.position(req.position)
    report = ctx.master.sii_write(where, req.image, force=req.force,
                                  only_changed=req.only_changed,
                                  backup=Path(req.backup) if req.backup else None)
    return _sii_result(ctx, where, report)


@handler(msg.SetAlias)
def _alias(ctx: MasterContext, req: msg.SetAlias) -> msg.SiiWriteResult:
    where = ctx.position(req.position)
    report = ctx.master.set_alias(where, req.alias, force=req.force,
                                  backup=Path(req.backup) if req.backup else None)
    return _sii_result(ctx, where, report)


# --- CoE ------------------------------------------------------------------------------------


@handler(msg.SdoUpload)
def _upload(ctx: MasterContext, req: msg.SdoUpload) -> msg.Data:
    client = ctx.coe(req.position)
    return msg.Data(client.upload(req.index, req.subindex, complete_access=req.complete_access))


@handler(msg.SdoDownload)
def _download(ctx: MasterContext, req: msg.SdoDownload) -> msg.Done:
    client = ctx.coe(req.position)
    client.download(req.index, req.subindex, req.data, complete_access=req.complete_access)
    return msg.Done()


@handler(msg.SdoEntryType)
def _entry_type(ctx: MasterContext, req: msg.SdoEntryType) -> msg.EntryType:
    client = ctx.coe(req.position)
    try:
        desc = client.entry_description(req.index, req.subindex, value_info=0)
        return msg.EntryType(int(DataType(desc.data_type)))
    except (SdoAbort, ValueError):
        return msg.EntryType(None)
    except Exception:  # noqa: BLE001 - no SDO information service: type unknown
        return msg.EntryType(None)


@handler(msg.SdoList)
def _sdo_list(ctx: MasterContext, req: msg.SdoList) -> msg.SdoObjects:
    client = ctx.coe(req.position)
    out: list[msg.SdoObjectInfo] = []
    # An object or entry the slave does not describe in time is reported with its
    # error and the browse goes on (a busy slave, a lost answer); a slave that
    # stopped answering altogether ends it after a few time-outs in a row, not one
    # time-out per object.
    timeouts = 0

    def failed(exc: Exception) -> str:
        nonlocal timeouts
        timeouts = timeouts + 1 if isinstance(exc, EcTimeoutError) else 0
        return str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)

    for index in client.od:
        if timeouts >= _SDO_LIST_TIMEOUTS:
            out.append(msg.SdoObjectInfo(index, "", [], "not described: the slave stopped "
                                         "answering"))
            continue
        try:
            obj = client.od[index]
        except (KeyError, EtherCATError) as exc:
            out.append(msg.SdoObjectInfo(index, "", [], failed(exc)))
            continue
        timeouts = 0
        entries: list[msg.SdoEntryInfo] = []
        errors: list[str] = []
        for sub in obj.subindices if req.entries else ():
            if timeouts >= _SDO_LIST_TIMEOUTS:
                errors.append("not all entries described: the slave stopped answering")
                break
            try:
                e = obj.entry(sub)
            except EtherCATError as exc:
                errors.append(f"0x{index:04X}:{sub:02X} not described: {failed(exc)}")
                continue
            timeouts = 0
            if e is not None:
                entries.append(msg.SdoEntryInfo(e.subindex, e.access_text, e.data_type,
                                                e.bit_length, e.name))
        out.append(msg.SdoObjectInfo(index, obj.name, entries, "; ".join(errors) or None))
    return msg.SdoObjects(out)


# --- diagnostics ----------------------------------------------------------------------------


@handler(msg.ErrorCounters)
def _counters(ctx: MasterContext, req: msg.ErrorCounters) -> msg.CounterList:
    slaves = ctx.slaves()
    results = ctx.master.read_many(RX_ERROR_COUNTER, diag.ERROR_COUNTERS_SIZE, slaves)
    if req.clear:
        ctx.master.clear_error_counters(slaves)
    return msg.CounterList([msg.CounterItem(s.position, s.station_address, r.ok, r.data)
                            for s, r in zip(slaves, results, strict=True)])


@handler(msg.MasterInfoRequest)
def _master(ctx: MasterContext, req: msg.MasterInfoRequest) -> msg.MasterInfo:
    m = ctx.master
    st = m.scheduler.stats
    src = m.scheduler.src
    runner = ctx.runner
    info = msg.MasterInfo(
        link=ctx.link, mac=":".join(f"{b:02x}" for b in src), pid=os.getpid(),
        running=not ctx.direct, slaves=len(m.slaves) if m.slaves else m.count_slaves(),
        frames_sent=st.frames_sent, frames_received=st.frames_received,
        frames_lost=st.frames_lost, timeouts=st.timeouts, retries=st.retries, stale=st.stale,
        rates=ctx.rates(), uptime=ctx.uptime)
    if runner is not None:
        cs = runner.stats
        info = dataclasses.replace(info, cycling=True, cycle_us=cs.period_ns / 1000,
                                   cycles=cs.cycles, wkc_errors=cs.wkc_errors,
                                   cycle_lost_frames=cs.lost_frames, late_cycles=cs.late)
    return info


@handler(msg.Domains)
def _domains(ctx: MasterContext, req: msg.Domains) -> msg.DomainList:
    m = ctx.master
    cfg = m.process_data
    runner = ctx.runner
    if cfg is None:
        return msg.DomainList([], runner is not None)
    live = {g.name: g for g in runner.groups} if runner is not None else {}
    rel = alias_positions(m.slaves)
    out: list[msg.DomainInfo] = []
    for n, group in enumerate(cfg.groups):
        image = m.images.get(group.name)
        size = len(image.buffer) if image is not None else 0
        g = live.get(group.name)
        fmmus: list[msg.DomainFmmu] = []
        for sc in group.slaves:
            alias, pos = rel.get(sc.position, (0, sc.position))
            sm_of = {sm.start: sm.index for sm in sc.sync_managers}
            for f in sc.fmmus:
                fmmus.append(msg.DomainFmmu(sc.position, alias, pos,
                                            sm_of.get(f.physical_start, -1),
                                            bool(f.fmmu_type & FmmuType.WRITE),
                                            f.logical_start, f.length))
        data = bytes(image.buffer) if req.data and image is not None else None
        out.append(msg.DomainInfo(n, group.name, group.logical_base, size,
                                  g.total_wkc if g is not None else 0,
                                  g.expected_wkc if g is not None else sum(
                                      d.expected_wkc for d in group.datagrams),
                                  g.exchanges if g is not None else 0, fmmus, data))
    return msg.DomainList(out, runner is not None)


@handler(msg.GetConfig)
def _config(ctx: MasterContext, req: msg.GetConfig) -> msg.ConfigReply:
    m = ctx.master
    if m.process_data is None and req.compute:
        ctx.slaves()
        if not m.slaves:
            raise ConfigError("no slaves found")
        m.configure()
    startup = [msg.StartupSdo(c.position, c.transition, c.index, c.subindex, bytes(c.data),
                              c.complete_access) for c in m.startup_commands]
    states = _state_list(ctx, list(m.slaves)).items if m.slaves else []
    return msg.ConfigReply(m.process_data, startup, states)


@handler(msg.Rescan)
def _rescan(ctx: MasterContext, req: msg.Rescan) -> msg.RescanReply:
    if ctx.runner is not None:
        raise ConfigError("the master is exchanging process data: a rescan would reassign "
                          "the slaves under it; stop the cyclic loop first")
    ctx.master.scan(reset=False, progress=ctx.progress)
    ctx.mark_scanned()
    return msg.RescanReply(len(ctx.master.slaves))


# --- EoE ------------------------------------------------------------------------------------


def _eoe_slave(ctx: MasterContext, position: int) -> Any:
    from pyethercat.master.eoe import eoe_client

    s = ctx.slave(position)
    client = eoe_client(s)
    if s.al_state in (AlState.INIT, AlState.BOOT, AlState.NONE):
        if not ctx.direct:
            raise ConfigError(f"{s.describe()} is in {s.al_state_name}: no mailbox there")
        ctx.master.set_state(AlState.PREOP, [s])
    return client


@handler(msg.EoeList)
def _eoe_list(ctx: MasterContext, req: msg.EoeList) -> msg.EoeHandlers:
    from pyethercat.master.eoe import eoe_clients
    from pyethercat.master.eoe_switch import running_eoe

    run = running_eoe(ctx.master)
    clients = run.clients if run is not None else eoe_clients(ctx.slaves())
    names = run.bridge.names if run is not None else {}
    seconds = time.monotonic() - run.started if run is not None else 0.0
    rows = []
    for pos, c in sorted(clients.items()):
        st = c.stats
        rows.append(msg.EoeHandler(
            names.get(pos, "-"), pos, "up" if run is not None else "down", st.rx.bytes,
            int(st.rx.bytes / seconds) if seconds > 0 else 0, st.tx.bytes,
            int(st.tx.bytes / seconds) if seconds > 0 else 0,
            f"{c.sender.queued}/{c.sender.queue_limit}", st.rx.frames, st.tx.frames,
            st.rx.dropped + st.tx.dropped))
    return msg.EoeHandlers(rows)


@handler(msg.EoeGetIp)
def _eoe_get_ip(ctx: MasterContext, req: msg.EoeGetIp) -> msg.EoeIp:
    p = _eoe_slave(ctx, req.position).get_ip()
    return msg.EoeIp(p.mac, None if p.ip is None else str(p.ip),
                     None if p.subnet is None else str(p.subnet),
                     None if p.gateway is None else str(p.gateway),
                     None if p.dns_server is None else str(p.dns_server), p.dns_name)


@handler(msg.EoeSetIp)
def _eoe_set_ip(ctx: MasterContext, req: msg.EoeSetIp) -> msg.Done:
    import ipaddress

    from pyethercat.wire.mailbox.eoe import EoeIpParameters

    q = req.params

    def addr(text: str | None) -> ipaddress.IPv4Address | None:
        return None if text is None else ipaddress.IPv4Address(text)

    params = EoeIpParameters(q.mac, addr(q.ip), addr(q.subnet), addr(q.gateway),
                             addr(q.dns_server), q.dns_name)
    _eoe_slave(ctx, req.position).set_ip(params)
    return msg.Done()


# --- FoE and SoE ----------------------------------------------------------------------------


@handler(msg.FoeRead)
def _foe_read(ctx: MasterContext, req: msg.FoeRead) -> msg.Data:
    s = ctx.mailbox_slave(req.position, "FoE", boot=True)
    data = foe_client(ctx.master.scheduler, s).read(
        req.name, password=req.password, max_size=req.max_size,
        progress=ctx.transfer_progress)
    telemetry_of(ctx.master).record_foe(req.position, req.name, len(data), "read")
    return msg.Data(data)


@handler(msg.FoeWrite)
def _foe_write(ctx: MasterContext, req: msg.FoeWrite) -> msg.Done:
    if req.boot:
        bootstrap_update(ctx.master, ctx.slave(req.position), req.data, name=req.name,
                         password=req.password, progress=ctx.transfer_progress)
        return msg.Done()
    s = ctx.mailbox_slave(req.position, "FoE", boot=True)
    foe_client(ctx.master.scheduler, s).write(req.name, req.data, password=req.password,
                                              progress=ctx.transfer_progress)
    telemetry_of(ctx.master).record_foe(req.position, req.name, len(req.data), "write")
    return msg.Done()


def _soe(ctx: MasterContext, position: int) -> SoeClient:
    return ctx.mailbox_slave(position, "SoE").client(SoeClient)


@handler(msg.SoeRead)
def _soe_read(ctx: MasterContext, req: msg.SoeRead) -> msg.Data:
    return msg.Data(_soe(ctx, req.position).read(req.idn, elements=req.elements,
                                                 drive=req.drive))


@handler(msg.SoeWrite)
def _soe_write(ctx: MasterContext, req: msg.SoeWrite) -> msg.Done:
    _soe(ctx, req.position).write(req.idn, req.data, elements=req.elements, drive=req.drive)
    return msg.Done()
