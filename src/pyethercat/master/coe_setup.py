"""CoE across a master's slaves: start-up commands and PDO mapping over CoE.

:class:`CoeSetup` is the master's CoE service (the CoE clients themselves are
made by :class:`~pyethercat.master.mailboxes.MailboxService`):

- start-up commands (:meth:`CoeSetup.add`, ESI ``InitCmd``) run at their
  transitions: as a :class:`~pyethercat.master.transitions.TransitionHook`
  it runs the commands of each slave's transition before the step is
  requested (PS: in PRE-OP before SAFE-OP), or after it for transitions into
  PRE-OP (IP), as the mailbox works only from PRE-OP on;
- process-data configuration takes the PDO assignment and mapping from CoE
  (0x1C12/0x1C13, 0x16xx/0x1Axx) for slaves that speak CoE, instead of the
  SII (as SOEM does): :meth:`CoeSetup.read_pdo_mappings`, run by
  ``configure()``; a slave whose assignment is empty at power-on (the master
  assigns) gets the SII's PDOs written to 0x1C12/0x1C13; a mapping written
  with ``slave.set_pdo_mapping`` (:meth:`CoeSetup.set_pdo_mapping`) is kept
  as PS start-up commands (re-applied at every PRE-OP -> SAFE-OP, as TwinCAT
  does) and used by the next configuration.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Mapping, Sequence

from pyethercat.errors import ConfigError, EtherCATError, MailboxError
from pyethercat.master.coe import (
    CoeClient,
    DTypeLike,
    PdoSpec,
    StartupCommand,
    pdo_assignment_writes,
    pdo_mapping_writes,
    resolve_dtype,
)
from pyethercat.master.config import MappedPdo, MappedPdoEntry, PdoDirection
from pyethercat.master.mailboxes import MailboxService
from pyethercat.master.slave_info import SlaveInfo
from pyethercat.master.transitions import Step
from pyethercat.wire.al import AlState, parse_transition
from pyethercat.wire.mailbox.datatypes import DataType, Value, encode_value
from pyethercat.wire.mailbox.objects import StandardObject, assignment_sm
from pyethercat.wire.sii.model import CoeDetails, SiiInfo, SyncManagerType

__all__ = ["CoeSetup", "pdo_names_from_sii", "process_data_sms"]

_log = logging.getLogger("pyethercat.coe")

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


def process_data_sms(sii: SiiInfo | None) -> dict[int, PdoDirection]:
    """Process-data sync managers of a slave by number, from its SII (SM2/SM3 by default)."""
    out: dict[int, PdoDirection] = {}
    if sii is not None:
        for n, sm in enumerate(sii.sync_managers):
            if sm.sm_type == SyncManagerType.OUTPUTS:
                out[n] = PdoDirection.OUTPUTS
            elif sm.sm_type == SyncManagerType.INPUTS:
                out[n] = PdoDirection.INPUTS
    return out or {2: PdoDirection.OUTPUTS, 3: PdoDirection.INPUTS}


class CoeSetup:
    """Start-up commands and CoE PDO mapping of a master's slaves (see the module text).

    ``mailboxes`` gives the CoE clients; ``bring_to_preop(slaves)`` takes
    slaves to PRE-OP (the master's state walk, with its hooks);
    ``mapping_changed()`` is called when a slave's PDO mapping changed (the
    next start configures process data anew).
    """

    def __init__(self, mailboxes: MailboxService, *,
                 bring_to_preop: Callable[[Sequence[SlaveInfo]], None],
                 mapping_changed: Callable[[], None] = lambda: None) -> None:
        self.mailboxes = mailboxes
        self._bring_to_preop = bring_to_preop
        self._mapping_changed = mapping_changed
        #: Every start-up command, in the order they run within a transition.
        self.startup_commands: list[StartupCommand] = []
        #: Read PDO mappings over CoE (instead of the SII) for slaves that speak CoE.
        self.pdo_config = True

    def client(self, slave: SlaveInfo) -> CoeClient:
        """The CoE client of a slave; :class:`ConfigError` when it has no mailbox."""
        client = self.mailboxes.client_of(slave.position, CoeClient)
        if client is None:
            raise ConfigError(f"{slave.describe()} has no mailbox: no CoE")
        return client

    # -- start-up commands ------------------------------------------------------------

    def add(self, slave: SlaveInfo, transition: str, index: int, subindex: int,
            data: bytes | Value, complete_access: bool = False, *,
            dtype: DTypeLike | None = None, comment: str = "",
            timeout: float | None = None) -> StartupCommand:
        """Have an SDO download done at a state transition (ESI ``InitCmd``).

        ``transition`` is ``"IP"``, ``"PS"``, ``"SO"``, ``"SP"``, ``"OS"``...;
        ``data`` raw bytes, or a value encoded as ``dtype``.
        """
        name = parse_transition(transition)
        if dtype is not None:
            raw = encode_value(resolve_dtype(dtype), data)
        elif isinstance(data, (bytes, bytearray)):
            raw = bytes(data)
        else:
            raise ConfigError(f"start-up command 0x{index:04X}:{subindex:02X}: give a dtype "
                              f"for {type(data).__name__} data")
        cmd = StartupCommand(slave.position, name, index, subindex, raw, complete_access,
                             comment, timeout)
        self.startup_commands.append(cmd)
        return cmd

    def remove(self, position: int | None = None,
               predicate: Callable[[StartupCommand], bool] | None = None) -> int:
        """Remove start-up commands (of one position, matching ``predicate``); returns how many."""
        keep = [c for c in self.startup_commands
                if not ((position is None or c.position == position)
                        and (predicate is None or predicate(c)))]
        removed = len(self.startup_commands) - len(keep)
        self.startup_commands[:] = keep
        return removed

    def _run_startup(self, step: Step, after: bool) -> None:
        cmds = self.startup_commands
        if not cmds:
            return
        for s in step.slaves:
            name = step.transition(s)
            if name is None:
                continue
            for c in cmds:
                if c.position == s.position and c.transition == name and c.runs_after == after:
                    c.run(self.client(s))

    def before_step(self, step: Step) -> None:
        """The start-up commands that run before the step is requested (PS, SO, ...)."""
        self._run_startup(step, after=False)

    def after_step(self, step: Step) -> None:
        """The start-up commands that run once the state is reached (IP, BP)."""
        self._run_startup(step, after=True)

    # -- PDO mapping over CoE -----------------------------------------------------------

    def read_pdo_mappings(self, slaves: Sequence[SlaveInfo], *,
                          bring_to_preop: bool = True) -> dict[int, dict[int, list[MappedPdo]]]:
        """Read the PDO assignment and mapping of CoE slaves; set ``slave.pdo_mapping``.

        Slaves whose SII announces CoE are brought to PRE-OP first (when
        ``bring_to_preop``; the mailbox works from there). A slave whose
        assignment is empty gets the SII's PDOs assigned when it announces PDO
        assignment (:meth:`_assign_sii_pdos`); one without the assignment
        objects, or that refuses them, keeps the SII's PDOs (``pdo_mapping``
        stays None). Returns the mappings read or written, by position.
        """
        chosen = [s for s in slaves if self._speaks_coe(s)]
        if not chosen:
            return {}
        low = [s for s in chosen if s.al_state in (AlState.INIT, AlState.BOOT, AlState.NONE)]
        if low and bring_to_preop:
            self._bring_to_preop(low)
        out: dict[int, dict[int, list[MappedPdo]]] = {}
        for s in chosen:
            try:
                client = self.client(s)
                names, pdo = _namers(s, client)
                mapping = client.read_pdos(process_data_sms(s.sii), names, pdo)
            except (MailboxError, EtherCATError) as exc:
                _log.info("%s: PDO mapping not read over CoE (%s); using the SII", s.describe(),
                          exc)
                continue
            if not any(p.bit_length for pdos in mapping.values() for p in pdos):
                if self._assign_sii_pdos(s, client) and s.pdo_mapping is not None:
                    out[s.position] = s.pdo_mapping
                continue
            s.pdo_mapping = mapping
            out[s.position] = mapping
        return out

    def _assign_sii_pdos(self, s: SlaveInfo, client: CoeClient) -> bool:
        """A slave whose 0x1C12/0x1C13 are empty gets the SII's PDOs assigned (PS commands).

        A device whose manual leaves the assignment to the master (0x1C12:00 =
        0 at power-on) checks its SM lengths against the PDOs assigned, none,
        and refuses SAFE-OP for SMs laid out from the SII (0x001D/0x001E). As
        the EtherCAT Slave Information's PDOs are the ones the ESI assigns by
        default (ETG.2010 TxPDO/RxPDO category, ``SyncM``), the master writes
        them to the assignment objects, as TwinCAT does from the ESI and IgH
        from its slave configuration (``ec_fsm_pdo``: assignment written when
        it differs and the device supports it). Only with the PDO-assignment
        bit of the SII's CoE details, in PRE-OP; False when nothing is written.
        """
        sii = s.sii
        if sii is None or not (sii.general is not None
                               and sii.general.coe_details & CoeDetails.PDO_ASSIGN):
            return False
        sms = process_data_sms(sii)
        spec: dict[int, list[PdoSpec]] = {}
        for p in list(sii.rx_pdos) + list(sii.tx_pdos):
            if p.sync_manager in sms and p.entries:
                spec.setdefault(p.sync_manager, []).append(p.index)
        if not spec or s.al_state != AlState.PREOP:
            return False
        try:
            write_pdo_mapping(client, s, spec, self.startup_commands)
        except (ConfigError, EtherCATError) as exc:
            _log.info("%s: the SII's PDOs not assigned over CoE (%s); using the SII",
                      s.describe(), exc)
            return False
        _log.info("%s: 0x1C12/0x1C13 empty: assigned the SII's PDOs (%s)", s.describe(),
                  "; ".join(f"SM{sm} " + ", ".join(f"0x{i:04X}" for i in pdos)
                            for sm, pdos in spec.items()))
        self._mapping_changed()
        return True

    def read_missing_mappings(self, slaves: Sequence[SlaveInfo]) -> None:
        """Before a configuration: the CoE mappings of CoE slaves not read yet."""
        if not self.pdo_config:
            return
        todo = [s for s in slaves if s.pdo_mapping is None and self._speaks_coe(s)]
        if todo:
            self.read_pdo_mappings(todo)

    def _speaks_coe(self, s: SlaveInfo) -> bool:
        return (s.has_coe and self.mailboxes.client_of(s.position, CoeClient) is not None)

    def set_pdo_mapping(self, slave: SlaveInfo, mapping: Mapping[int, Sequence[PdoSpec]]
                        ) -> dict[int, list[MappedPdo]]:
        """Write a PDO assignment (and mappings) to a slave in PRE-OP (``Slave.set_pdo_mapping``)."""
        client = self.mailboxes.client_of(slave.position, CoeClient)
        if client is None:
            raise ConfigError(f"{slave.describe()} has no mailbox: PDOs cannot be mapped over CoE")
        result = write_pdo_mapping(client, slave, mapping, self.startup_commands)
        self._mapping_changed()
        return result


def _namers(s: SlaveInfo, client: CoeClient) -> tuple[Callable[[int, int, int], tuple[str, int]],
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


def _has_sdo_info(s: SlaveInfo) -> bool:
    gen = s.sii.general if s.sii is not None else None
    return gen is not None and bool(gen.coe_details & CoeDetails.SDO_INFO)


def write_pdo_mapping(client: CoeClient, slave: SlaveInfo, mapping: Mapping[int, Sequence[PdoSpec]],
                      startup: list[StartupCommand] | None) -> dict[int, list[MappedPdo]]:
    """Write a PDO assignment (and mappings) to a slave in PRE-OP; see ``Slave.set_pdo_mapping``.

    The writes are also kept in ``startup`` as PS start-up commands.
    """
    if slave.al_state != AlState.PREOP:
        raise ConfigError(f"{slave.describe()} is in {slave.al_state_name}: PDO mapping is "
                          "written in PRE-OP")
    sms = process_data_sms(slave.sii)
    entry_name, pdo_name = _namers(slave, client)
    writes: list[tuple[int, int, bytes]] = []
    result: dict[int, list[MappedPdo]] = {}
    for key, items in mapping.items():
        sm = assignment_sm(key) if key >= StandardObject.SM_PDO_ASSIGNMENT_FIRST else key
        if sm not in sms:
            raise ConfigError(f"{slave.describe()}: SM{sm} carries no process data "
                              f"(process-data SMs: {', '.join(f'SM{n}' for n in sms)})")
        direction = sms[sm]
        indices: list[int] = []
        pdos: list[MappedPdo] = []
        for item in items:
            if isinstance(item, int):
                pdo_index = item
                entries = client.read_pdo_mapping(pdo_index)
            else:
                pdo_index, entries = item[0], list(item[1])
                writes += pdo_mapping_writes(pdo_index, entries)
            indices.append(pdo_index)
            made: list[MappedPdoEntry] = []
            for i, sub, bits in entries:
                name, dtype = entry_name(i, sub, pdo_index) if i else ("", 0)
                made.append(MappedPdoEntry(i, sub, bits, (dtype or _bits_type(bits)) if i else 0,
                                           name))
            pdos.append(MappedPdo(pdo_index, pdo_name(pdo_index), tuple(made), direction, sm))
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
    return result
