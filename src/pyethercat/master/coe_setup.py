"""Mailboxes and CoE on a ``Master``: clients per slave, start-up commands, CoE PDO mapping.

``CoeMasterMixin`` gives :class:`~pyethercat.master.master.Master` what the
mailbox layer needs across slaves:

- after a scan every slave with a mailbox gets ``slave.mbx`` (its
  :class:`~pyethercat.master.mailbox.Mailbox`) and ``slave.coe`` (a
  :class:`~pyethercat.master.coe.CoeClient`); all mailboxes share one
  :class:`~pyethercat.master.mailbox.MailboxPoller`, so concurrent
  transactions poll in shared frames;
- while cyclic exchange runs, each mailbox takes its SM1 status from the
  byte the cyclic frame reads into the group image (:class:`CyclicMailboxStatus`,
  the FMMU ``master.config`` maps): no poll frames;
- emergencies of every slave also land in ``master.emergencies`` and the
  callbacks given to :meth:`CoeMasterMixin.on_emergency`;
- start-up commands (:meth:`CoeMasterMixin.add_startup_command`) run at their
  transitions: the mixin's ``_prepare_step``/``_finish_step`` are the hooks the
  state machine calls before requesting and after reaching each state;
- process-data configuration takes the PDO assignment and mapping from CoE
  (0x1C12/0x1C13, 0x16xx/0x1Axx) for slaves that speak CoE, instead of the
  SII (as SOEM does): :meth:`CoeMasterMixin.read_coe_pdo_mappings`, called by
  ``configure()``; a mapping written with ``slave.set_pdo_mapping`` is stored
  as PS start-up commands (re-applied at every PRE-OP -> SAFE-OP, as TwinCAT
  does) and used by the next configuration.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from pyethercat.errors import ConfigError, EtherCATError, MailboxError
from pyethercat.master import states
from pyethercat.master.coe import (
    CoeClient,
    DropOldestQueue,
    DTypeLike,
    EmergencyEvent,
    StartupCommand,
    parse_transition,
    pdo_assignment_writes,
    pdo_mapping_writes,
    resolve_dtype,
)
from pyethercat.master.config import Direction, Pdo, PdoEntry
from pyethercat.master.mailbox import DEFAULT_MAILBOX_TIMEOUT, Mailbox, MailboxPoller
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.datatypes import DataType, Value, encode_value
from pyethercat.wire.mailbox.objects import (
    StandardObject,
    assignment_sm,
)
from pyethercat.wire.registers import AL_STATE_MASK
from pyethercat.wire.sii.model import CoeDetails, MailboxProtocol, SiiInfo, SyncManagerType

if TYPE_CHECKING:
    from pyethercat.master.config import ProcessDataConfig
    from pyethercat.master.cyclic import CyclicRunner
    from pyethercat.master.scheduler import Scheduler

__all__ = ["CoeMasterMixin", "CyclicMailboxStatus", "PdoSpec", "pdo_names_from_sii"]

_log = logging.getLogger("pyethercat.coe")

_STATE_LETTER = {AlState.INIT: "I", AlState.PREOP: "P", AlState.SAFEOP: "S", AlState.OP: "O",
                 AlState.BOOT: "B"}

#: What ``set_pdo_mapping`` takes per sync manager: PDO indices (keep their mapping) or
#: (PDO index, entries) pairs whose mapping is rewritten; entries are (index, sub, bits).
PdoSpec = int | tuple[int, Sequence[tuple[int, int, int]]]


def pdo_names_from_sii(sii: SiiInfo | None) -> tuple[Callable[[int, int, int], tuple[str, int]],
                                                    Callable[[int], str]]:
    """Name/type look-ups for CoE-read PDOs from what the SII says about the same objects."""
    entries: dict[tuple[int, int], tuple[str, int]] = {}
    pdos: dict[int, str] = {}
    if sii is not None:
        for p in list(sii.rx_pdos) + list(sii.tx_pdos):
            pdos[p.index] = sii.pdo_name(p) or ""
            for e in p.entries:
                entries[(e.index, e.subindex)] = (sii.pdo_name(e) or "", e.data_type)

    def entry(index: int, sub: int, _pdo: int) -> tuple[str, int]:
        return entries.get((index, sub), ("", 0))

    def pdo(index: int) -> str:
        return pdos.get(index, "")

    return entry, pdo


def _bits_type(bits: int) -> int:
    return {1: DataType.BOOLEAN, 8: DataType.UNSIGNED8, 16: DataType.UNSIGNED16,
            32: DataType.UNSIGNED32, 64: DataType.UNSIGNED64}.get(bits, 0)


def process_data_sms(sii: SiiInfo | None) -> dict[int, Direction]:
    """Process-data sync managers of a slave by number, from its SII (SM2/SM3 by default)."""
    out: dict[int, Direction] = {}
    if sii is not None:
        for n, sm in enumerate(sii.sync_managers):
            if sm.sm_type == SyncManagerType.OUTPUTS:
                out[n] = Direction.OUTPUTS
            elif sm.sm_type == SyncManagerType.INPUTS:
                out[n] = Direction.INPUTS
    return out or {2: Direction.OUTPUTS, 3: Direction.INPUTS}


class CyclicMailboxStatus:
    """``Mailbox.status_source`` of one slave: its SM1 status byte in the running cycle's image.

    The group's cyclic frame reads SM1's status register (0x080D) into the
    image through the FMMU ``master.config`` maps. A call waits until two
    more exchanges of the slave's group came back (so the second one began
    after the call: the byte is newer than the caller's last SM1 read) and
    returns the byte. None when no cyclic exchange runs, the slave has no
    status byte, nothing came within ``budget`` or the group's working
    counter was off (the mailbox then polls with a frame).
    """

    def __init__(self, master: CoeMasterMixin, position: int) -> None:
        self._master = master
        self.position = position
        self._where: tuple[CyclicRunner, str, int] | None = None

    def _locate(self) -> tuple[CyclicRunner, str, int] | None:
        runner = self._master.runner
        if runner is None or not runner.running:
            return None
        where = self._where
        if where is not None and where[0] is runner:
            return where
        sc = runner.config.slaves.get(self.position)
        if sc is None or sc.mailbox_status_offset < 0:
            return None
        if not any(g.name == sc.group for g in runner.groups):
            return None  # the runner does not exchange this slave's group
        self._where = (runner, sc.group, sc.mailbox_status_offset)
        return self._where

    def __call__(self, budget: float) -> int | None:
        where = self._locate()
        if where is None:
            return None
        runner, group, at = where
        # Two more exchanges: the second began after this call, so its byte is newer
        # than the caller's last SM1 read. (False from the loop thread itself.)
        if budget > 0 and not runner.wait_exchanges(group, 2, budget):
            return None
        status = runner.group_status(group)
        return status.image[at] if status.wkc_ok else None


class CoeMasterMixin:
    """Mailbox and CoE methods of the master (see the module text)."""

    scheduler: Scheduler
    slaves: list[Slave]
    process_data: ProcessDataConfig | None = None
    runner: CyclicRunner | None = None
    _lock: threading.RLock
    #: Read PDO mappings over CoE (instead of the SII) for slaves that speak CoE.
    coe_pdo_config: bool = True
    #: Default time one mailbox transaction may take.
    mailbox_timeout: float = DEFAULT_MAILBOX_TIMEOUT

    def _sleep(self, seconds: float) -> None: ...  # provided by Master

    # -- attaching -------------------------------------------------------------------------

    def _coe_state(self) -> dict[str, Any]:
        st: dict[str, Any] | None = self.__dict__.get("_coe_mixin_state")
        if st is None:
            st = {"poller": MailboxPoller(self.scheduler), "startup": [],
                  "callbacks": [], "queue": DropOldestQueue(1024), "from": {}}
            self.__dict__["_coe_mixin_state"] = st
        return st

    @property
    def startup_commands(self) -> list[StartupCommand]:
        """Every start-up command, in the order they run within a transition."""
        cmds: list[StartupCommand] = self._coe_state()["startup"]
        return cmds

    @property
    def emergencies(self) -> DropOldestQueue[EmergencyEvent]:
        """Emergencies of every slave (oldest dropped when 1024 are waiting)."""
        q: DropOldestQueue[EmergencyEvent] = self._coe_state()["queue"]
        return q

    def _attach_mailboxes(self, slaves: Sequence[Slave]) -> None:
        """Give every slave with a mailbox its transport and CoE client (after a scan)."""
        st = self._coe_state()
        for s in slaves:
            info = s.mailbox
            s.mbx = None
            s.coe = None
            s.pdo_mapping = None
            s._mapping_changed = self._mapping_changed
            s._startup = self.startup_commands
            if info is None or not s.has_mailbox:
                continue
            box = Mailbox(self.scheduler, s.station_address, s.describe(),
                          rx_offset=info.rx_offset, rx_size=info.rx_size,
                          tx_offset=info.tx_offset, tx_size=info.tx_size, poller=st["poller"],
                          timeout=self.mailbox_timeout)
            box.status_source = CyclicMailboxStatus(self, s.position)
            s.mbx = box
            client = CoeClient(box, position=s.position, emergencies=st["queue"])
            client.on_emergency(self._emergency)
            s.coe = client

    def _emergency(self, event: EmergencyEvent) -> None:
        # The client filed it in the master's queue already: only the callbacks here.
        st = self._coe_state()
        for cb in list(st["callbacks"]):
            try:
                cb(event)
            except Exception:  # noqa: BLE001 - never let a callback break the mailbox
                _log.exception("emergency callback failed")

    def on_emergency(self, callback: Callable[[EmergencyEvent], None]) -> None:
        """Call ``callback(event)`` for every emergency of every slave."""
        self._coe_state()["callbacks"].append(callback)

    def coe(self, slave: Slave | int) -> CoeClient:
        """The CoE client of a slave; :class:`ConfigError` when it has no mailbox."""
        s = slave if isinstance(slave, Slave) else self.slaves[slave]
        client = s.coe
        if client is None:
            raise ConfigError(f"{s.describe()} has no mailbox: no CoE")
        return client

    def poll_mailboxes(self) -> int:
        """Fetch whatever the slaves posted unasked (emergencies); returns how many came."""
        got = 0
        for s in self.slaves:
            if s.mbx is not None and s.mbx.poll():
                got += 1
        return got

    # -- start-up commands ------------------------------------------------------------------

    def add_startup_command(self, slave: Slave | int, transition: str, index: int,
                            subindex: int, data: bytes | Value, complete_access: bool = False,
                            *, dtype: DTypeLike | None = None, comment: str = "",
                            timeout: float | None = None) -> StartupCommand:
        """Have an SDO download done at a state transition (ESI ``InitCmd``).

        ``transition`` is ``"IP"``, ``"PS"``, ``"SO"``, ``"SP"``, ``"OS"``...;
        ``data`` raw bytes, or a value encoded as ``dtype``.
        """
        s = slave if isinstance(slave, Slave) else self.slaves[slave]
        name = parse_transition(transition)
        if dtype is not None:
            raw = encode_value(resolve_dtype(dtype), data)
        elif isinstance(data, (bytes, bytearray)):
            raw = bytes(data)
        else:
            raise ConfigError(f"start-up command 0x{index:04X}:{subindex:02X}: give a dtype "
                              f"for {type(data).__name__} data")
        cmd = StartupCommand(s.position, name, index, subindex, raw, complete_access, comment,
                             timeout)
        self.startup_commands.append(cmd)
        return cmd

    def remove_startup_commands(self, slave: Slave | int | None = None,
                                predicate: Callable[[StartupCommand], bool] | None = None,
                                ) -> int:
        """Remove start-up commands (of one slave, matching ``predicate``); returns how many."""
        pos = None if slave is None else (slave.position if isinstance(slave, Slave) else slave)
        keep = [c for c in self.startup_commands
                if not ((pos is None or c.position == pos)
                        and (predicate is None or predicate(c)))]
        removed = len(self.startup_commands) - len(keep)
        self.startup_commands[:] = keep
        return removed

    def _run_startup(self, group: Sequence[Slave], transition_of: Callable[[Slave], str | None],
                     after: bool) -> None:
        cmds = self.startup_commands
        if not cmds:
            return
        for s in group:
            name = transition_of(s)
            if name is None:
                continue
            for c in cmds:
                if c.position == s.position and c.transition == name and c.runs_after == after:
                    c.run(self.coe(s))

    def _prepare_step(self, scheduler: Scheduler, step: AlState, group: Sequence[Slave]) -> None:
        """Before requesting ``step``: mailbox SMs, then the start-up commands of the transition."""
        states.setup_mailboxes(scheduler, step, group)
        frm: dict[int, AlState] = self._coe_state()["from"]
        for s in group:
            frm[s.position] = s.al_state
            if step == AlState.INIT and s.mbx is not None:
                s.mbx.reset()
        self._run_startup(group, lambda s: _transition(frm.get(s.position), step), after=False)

    def _finish_step(self, scheduler: Scheduler, step: AlState, group: Sequence[Slave]) -> None:
        """After reaching ``step``: the start-up commands that run after it (IP, BP)."""
        frm: dict[int, AlState] = self._coe_state()["from"]
        for s in group:
            if s.mbx is None:
                continue
            if step == AlState.INIT:
                s.mbx.reset()
            elif step == AlState.PREOP and frm.get(s.position) in (AlState.INIT, AlState.BOOT):
                s.mbx.drain()  # whatever an earlier session left in SM1
        self._run_startup(group, lambda s: _transition(frm.get(s.position), step), after=True)

    # -- PDO mapping over CoE ------------------------------------------------------------------

    def read_coe_pdo_mappings(self, slaves: Sequence[Slave] | None = None, *,
                              bring_to_preop: bool = True) -> dict[int, dict[int, list[Pdo]]]:
        """Read the PDO assignment and mapping of CoE slaves; set ``slave.pdo_mapping``.

        Slaves whose SII announces CoE are brought to PRE-OP first (when
        ``bring_to_preop``; the mailbox works from there). A slave without
        the assignment objects, or whose CoE mapping is empty, keeps the SII's
        PDOs (``pdo_mapping`` stays None). Returns the mappings read, by position.
        """
        chosen = [s for s in (self.slaves if slaves is None else slaves) if _speaks_coe(s)]
        if not chosen:
            return {}
        low = [s for s in chosen if s.al_state in (AlState.INIT, AlState.BOOT, AlState.NONE)]
        if low and bring_to_preop:
            self.set_state(AlState.PREOP, low)  # type: ignore[attr-defined]
        out: dict[int, dict[int, list[Pdo]]] = {}
        for s in chosen:
            try:
                mapping = self._read_mapping(s)
            except (MailboxError, EtherCATError) as exc:
                _log.info("%s: PDO mapping not read over CoE (%s); using the SII", s.describe(),
                          exc)
                continue
            if not any(p.bit_length for pdos in mapping.values() for p in pdos):
                continue
            s.pdo_mapping = mapping
            out[s.position] = mapping
        return out

    def _read_mapping(self, s: Slave) -> dict[int, list[Pdo]]:
        client = self.coe(s)
        names, pdo = _namers(s, client)
        return client.read_pdos(process_data_sms(s.sii), names, pdo)

    def _mapping_changed(self, slave: Slave) -> None:
        """A slave's PDO mapping changed: the next start configures process data anew."""
        self.process_data = None

    def _state_hooks(self) -> dict[str, Any]:
        """``prepare``/``finish`` for ``states.set_state``: mailbox SMs and start-up commands."""
        return {"prepare": self._prepare_step, "finish": self._finish_step}

    def _before_configure(self) -> None:
        """Hook for ``configure()``: CoE mappings of slaves not read yet."""
        if not self.coe_pdo_config:
            return
        todo = [s for s in self.slaves if _speaks_coe(s) and s.pdo_mapping is None
                and s.coe is not None]
        if todo:
            self.read_coe_pdo_mappings(todo)


def _transition(frm: AlState | None, to: AlState) -> str | None:
    if frm is None or frm == to:
        return None
    a, b = _STATE_LETTER.get(AlState(int(frm) & AL_STATE_MASK)), _STATE_LETTER.get(to)
    if a is None or b is None:
        return None
    return a + b


def _speaks_coe(s: Slave) -> bool:
    return (s.coe is not None and s.mailbox is not None
            and bool(s.mailbox.protocols & MailboxProtocol.COE))


def _namers(s: Slave, client: CoeClient) -> tuple[Callable[[int, int, int], tuple[str, int]],
                                                  Callable[[int], str]]:
    """Entry and PDO name look-ups: the SII first, then the slave's SDO information."""
    entry, pdo = pdo_names_from_sii(s.sii)
    info = _has_sdo_info(s)

    def names(index: int, sub: int, pdo_index: int) -> tuple[str, int]:
        name, dtype = entry(index, sub, pdo_index)
        if (not name or not dtype) and info:
            try:
                d = client.entry_description(index, sub, value_info=0)
                name, dtype = name or d.description, dtype or d.data_type
            except EtherCATError:
                pass
        return name, dtype

    def pdo_name(index: int) -> str:
        name = pdo(index)
        if not name and info:
            with contextlib.suppress(EtherCATError):
                name = client.object_description(index).name
        return name

    return names, pdo_name


def _has_sdo_info(s: Slave) -> bool:
    gen = s.sii.general if s.sii is not None else None
    return gen is not None and bool(gen.coe_details & CoeDetails.SDO_INFO)


def set_pdo_mapping(master_hook: Callable[[Slave], None] | None, slave: Slave,
                    mapping: Mapping[int, Sequence[PdoSpec]],
                    startup: list[StartupCommand] | None) -> dict[int, list[Pdo]]:
    """Write a PDO assignment (and mappings) to a slave in PRE-OP; see ``Slave.set_pdo_mapping``."""
    client = slave.coe
    if client is None:
        raise ConfigError(f"{slave.describe()} has no mailbox: PDOs cannot be mapped over CoE")
    if slave.al_state != AlState.PREOP:
        raise ConfigError(f"{slave.describe()} is in {slave.al_state_name}: PDO mapping is "
                          "written in PRE-OP")
    sms = process_data_sms(slave.sii)
    entry_name, pdo_name = _namers(slave, client)
    writes: list[tuple[int, int, bytes]] = []
    result: dict[int, list[Pdo]] = {}
    for key, items in mapping.items():
        sm = assignment_sm(key) if key >= StandardObject.SM_PDO_ASSIGNMENT_FIRST else key
        if sm not in sms:
            raise ConfigError(f"{slave.describe()}: SM{sm} carries no process data "
                              f"(process-data SMs: {', '.join(f'SM{n}' for n in sms)})")
        direction = sms[sm]
        indices: list[int] = []
        pdos: list[Pdo] = []
        for item in items:
            if isinstance(item, int):
                pdo_index = item
                entries = client.read_pdo_mapping(pdo_index)
            else:
                pdo_index, entries = item[0], list(item[1])
                writes += pdo_mapping_writes(pdo_index, entries)
            indices.append(pdo_index)
            made: list[PdoEntry] = []
            for i, sub, bits in entries:
                name, dtype = entry_name(i, sub, pdo_index) if i else ("", 0)
                made.append(PdoEntry(i, sub, bits, (dtype or _bits_type(bits)) if i else 0,
                                     name))
            pdos.append(Pdo(pdo_index, pdo_name(pdo_index), tuple(made), direction, sm))
        writes += pdo_assignment_writes(sm, indices)
        result[sm] = pdos
    for index, sub, data in writes:
        client.download(index, sub, data)
    if startup is not None:
        startup[:] = [c for c in startup if not (c.position == slave.position
                                                and c.comment == "PDO mapping")]
        startup += [StartupCommand(slave.position, "PS", i, sub, d, comment="PDO mapping")
                    for i, sub, d in writes]
    if slave.pdo_mapping is None:
        # Not configured yet: the sync managers this call leaves alone keep what the
        # slave has assigned now (the layout would otherwise lose them, and the
        # slave refuses SAFE-OP for an SM length that does not match).
        rest = {sm: d for sm, d in sms.items() if sm not in result}
        try:
            merged = client.read_pdos(rest, entry_name, pdo_name) if rest else {}
        except EtherCATError as exc:
            _log.info("%s: PDO mapping of %s not read over CoE (%s)", slave.describe(),
                      ", ".join(f"SM{n}" for n in rest), exc)
            merged = {}
    else:
        merged = dict(slave.pdo_mapping)
    merged.update(result)
    slave.pdo_mapping = merged
    if master_hook is not None:
        master_hook(slave)
    return result
