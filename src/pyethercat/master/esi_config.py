"""Master configuration from ESI files and ENI files.

Three jobs, all on a scanned :class:`~pyethercat.master.master.Master`:

* **Expected network** (:class:`EsiSlaveSpec`, :func:`expected_from_topology`):
  which device sits at which position. :func:`apply_esi_config` checks the
  scan against it (:class:`~pyethercat.errors.TopologyMismatchError` naming
  position, expected and found device) and then configures each slave as its
  ESI says: the PDO assignment (fixed and mandatory PDOs kept, the selectable
  ones chosen, ``Exclude`` honoured, via ``EsiDevice.pdo_layout``), written
  over CoE at PRE-OP -> SAFE-OP when the device supports PDO assignment; the
  CoE ``InitCmds`` as start-up commands at their transitions; the DC op mode
  kept in ``slave.dc_op_mode`` for the distributed-clock set-up.
* **ENI export** (:func:`eni_from_master`): the scanned and configured
  network as an :class:`~pyethercat.esi.eni.EniConfig` (``build_eni`` writes it).
* **ENI import** (:func:`start_from_eni`): scan without reading the SII,
  verify each slave's identity (SII words 8-0xD only), and configure it from
  the ENI; then ``master.configure()`` / ``master.start()`` as usual.

The master stands on ``pyethercat.esi`` only (never on the simulator).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from pyethercat.errors import ConfigError, EsiError, EtherCATError, TopologyMismatchError
from pyethercat.esi.eni import (
    EniCmd,
    EniConfig,
    EniDc,
    EniFrame,
    EniInitCmd,
    EniMailbox,
    EniPdo,
    EniPdoEntry,
    EniSlave,
    EniSm,
    EniVariable,
    eni_slave_device,
    eni_slave_from_esi,
)
from pyethercat.esi.model import ESI_TYPE_NAMES, EsiDcOpMode, EsiDevice, EsiFile, type_info
from pyethercat.esi.parse import load_esi
from pyethercat.esi.sii_from_esi import (
    FMMU_USAGES,
    MAILBOX_PROTOCOLS,
    PORT_LETTERS,
    SM_TYPES,
    esi_to_sii,
    pick_device,
)
from pyethercat.master import scan as scanning
from pyethercat.master.config import MappedPdo, MappedPdoEntry, PdoDirection
from pyethercat.master.cross import cross_links_from_eni
from pyethercat.master.scan import ExpectedSlave
from pyethercat.master.slave import Identity, Slave
from pyethercat.topology import parse_topology_text
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.objects import sm_pdo_assignment
from pyethercat.wire.sii import (
    GeneralFlags,
    SiiInfo,
    SiiPdoFlags,
    parse_sii,
)
from pyethercat.wire.sii.model import WORD_VENDOR_ID

if TYPE_CHECKING:
    from pyethercat.master.master import Master

__all__ = [
    "EsiSlaveSpec",
    "apply_esi_config",
    "eni_from_master",
    "esi_specs",
    "expected_from_topology",
    "start_from_eni",
]


@dataclass
class EsiSlaveSpec:
    """What is expected at one position and how to configure it.

    ``device`` is None for an entry known only by identity (an SII image in
    a topology file): it is checked at scan and configured from its SII.
    ``assignment`` ({sm: PDO indices}) chooses selectable PDOs; ``op_mode``
    names the DC op mode (default: the ESI's first).
    """

    identity: Identity
    device: EsiDevice | None = None
    name: str | None = None
    alias: int | None = None
    assignment: dict[int, tuple[int, ...]] | None = None
    op_mode: str | None = None

    @property
    def expected(self) -> ExpectedSlave:
        """The entry for the scan check."""
        return ExpectedSlave(self.identity, self.alias, self.name)


def esi_specs(
    devices: Sequence[tuple[str | Path, int | None, int | None]],
) -> list[EsiSlaveSpec]:
    """Specs from ``(ESI file, product code, revision)`` triples, one per position.

    Each file is parsed once, however many positions name it.
    """
    loaded: dict[Path, EsiFile] = {}
    return [_spec(_load_once(path, loaded), product, revision)
            for path, product, revision in devices]  # fmt: skip


def _load_once(path: str | Path, loaded: dict[Path, EsiFile]) -> EsiFile:
    """``load_esi(path)``, parsed once per resolved path for the ``loaded`` cache."""
    key = Path(path).resolve()
    esi = loaded.get(key)
    if esi is None:
        esi = loaded[key] = load_esi(path)
    return esi


def _spec(esi: EsiFile, product: int | None, revision: int | None) -> EsiSlaveSpec:
    dev = pick_device(esi, product, revision)
    return EsiSlaveSpec(Identity(esi.vendor.id, dev.product_code, dev.revision), dev, dev.type_name)


def expected_from_topology(path: str | Path) -> list[EsiSlaveSpec]:
    """The expected network of a topology file (the format of ``pyethercat.topology``).

    ``esi = ...`` entries give an ESI device; ``sii = ...`` entries an
    identity read from the image. ``device = "builtin:..."`` entries cannot
    be checked by the master (their identities live in the simulator) and
    raise :class:`ConfigError`. Only the ``[[slave]]`` order counts: the
    master sees slaves in ring order, which for a line is the file order.
    """
    p = Path(path)
    try:
        text = p.read_text("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read topology file: {exc}") from exc
    doc = parse_topology_text(text, str(p))
    if any(s.parent is not None for s in doc.slaves):
        raise ConfigError(f"{p}: tree topologies (parent/port) are not supported as an "
                          "expected network; list the slaves in ring order")  # fmt: skip
    out: list[EsiSlaveSpec] = []
    loaded: dict[Path, EsiFile] = {}  # a catalogue named by many slaves is parsed once
    for n, s in enumerate(doc.slaves):
        where = f"{p}: slave #{n + 1}"
        if s.kind == "esi":
            try:
                spec = _spec(_load_once(p.parent / s.source, loaded), s.product, s.revision)
            except EsiError as exc:
                raise ConfigError(f"{where}: {exc}") from exc
        elif s.kind == "sii":
            try:
                info = parse_sii((p.parent / s.source).read_bytes())
            except (OSError, EtherCATError) as exc:
                raise ConfigError(f"{where}: SII {s.source}: {exc}") from exc
            spec = EsiSlaveSpec(Identity(info.vendor_id, info.product_code, info.revision))
        else:
            raise ConfigError(f"{where}: {s.written_source!r}: only esi = ... and sii = ... "
                              "entries name an identity the master can check")  # fmt: skip
        spec.name = s.name
        spec.alias = s.alias
        out.append(spec)
    return out


# --- configuring from ESI ---------------------------------------------------------------


def _entry_type(data_type: str | None, bits: int) -> int:
    info = type_info(data_type) if data_type else None
    if info is not None:
        return int(info.code)
    return int({1: DataType.BOOLEAN, 8: DataType.UNSIGNED8, 16: DataType.UNSIGNED16,
                32: DataType.UNSIGNED32}.get(bits, 0))  # fmt: skip


def _mapping_from_eni(slave: EniSlave) -> dict[int, list[MappedPdo]]:
    """The master's PDO view ({sm: [MappedPdo]}) of an ENI slave's assignment."""
    by_index = {p.index: p for p in slave.pdos}
    out: dict[int, list[MappedPdo]] = {}
    for sm in slave.sms:
        if sm.kind not in ("Outputs", "Inputs"):
            continue
        direction = PdoDirection.OUTPUTS if sm.kind == "Outputs" else PdoDirection.INPUTS
        pdos = []
        for idx in sm.pdos:
            p = by_index.get(idx)
            if p is None:
                raise ConfigError(f"{slave.name}: SM{sm.index} assigns PDO 0x{idx:04X}, "
                                  "which is not described")  # fmt: skip
            entries = tuple(
                MappedPdoEntry(
                    e.index, e.subindex, e.bit_len, _entry_type(e.data_type, e.bit_len), e.name
                )  # fmt: skip
                for e in p.entries
            )
            pdos.append(MappedPdo(p.index, p.name, entries, direction, sm.index))
        out[sm.index] = pdos
    return out


def _configure_slave(master: Master, slave: Slave, eni: EniSlave, pdo_assign: bool) -> None:
    """PDO assignment, start-up commands and DC op mode of one slave from its ENI view."""
    slave.pdo_mapping = _mapping_from_eni(eni)
    # A configuration built earlier does not know the new mapping.
    master.pd.invalidate()
    master.remove_startup_commands(slave)
    if pdo_assign and eni.mailbox is not None:
        for sm, pdos in eni.assignment().items():
            obj = sm_pdo_assignment(sm)
            master.add_startup_command(slave, "PS", obj, 0, b"\x00", comment="ESI PDO assign")
            for k, idx in enumerate(pdos, start=1):
                master.add_startup_command(
                    slave, "PS", obj, k, struct.pack("<H", idx), comment="ESI PDO assign"
                )
            master.add_startup_command(
                slave, "PS", obj, 0, bytes([len(pdos)]), comment="ESI PDO assign"
            )
    if eni.mailbox is not None:
        for c in eni.mailbox.init_cmds:
            for t in c.transitions:
                master.add_startup_command(
                    slave, t, c.index, c.subindex, c.data, c.complete_access,
                    comment=c.comment,
                )  # fmt: skip
    slave.dc_op_mode = eni.dc


def apply_esi_config(
    master: Master, specs: Sequence[EsiSlaveSpec], *, check: bool = True
) -> list[EniSlave]:
    """Check the scanned slaves against ``specs`` and configure them from their ESI.

    Returns the ENI view of every configured slave (``None`` devices are left
    to their SII). Raises :class:`TopologyMismatchError` on a difference.
    """
    if check:
        scanning.check_expected(master.slaves, [s.expected for s in specs])
    out: list[EniSlave] = []
    for spec, slave in zip(specs, master.slaves, strict=False):
        if spec.device is None:
            continue
        eni = eni_slave_from_esi(
            spec.device, vendor_id=spec.identity.vendor_id, position=slave.position,
            station_address=slave.station_address, name=slave.name,
            assignment=spec.assignment, op_mode=spec.op_mode,
        )  # fmt: skip
        mbx = spec.device.mailbox
        pdo_assign = bool(mbx and mbx.coe and mbx.coe.pdo_assign)
        _configure_slave(master, slave, eni, pdo_assign)
        slave.dc_op_mode_esi = _op_mode(spec.device, spec.op_mode)
        out.append(eni)
    return out


def _op_mode(device: EsiDevice, name: str | None) -> EsiDcOpMode | None:
    if device.dc is None or not device.dc.op_modes:
        return None
    return device.dc.op_modes[0] if name is None else device.dc.op_mode(name)


# --- ENI export -------------------------------------------------------------------------


_SM_KIND: dict[int, str] = {v: k for k, v in SM_TYPES.items()}
_FMMU_NAMES: dict[int, str] = {v: k for k, v in FMMU_USAGES.items()}


def _kind(sm_type: int) -> str:
    return _SM_KIND.get(int(sm_type), "Unused")


def _protocols(mask: int) -> tuple[str, ...]:
    return tuple(n for n, bit in MAILBOX_PROTOCOLS.items() if mask & bit)


def _dtype_name(code: int) -> str | None:
    return ESI_TYPE_NAMES.get(code)


def _eni_slave_of(master: Master, slave: Slave) -> EniSlave:
    sii: SiiInfo | None = slave.sii
    if sii is None:
        raise ConfigError(f"{slave.describe()}: no SII: cannot describe it in an ENI")
    cfg = master.process_data.slaves.get(slave.position) if master.process_data else None
    assigned: dict[int, int] = {}
    sms: list[EniSm] = []
    sm_cfg = {s.index: s for s in cfg.sync_managers} if cfg is not None else {}
    for n, s in enumerate(sii.sync_managers):
        c = sm_cfg.get(n)
        pdos = tuple(p.index for p in c.pdos) if c is not None else ()
        for i in pdos:
            assigned[i] = n
        sms.append(EniSm(index=n, kind=_kind(s.sm_type), start=s.start,  # type: ignore[arg-type]
                         size=c.length if c is not None else s.length, control=s.control,
                         enable=s.enabled, pdos=pdos))  # fmt: skip
    mapping: Mapping[int, Sequence[MappedPdo]] = slave.pdo_mapping or {}
    pdos_seen: dict[int, EniPdo] = {}

    def add(index: int, direction: str, name: str, entries: tuple[EniPdoEntry, ...],
            fixed: bool, mandatory: bool) -> None:  # fmt: skip
        pdos_seen[index] = EniPdo(direction=direction, index=index, name=name,  # type: ignore[arg-type]
                                  sm=assigned.get(index), fixed=fixed, mandatory=mandatory,
                                  entries=entries)  # fmt: skip

    for direction, pdo_list in (("rx", sii.rx_pdos), ("tx", sii.tx_pdos)):
        for p in pdo_list:
            add(p.index, direction, sii.pdo_name(p) or "", tuple(
                EniPdoEntry(index=e.index, subindex=e.subindex, bit_len=e.bit_length,
                            name=sii.pdo_name(e) or "", data_type=_dtype_name(e.data_type))
                for e in p.entries), bool(p.flags & SiiPdoFlags.FIXED_CONTENT),
                bool(p.flags & SiiPdoFlags.MANDATORY))  # fmt: skip
    for mapped in mapping.values():
        for q in mapped:
            known = pdos_seen.get(q.index)  # keep the SII's Fixed/Mandatory flags
            add(q.index, "rx" if q.direction is PdoDirection.OUTPUTS else "tx", q.name, tuple(
                EniPdoEntry(index=e.index, subindex=e.subindex, bit_len=e.bit_length,
                            name=e.name, data_type=_dtype_name(e.data_type))
                for e in q.entries), bool(known and known.fixed), bool(known and known.mandatory))  # fmt: skip
    # PDOs the configuration assigns that neither SII nor CoE described (none expected).
    mbx = None
    if slave.mailbox is not None and slave.mailbox.rx_size and slave.mailbox.tx_size:
        m = slave.mailbox
        cmds = tuple(
            EniInitCmd(transitions=(c.transition,), index=c.index, subindex=c.subindex,
                       data=c.data, comment=c.comment, complete_access=c.complete_access)
            for c in master.startup_commands if c.position == slave.position
        )  # fmt: skip
        gen = sii.general
        mbx = EniMailbox(out_start=m.rx_offset, out_size=m.rx_size, in_start=m.tx_offset,
                         in_size=m.tx_size, protocols=_protocols(m.protocols),
                         data_link_layer=bool(gen and gen.flags & GeneralFlags.MBOX_DATA_LINK_LAYER),
                         init_cmds=cmds)  # fmt: skip
    dc = slave.dc_op_mode
    if dc is None and sii.dc_modes:
        mode = sii.dc_modes[0]
        dc = EniDc(op_mode=sii.string(mode.name_index) or "", assign_activate=mode.assign_activate,
                   cycle_time0=mode.cycle_time_sync0, shift_time0=mode.shift_time_sync0,
                   shift_time1=mode.shift_time_sync1)  # fmt: skip
    ports = sii.general.ports if sii.general is not None else (0, 0, 0, 0)
    physics = "".join(PORT_LETTERS.get(p, " ") for p in ports).rstrip() or None
    return EniSlave(
        name=slave.name, position=slave.position, station_address=slave.station_address,
        vendor_id=slave.identity.vendor_id, product_code=slave.identity.product_code,
        revision=slave.identity.revision or 0, serial=slave.identity.serial,
        alias=slave.alias or None, physics=physics, sms=tuple(sms),
        fmmus=tuple(_FMMU_NAMES.get(u, "Unused") for u in sii.fmmus),
        rx_pdos=tuple(p for p in pdos_seen.values() if p.direction == "rx"),
        tx_pdos=tuple(p for p in pdos_seen.values() if p.direction == "tx"),
        mailbox=mbx, dc=dc,
        send_bit_start=(cfg.output_bit_offset if cfg and cfg.output_bit_offset >= 0 else None),
        send_bit_length=cfg.output_bits if cfg else 0,
        recv_bit_start=(cfg.input_bit_offset if cfg and cfg.input_bit_offset >= 0 else None),
        recv_bit_length=cfg.input_bits if cfg else 0,
    )  # fmt: skip


def eni_from_master(master: Master, *, cycle_time_us: int | None = None) -> EniConfig:
    """The scanned (and, when configured, process-data configured) network as an ENI."""
    if not master.slaves:
        raise ConfigError("no slaves: scan first")
    slaves = tuple(_eni_slave_of(master, s) for s in master.slaves)
    frames: list[EniFrame] = []
    inputs: list[EniVariable] = []
    outputs: list[EniVariable] = []
    in_bytes = out_bytes = 0
    pd = master.process_data
    if pd is not None:
        for g in pd.groups:
            cmds = tuple(
                EniCmd(states=("SAFEOP", "OP"), cmd=int(d.command), addr=d.logical_address,
                       data_length=d.length, cnt=d.expected_wkc, input_offs=d.offset,
                       output_offs=d.offset, comment=g.name)
                for d in g.datagrams
            )  # fmt: skip
            if cmds:
                frames.append(EniFrame(cmds=cmds))
            for v in g.variables:
                var = EniVariable(name=f"{v.position}.{v.qualified_name}",
                                  data_type=_dtype_name(v.data_type), bit_size=v.bit_length,
                                  bit_offs=v.bit_offset)  # fmt: skip
                (outputs if v.direction is PdoDirection.OUTPUTS else inputs).append(var)
            in_bytes += g.input_bytes
            out_bytes += g.output_bytes
    return EniConfig(
        slaves=slaves, cycle_time_us=cycle_time_us, frames=tuple(frames),
        input_bytes=in_bytes, output_bytes=out_bytes, inputs=tuple(inputs),
        outputs=tuple(outputs),
    )  # fmt: skip


# --- ENI import -------------------------------------------------------------------------


@dataclass
class EniStart:
    """What :func:`start_from_eni` did: the slaves, and per slave the ENI entry used."""

    slaves: list[Slave]
    configured: list[EniSlave] = field(default_factory=list)


def start_from_eni(master: Master, eni: EniConfig) -> EniStart:
    """Scan without reading the SII, verify identities, configure every slave from ``eni``.

    Each slave's identity (vendor, product, revision) is read from SII words
    8-0xD in one batched read and compared with the ENI entry at its position
    (:class:`TopologyMismatchError` on a difference or a different count).
    The slave then gets an SII model built from the ENI (names, mailbox, SMs,
    FMMUs, PDOs), the ENI's PDO assignment and its CoE InitCmds as start-up
    commands; ``master.configure()`` and ``master.start()`` follow as usual.
    """
    slaves = master.scan(read_sii=False)
    if len(slaves) != len(eni.slaves):
        raise TopologyMismatchError(
            f"the ENI describes {len(eni.slaves)} slaves, the segment has {len(slaves)}"
        )
    heads = scanning.read_sii_batch(
        master.scheduler, [scanning.SiiAccess.of(s) for s in slaves], length=0x20
    )
    for s, e, head in zip(slaves, eni.slaves, heads, strict=True):
        if isinstance(head, Exception) or len(head) < 0x1C:
            raise TopologyMismatchError(f"position {s.position}: identity not readable ({head!r})")
        vendor, product, revision = struct.unpack_from("<III", head, 2 * WORD_VENDOR_ID)
        found = Identity(vendor, product, revision)
        want = Identity(e.vendor_id, e.product_code, e.revision)
        if not want.matches(found):
            raise TopologyMismatchError(f"position {s.position}: expected {want} ({e.name}), "
                                        f"found {found}")  # fmt: skip
    out = EniStart(slaves=slaves)
    for s, e in zip(slaves, eni.slaves, strict=True):
        device = eni_slave_device(e)
        image = esi_to_sii(device, vendor_id=e.vendor_id, serial=e.serial or 0).image
        scanning.apply_sii(s, image)
        if e.alias is not None and not s.alias:
            s.alias = e.alias
        s.name = e.name or s.name
        out.configured.append(e)
    master.mailboxes.attach(slaves)
    for s, e in zip(slaves, eni.slaves, strict=True):
        # The ENI's InitCmds already hold any PDO assignment writes.
        _configure_slave(master, s, e, pdo_assign=False)
    # Outputs of one slave laid over another's inputs: cross traffic.
    master.pd.cross = cross_links_from_eni(eni.slaves)
    return out
