"""ENI (EtherCAT Network Information): the configured network as XML, both ways.

A configuration tool (TwinCAT, EC-Engineer, ...) exports the network it
configured as an ENI file; a master that reads it can start without reading
every slave's EEPROM. :class:`EniConfig` is the typed model of what pyethercat
writes and reads; :func:`build_eni` turns it into XML, :func:`parse_eni` back
(round trip: ``parse_eni(build_eni(c)) == c``).

What is written, following the ETG.2100 element names TwinCAT uses::

    EtherCATConfig/Config
      Master/Info (Name, Destination, Source, EtherType)
      Slave*  Info (Name, PhysAddr, AutoIncAddr, Physics, VendorId, ProductCode,
                    RevisionNo, SerialNo, Alias)
              ProcessData (Send/Recv BitStart+BitLength, Sm0..Sm7 with Type,
                    StartAddress, ControlByte, DefaultSize, Enable and the
                    assigned Pdo indices, RxPdo/TxPdo with entries, Fmmu*)
              Mailbox (DataLinkLayer; Send/Recv Start+Length(+PollTime);
                    Protocol*; CoE/InitCmds/InitCmd: Transition, Index,
                    SubIndex, Data, Comment, CompleteAccess)
              DC (OpMode, AssignActivate, CycleTime0/1, ShiftTime0/1)
      Cyclic (CycleTime, Frame*/Cmd*: State, Cmd, Addr, DataLength, Cnt,
              InputOffs, OutputOffs)
      ProcessImage (Inputs/Outputs: ByteSize, Variable*: Name, DataType,
              BitSize, BitOffs)

Left out, because pyethercat's master does its own bring-up: the
register-level ``InitCmds`` TwinCAT lists per slave (station address, SM and
FMMU writes, DC set-up). ``Fmmu`` under ``ProcessData`` and ``OpMode`` /
``AssignActivate`` under ``DC`` are not TwinCAT element names: they keep what
those register commands would carry. Files from other tools are read where
they use these elements; missing optional parts are simply absent.

Pure: bytes in, typed objects out (``load_eni`` only reads the file).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

from lxml import etree

from pyethercat.esi.model import (
    EsiCoe,
    EsiDc,
    EsiDcOpMode,
    EsiDevice,
    EsiFmmu,
    EsiInitCmd,
    EsiMailbox,
    EsiPdo,
    EsiPdoEntry,
    EsiSm,
    Text,
)
from pyethercat.esi.xmlread import (
    DEFAULT_MAX_BYTES,
    XmlReader,
    _kids,
    _local,
    _read_bounded,
    _safe_xml_root,
    _text,
    parse_hex_bytes,
    parse_int,
)
from pyethercat.wire.frame import ETHERTYPE_ETHERCAT

__all__ = [
    "EniCmd",
    "EniConfig",
    "EniDc",
    "EniFrame",
    "EniInitCmd",
    "EniMailbox",
    "EniPdo",
    "EniPdoEntry",
    "EniSlave",
    "EniSm",
    "EniVariable",
    "build_eni",
    "eni_slave_device",
    "eni_slave_from_esi",
    "load_eni",
    "parse_eni",
]

SmKindName = Literal["MBoxOut", "MBoxIn", "Outputs", "Inputs", "Unused"]


# --- model ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class EniPdoEntry:
    """One mapped object of a PDO (index 0: a gap)."""

    index: int
    subindex: int
    bit_len: int
    name: str = ""
    data_type: str | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class EniPdo:
    """An RxPdo (``rx``, outputs) or TxPdo (``tx``, inputs); ``sm`` when assigned."""

    direction: Literal["rx", "tx"]
    index: int
    name: str = ""
    sm: int | None = None
    fixed: bool = False
    mandatory: bool = False
    entries: tuple[EniPdoEntry, ...] = ()

    @property
    def bit_size(self) -> int:
        """Sum of the entries' bits."""
        return sum(e.bit_len for e in self.entries)


@dataclass(frozen=True, slots=True, kw_only=True)
class EniSm:
    """A sync manager as configured: registers and the PDOs assigned to it."""

    index: int
    kind: SmKindName
    start: int
    size: int
    control: int
    enable: bool = True
    pdos: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class EniInitCmd:
    """A CoE start-up command (SDO download at ``transitions``)."""

    transitions: tuple[str, ...]
    index: int
    subindex: int
    data: bytes
    comment: str = ""
    complete_access: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class EniMailbox:
    """Mailbox sync managers and protocols of a slave."""

    out_start: int
    out_size: int
    in_start: int
    in_size: int
    protocols: tuple[str, ...] = ()
    data_link_layer: bool = False
    poll_time_ms: int | None = None
    init_cmds: tuple[EniInitCmd, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class EniDc:
    """The DC op mode chosen for a slave (times in ns; 0 cycle = the bus cycle)."""

    op_mode: str = ""
    assign_activate: int = 0
    cycle_time0: int = 0
    shift_time0: int = 0
    cycle_time1: int = 0
    shift_time1: int = 0


@dataclass(frozen=True, slots=True, kw_only=True)
class EniSlave:
    """One configured slave."""

    name: str
    position: int  # auto-increment position, 0 = next to the master
    station_address: int
    vendor_id: int
    product_code: int
    revision: int
    serial: int | None = None
    alias: int | None = None
    physics: str | None = None
    sms: tuple[EniSm, ...] = ()
    fmmus: tuple[str, ...] = ()  # usage per FMMU: Outputs, Inputs, MBoxState, Unused
    rx_pdos: tuple[EniPdo, ...] = ()
    tx_pdos: tuple[EniPdo, ...] = ()
    mailbox: EniMailbox | None = None
    dc: EniDc | None = None
    send_bit_start: int | None = None  # outputs in the process image
    send_bit_length: int = 0
    recv_bit_start: int | None = None  # inputs in the process image
    recv_bit_length: int = 0

    @property
    def pdos(self) -> tuple[EniPdo, ...]:
        """All PDOs, RxPDOs first."""
        return self.rx_pdos + self.tx_pdos

    def assignment(self) -> dict[int, tuple[int, ...]]:
        """PDO assignment per process-data SM ({2: (0x1600,), 3: (0x1A00,)})."""
        return {s.index: s.pdos for s in self.sms if s.kind in ("Outputs", "Inputs")}


@dataclass(frozen=True, slots=True, kw_only=True)
class EniCmd:
    """One datagram of a cyclic frame."""

    states: tuple[str, ...]
    cmd: int  # datagram command code (LRW = 12)
    addr: int  # logical address (or ADP << 16 | ADO for device commands)
    data_length: int
    cnt: int  # expected working counter
    input_offs: int | None = None
    output_offs: int | None = None
    comment: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class EniFrame:
    """One cyclic frame: its datagrams in order."""

    cmds: tuple[EniCmd, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class EniVariable:
    """A named variable of the process image (bit offset from the image start)."""

    name: str
    data_type: str | None
    bit_size: int
    bit_offs: int


@dataclass(frozen=True, slots=True, kw_only=True)
class EniConfig:
    """A whole ENI file."""

    master_name: str = "pyethercat"
    destination: bytes = b"\xff" * 6
    source: bytes = b"\x00" * 6
    slaves: tuple[EniSlave, ...] = ()
    cycle_time_us: int | None = None
    frames: tuple[EniFrame, ...] = ()
    input_bytes: int = 0
    output_bytes: int = 0
    inputs: tuple[EniVariable, ...] = ()
    outputs: tuple[EniVariable, ...] = ()


# --- ESI -> ENI slave, ENI slave -> device model -------------------------------------------


def eni_slave_from_esi(
    device: EsiDevice,
    *,
    vendor_id: int,
    position: int,
    station_address: int,
    name: str | None = None,
    assignment: dict[int, tuple[int, ...]] | None = None,
    op_mode: str | None = None,
    init_cmds: tuple[EniInitCmd, ...] | None = None,
) -> EniSlave:
    """The ENI view of an ESI device configured with a PDO ``assignment`` / DC ``op_mode``.

    ``assignment`` ({sm: pdo indices}) defaults to the ESI default (or the op
    mode's). ``init_cmds`` default to the ESI's CoE InitCmds.
    """
    layout = device.pdo_layout(op_mode=op_mode, assignment=assignment)
    assigned = {s.sm.index: s.pdo_indices for s in layout.sms}
    sms: list[EniSm] = []
    for s in device.sms:
        kind: SmKindName = s.kind if s.kind is not None else "Unused"
        lay = layout.for_sm(s.index)
        size = s.default_size or 0
        if lay is not None and not s.is_mailbox:
            size = lay.byte_size
        sms.append(
            EniSm(
                index=s.index,
                kind=kind,
                start=s.start_address or 0,
                size=size,
                control=s.control_byte or 0,
                enable=s.enable,
                pdos=assigned.get(s.index, ()),
            )
        )
    pdo_sm = {i: sm for sm, idx in assigned.items() for i in idx}

    def conv(p: EsiPdo) -> EniPdo:
        return EniPdo(
            direction=p.direction,
            index=p.index,
            name=p.name.pick(),
            sm=pdo_sm.get(p.index),
            fixed=p.fixed,
            mandatory=p.mandatory,
            entries=tuple(
                EniPdoEntry(
                    index=e.index,
                    subindex=e.subindex,
                    bit_len=e.bit_len,
                    name=e.name.pick(),
                    data_type=e.data_type,
                )
                for e in p.entries
            ),
        )

    mbx: EniMailbox | None = None
    sizes = device.mailbox_sizes
    if device.mailbox is not None and sizes is not None:
        out_sm, in_sm = device.mbox_out, device.mbox_in
        assert out_sm is not None and in_sm is not None
        coe = device.mailbox.coe
        cmds = init_cmds
        if cmds is None:
            cmds = tuple(
                EniInitCmd(
                    transitions=c.transitions,
                    index=c.index,
                    subindex=c.subindex,
                    data=c.data,
                    comment=c.comment or "",
                    complete_access=c.complete_access,
                )
                for c in (coe.init_cmds if coe is not None else ())
            )
        mbx = EniMailbox(
            out_start=out_sm.start_address or 0,
            out_size=sizes[0],
            in_start=in_sm.start_address or 0,
            in_size=sizes[1],
            protocols=device.mailbox.protocols,
            data_link_layer=device.mailbox.data_link_layer,
            init_cmds=cmds,
        )
    dc: EniDc | None = None
    if device.dc is not None and device.dc.op_modes:
        mode = device.dc.op_modes[0] if op_mode is None else device.dc.op_mode(op_mode)
        if mode is not None:
            dc = EniDc(
                op_mode=mode.name,
                assign_activate=mode.assign_activate,
                cycle_time0=mode.cycle_time_sync0 or 0,
                shift_time0=mode.shift_time_sync0 or 0,
                cycle_time1=mode.cycle_time_sync1 or 0,
                shift_time1=mode.shift_time_sync1 or 0,
            )
    return EniSlave(
        name=name or device.type_name,
        position=position,
        station_address=station_address,
        vendor_id=vendor_id,
        product_code=device.product_code,
        revision=device.revision,
        physics=device.physics,
        sms=tuple(sms),
        fmmus=tuple(f.name for f in device.fmmus),
        rx_pdos=tuple(conv(p) for p in device.rx_pdos),
        tx_pdos=tuple(conv(p) for p in device.tx_pdos),
        mailbox=mbx,
        dc=dc,
    )


def eni_slave_device(slave: EniSlave) -> EsiDevice:
    """An ESI device model carrying what the ENI says about ``slave``.

    Its default PDO assignment is the ENI's; :func:`esi_to_sii` turns it into
    the SII model the master configures from when it starts from an ENI.
    """
    sms = tuple(
        EsiSm(
            index=s.index,
            name=s.kind if s.kind != "Unused" else "",
            start_address=s.start,
            control_byte=s.control,
            default_size=s.size,
            enable=s.enable,
        )
        for s in slave.sms
    )

    def conv(p: EniPdo) -> EsiPdo:
        return EsiPdo(
            direction=p.direction,
            index=p.index,
            name=Text(((None, p.name),)) if p.name else Text(),
            sm=p.sm,
            fixed=p.fixed,
            # Only assigned PDOs may be mandatory here, so that the device
            # model's default assignment is exactly the ENI's.
            mandatory=p.mandatory and p.sm is not None,
            entries=tuple(
                EsiPdoEntry(
                    index=e.index,
                    subindex=e.subindex,
                    bit_len=e.bit_len,
                    name=Text(((None, e.name),)) if e.name else Text(),
                    data_type=e.data_type,
                )
                for e in p.entries
            ),
        )

    mailbox = None
    if slave.mailbox is not None:
        m = slave.mailbox
        coe = None
        if any(p.lower() == "coe" for p in m.protocols):
            coe = EsiCoe(
                init_cmds=tuple(
                    EsiInitCmd(
                        transitions=c.transitions,
                        index=c.index,
                        subindex=c.subindex,
                        data=c.data,
                        comment=c.comment or None,
                        complete_access=c.complete_access,
                    )
                    for c in m.init_cmds
                )
            )
        mailbox = EsiMailbox(protocols=m.protocols, data_link_layer=m.data_link_layer, coe=coe)
    dc = None
    if slave.dc is not None:
        d = slave.dc
        dc = EsiDc(
            op_modes=(
                EsiDcOpMode(
                    name=d.op_mode or "DC",
                    assign_activate=d.assign_activate,
                    cycle_time_sync0=d.cycle_time0,
                    shift_time_sync0=d.shift_time0,
                    cycle_time_sync1=d.cycle_time1,
                    shift_time_sync1=d.shift_time1,
                ),
            )
        )
    # PDOs the ENI assigns carry their SM; unassigned ones none, so the
    # device's default assignment is the ENI's.
    return EsiDevice(
        product_code=slave.product_code,
        revision=slave.revision,
        type_name=slave.name,
        name=Text(((None, slave.name),)),
        physics=slave.physics,
        fmmus=tuple(EsiFmmu(index=i, name=n) for i, n in enumerate(slave.fmmus)),
        sms=sms,
        rx_pdos=tuple(conv(p) for p in slave.rx_pdos),
        tx_pdos=tuple(conv(p) for p in slave.tx_pdos),
        mailbox=mailbox,
        dc=dc,
    )


# --- writing -------------------------------------------------------------------------------


def _hex(v: int, digits: int = 4) -> str:
    return f"#x{v:0{digits}X}"


def _sub(parent: etree._Element, tag: str, text: object = None, **attrs: str) -> etree._Element:
    el = etree.SubElement(parent, tag, attrs)
    if text is not None:
        el.text = str(text)
    return el


def _pdo_xml(parent: etree._Element, p: EniPdo) -> None:
    attrs = {"Fixed": "true" if p.fixed else "false"}
    if p.mandatory:
        attrs["Mandatory"] = "true"
    if p.sm is not None:
        attrs["Sm"] = str(p.sm)
    el = _sub(parent, "RxPdo" if p.direction == "rx" else "TxPdo", **attrs)
    _sub(el, "Index", _hex(p.index))
    _sub(el, "Name", p.name)
    for e in p.entries:
        en = _sub(el, "Entry")
        _sub(en, "Index", _hex(e.index))
        _sub(en, "SubIndex", e.subindex)
        _sub(en, "BitLen", e.bit_len)
        if e.name:
            _sub(en, "Name", e.name)
        if e.data_type:
            _sub(en, "DataType", e.data_type)


def _slave_xml(parent: etree._Element, s: EniSlave) -> None:
    el = _sub(parent, "Slave")
    info = _sub(el, "Info")
    _sub(info, "Name", s.name)
    _sub(info, "PhysAddr", s.station_address)
    _sub(info, "AutoIncAddr", (-s.position) & 0xFFFF)
    if s.physics:
        _sub(info, "Physics", s.physics)
    _sub(info, "VendorId", s.vendor_id)
    _sub(info, "ProductCode", s.product_code)
    _sub(info, "RevisionNo", s.revision)
    if s.serial is not None:
        _sub(info, "SerialNo", s.serial)
    if s.alias is not None:
        _sub(info, "Alias", s.alias)
    pd = _sub(el, "ProcessData")
    if s.send_bit_start is not None:
        send = _sub(pd, "Send")
        _sub(send, "BitStart", s.send_bit_start)
        _sub(send, "BitLength", s.send_bit_length)
    if s.recv_bit_start is not None:
        recv = _sub(pd, "Recv")
        _sub(recv, "BitStart", s.recv_bit_start)
        _sub(recv, "BitLength", s.recv_bit_length)
    for sm in s.sms:
        se = _sub(pd, f"Sm{sm.index}")
        _sub(se, "Type", sm.kind)
        _sub(se, "StartAddress", _hex(sm.start))
        _sub(se, "ControlByte", _hex(sm.control, 2))
        _sub(se, "DefaultSize", sm.size)
        _sub(se, "Enable", "true" if sm.enable else "false")
        for idx in sm.pdos:
            _sub(se, "Pdo", _hex(idx))
    for p in s.rx_pdos + s.tx_pdos:
        _pdo_xml(pd, p)
    for f in s.fmmus:
        _sub(pd, "Fmmu", f)
    if s.mailbox is not None:
        m = s.mailbox
        mb = _sub(el, "Mailbox", DataLinkLayer="true" if m.data_link_layer else "false")
        send = _sub(mb, "Send")
        _sub(send, "Start", _hex(m.out_start))
        _sub(send, "Length", m.out_size)
        recv = _sub(mb, "Recv")
        _sub(recv, "Start", _hex(m.in_start))
        _sub(recv, "Length", m.in_size)
        if m.poll_time_ms is not None:
            _sub(recv, "PollTime", m.poll_time_ms)
        for proto in m.protocols:
            _sub(mb, "Protocol", proto)
        if m.init_cmds:
            cmds = _sub(_sub(mb, "CoE"), "InitCmds")
            for c in m.init_cmds:
                ce = _sub(cmds, "InitCmd", CompleteAccess="true" if c.complete_access else "false")
                for t in c.transitions:
                    _sub(ce, "Transition", t)
                if c.comment:
                    _sub(ce, "Comment", c.comment)
                _sub(ce, "Ccs", 1)  # SDO download
                _sub(ce, "Index", _hex(c.index))
                _sub(ce, "SubIndex", c.subindex)
                _sub(ce, "Data", c.data.hex())
    if s.dc is not None:
        d = s.dc
        de = _sub(el, "DC")
        if d.op_mode:
            _sub(de, "OpMode", d.op_mode)
        _sub(de, "AssignActivate", _hex(d.assign_activate))
        _sub(de, "CycleTime0", d.cycle_time0)
        _sub(de, "ShiftTime0", d.shift_time0)
        _sub(de, "CycleTime1", d.cycle_time1)
        _sub(de, "ShiftTime1", d.shift_time1)


def build_eni(cfg: EniConfig) -> bytes:
    """The ENI XML of ``cfg`` (UTF-8, indented)."""
    root = etree.Element("EtherCATConfig", {"Version": "1.3"})
    config = _sub(root, "Config")
    info = _sub(_sub(config, "Master"), "Info")
    _sub(info, "Name", cfg.master_name)
    _sub(info, "Destination", cfg.destination.hex().upper())
    _sub(info, "Source", cfg.source.hex().upper())
    _sub(info, "EtherType", f"{ETHERTYPE_ETHERCAT:04X}")
    for s in cfg.slaves:
        _slave_xml(config, s)
    if cfg.cycle_time_us is not None or cfg.frames:
        cyc = _sub(config, "Cyclic")
        if cfg.cycle_time_us is not None:
            _sub(cyc, "CycleTime", cfg.cycle_time_us)
        for fr in cfg.frames:
            fe = _sub(cyc, "Frame")
            for c in fr.cmds:
                ce = _sub(fe, "Cmd")
                for st in c.states:
                    _sub(ce, "State", st)
                if c.comment:
                    _sub(ce, "Comment", c.comment)
                _sub(ce, "Cmd", c.cmd)
                _sub(ce, "Addr", c.addr)
                _sub(ce, "DataLength", c.data_length)
                _sub(ce, "Cnt", c.cnt)
                if c.input_offs is not None:
                    _sub(ce, "InputOffs", c.input_offs)
                if c.output_offs is not None:
                    _sub(ce, "OutputOffs", c.output_offs)
    pi = _sub(config, "ProcessImage")
    for tag, size, variables in (
        ("Inputs", cfg.input_bytes, cfg.inputs),
        ("Outputs", cfg.output_bytes, cfg.outputs),
    ):
        part = _sub(pi, tag)
        _sub(part, "ByteSize", size)
        for v in variables:
            ve = _sub(part, "Variable")
            _sub(ve, "Name", v.name)
            if v.data_type:
                _sub(ve, "DataType", v.data_type)
            _sub(ve, "BitSize", v.bit_size)
            _sub(ve, "BitOffs", v.bit_offs)
    etree.indent(root, space="  ")
    body: bytes = etree.tostring(root, xml_declaration=True, encoding="UTF-8")
    return body + b"\n"


# --- reading -------------------------------------------------------------------------------


class _Reader(XmlReader):
    """One ENI parse (the typed reads of :class:`XmlReader`)."""

    def kids(self, el: etree._Element) -> dict[str, list[etree._Element]]:
        out: dict[str, list[etree._Element]] = {}
        for name, c in _kids(el):
            out.setdefault(name, []).append(c)
        return out

    def pdo(self, el: etree._Element, direction: Literal["rx", "tx"]) -> EniPdo:
        what = "RxPdo" if direction == "rx" else "TxPdo"
        sm_raw = el.get("Sm")
        try:
            sm = parse_int(sm_raw) if sm_raw is not None else None
        except ValueError as exc:
            raise self.error(el, f"{what}@Sm: {exc}") from None
        entries = []
        for n, e in _kids(el):
            if n != "Entry":
                continue
            sub = self.opt_child_int(e, "SubIndex", f"{what}/Entry")
            dt = self.child(e, "DataType")
            nm = self.child(e, "Name")
            entries.append(
                EniPdoEntry(
                    index=self.int_text(self.need(e, "Index", f"{what}/Entry"), f"{what}/Entry/Index"),
                    subindex=sub or 0,
                    bit_len=self.int_text(
                        self.need(e, "BitLen", f"{what}/Entry"), f"{what}/Entry/BitLen"
                    ),
                    name=_text(nm),
                    data_type=_text(dt) or None,
                )
            )
        return EniPdo(
            direction=direction,
            index=self.int_text(self.need(el, "Index", what), f"{what}/Index"),
            name=_text(self.child(el, "Name")),
            sm=sm,
            fixed=self.bool_attr(el, "Fixed"),
            mandatory=self.bool_attr(el, "Mandatory"),
            entries=tuple(entries),
        )

    def slave(self, el: etree._Element) -> EniSlave:
        info = self.need(el, "Info", "Slave")
        k = self.kids(info)

        def num(name: str, required: bool = True) -> int | None:
            if name not in k:
                if required:
                    raise self.error(info, f"Slave/Info: missing <{name}>")
                return None
            return self.int_text(k[name][0], f"Slave/Info/{name}")

        auto = num("AutoIncAddr", False) or 0
        phys = num("PhysAddr")
        vendor, product, revision = num("VendorId"), num("ProductCode"), num("RevisionNo")
        assert phys is not None and vendor is not None and product is not None
        assert revision is not None
        sms: list[EniSm] = []
        rx: list[EniPdo] = []
        tx: list[EniPdo] = []
        fmmus: list[str] = []
        send = recv = None
        pd = self.child(el, "ProcessData")
        if pd is not None:
            for n, c in _kids(pd):
                if n.startswith("Sm") and n[2:].isdigit():
                    sk = self.kids(c)
                    kind = _text(sk["Type"][0]) if "Type" in sk else "Unused"
                    if kind not in ("MBoxOut", "MBoxIn", "Outputs", "Inputs", "Unused"):
                        raise self.error(c, f"ProcessData/{n}/Type: unknown type {kind!r}")
                    en = sk.get("Enable")
                    sms.append(
                        EniSm(
                            index=int(n[2:]),
                            kind=kind,  # type: ignore[arg-type]
                            start=self.opt_child_int(c, "StartAddress", n) or 0,
                            size=self.opt_child_int(c, "DefaultSize", n) or 0,
                            control=self.opt_child_int(c, "ControlByte", n) or 0,
                            enable=self.bool_text(en[0], f"{n}/Enable") if en else True,
                            pdos=tuple(self.int_text(p, f"{n}/Pdo") for p in sk.get("Pdo", [])),
                        )
                    )
                elif n == "RxPdo":
                    rx.append(self.pdo(c, "rx"))
                elif n == "TxPdo":
                    tx.append(self.pdo(c, "tx"))
                elif n == "Fmmu":
                    fmmus.append(_text(c))
                elif n == "Send":
                    send = (self.opt_child_int(c, "BitStart", n), self.opt_child_int(c, "BitLength", n))
                elif n == "Recv":
                    recv = (self.opt_child_int(c, "BitStart", n), self.opt_child_int(c, "BitLength", n))
        mbx = None
        mb = self.child(el, "Mailbox")
        if mb is not None:
            s_el = self.need(mb, "Send", "Mailbox")
            r_el = self.need(mb, "Recv", "Mailbox")
            cmds: list[EniInitCmd] = []
            coe = self.child(mb, "CoE")
            ic = self.child(coe, "InitCmds") if coe is not None else None
            for n, c in _kids(ic) if ic is not None else ():
                if n != "InitCmd":
                    continue
                ck = self.kids(c)
                try:
                    data = parse_hex_bytes(_text(ck["Data"][0])) if "Data" in ck else b""
                except ValueError as exc:
                    raise self.error(c, f"InitCmd/Data: {exc}") from None
                cmds.append(
                    EniInitCmd(
                        transitions=tuple(_text(t) for t in ck.get("Transition", [])),
                        index=self.int_text(self.need(c, "Index", "InitCmd"), "InitCmd/Index"),
                        subindex=self.opt_child_int(c, "SubIndex", "InitCmd") or 0,
                        data=data,
                        comment=_text(ck["Comment"][0]) if "Comment" in ck else "",
                        complete_access=self.bool_attr(c, "CompleteAccess"),
                    )
                )
            mbx = EniMailbox(
                out_start=self.opt_child_int(s_el, "Start", "Mailbox/Send") or 0,
                out_size=self.opt_child_int(s_el, "Length", "Mailbox/Send") or 0,
                in_start=self.opt_child_int(r_el, "Start", "Mailbox/Recv") or 0,
                in_size=self.opt_child_int(r_el, "Length", "Mailbox/Recv") or 0,
                poll_time_ms=self.opt_child_int(r_el, "PollTime", "Mailbox/Recv"),
                protocols=tuple(_text(c) for n, c in _kids(mb) if n == "Protocol"),
                data_link_layer=self.bool_attr(mb, "DataLinkLayer"),
                init_cmds=tuple(cmds),
            )
        dc = None
        de = self.child(el, "DC")
        if de is not None:
            dc = EniDc(
                op_mode=_text(self.child(de, "OpMode")),
                assign_activate=self.opt_child_int(de, "AssignActivate", "DC") or 0,
                cycle_time0=self.opt_child_int(de, "CycleTime0", "DC") or 0,
                shift_time0=self.opt_child_int(de, "ShiftTime0", "DC") or 0,
                cycle_time1=self.opt_child_int(de, "CycleTime1", "DC") or 0,
                shift_time1=self.opt_child_int(de, "ShiftTime1", "DC") or 0,
            )
        physics = _text(k["Physics"][0]) if "Physics" in k else None
        return EniSlave(
            name=_text(k["Name"][0]) if "Name" in k else "",
            position=(-auto) & 0xFFFF,
            station_address=phys,
            vendor_id=vendor,
            product_code=product,
            revision=revision,
            serial=num("SerialNo", False),
            alias=num("Alias", False),
            physics=physics or None,
            sms=tuple(sms),
            fmmus=tuple(fmmus),
            rx_pdos=tuple(rx),
            tx_pdos=tuple(tx),
            mailbox=mbx,
            dc=dc,
            send_bit_start=send[0] if send else None,
            send_bit_length=(send[1] or 0) if send else 0,
            recv_bit_start=recv[0] if recv else None,
            recv_bit_length=(recv[1] or 0) if recv else 0,
        )

    def config(self, root: etree._Element) -> EniConfig:
        if _local(root.tag) != "EtherCATConfig":
            raise self.error(root, f"root element is <{_local(root.tag)}>, not <EtherCATConfig>")
        config = self.need(root, "Config", "EtherCATConfig")
        master = self.child(config, "Master")
        name, dest, src = "", b"\xff" * 6, b"\x00" * 6
        if master is not None and (info := self.child(master, "Info")) is not None:
            name = _text(self.child(info, "Name"))
            try:
                d = self.child(info, "Destination")
                s = self.child(info, "Source")
                dest = parse_hex_bytes(_text(d)) if d is not None else dest
                src = parse_hex_bytes(_text(s)) if s is not None else src
            except ValueError as exc:
                raise self.error(info, f"Master/Info: {exc}") from None
        slaves = [self.slave(c) for n, c in _kids(config) if n == "Slave"]
        cycle = None
        frames: list[EniFrame] = []
        cyc = self.child(config, "Cyclic")
        if cyc is not None:
            cycle = self.opt_child_int(cyc, "CycleTime", "Cyclic")
            for n, fr in _kids(cyc):
                if n != "Frame":
                    continue
                cmds = []
                for m, c in _kids(fr):
                    if m != "Cmd":
                        continue
                    ck = self.kids(c)
                    cmds.append(
                        EniCmd(
                            states=tuple(_text(x) for x in ck.get("State", [])),
                            cmd=self.int_text(self.need(c, "Cmd", "Frame/Cmd"), "Cmd/Cmd"),
                            addr=self.opt_child_int(c, "Addr", "Cmd") or 0,
                            data_length=self.opt_child_int(c, "DataLength", "Cmd") or 0,
                            cnt=self.opt_child_int(c, "Cnt", "Cmd") or 0,
                            input_offs=self.opt_child_int(c, "InputOffs", "Cmd"),
                            output_offs=self.opt_child_int(c, "OutputOffs", "Cmd"),
                            comment=_text(ck["Comment"][0]) if "Comment" in ck else "",
                        )
                    )
                frames.append(EniFrame(cmds=tuple(cmds)))
        sizes = {"Inputs": 0, "Outputs": 0}
        variables: dict[str, list[EniVariable]] = {"Inputs": [], "Outputs": []}
        pi = self.child(config, "ProcessImage")
        if pi is not None:
            for part in ("Inputs", "Outputs"):
                pe = self.child(pi, part)
                if pe is None:
                    continue
                sizes[part] = self.opt_child_int(pe, "ByteSize", part) or 0
                for n, v in _kids(pe):
                    if n != "Variable":
                        continue
                    dt = self.child(v, "DataType")
                    variables[part].append(
                        EniVariable(
                            name=_text(self.child(v, "Name")),
                            data_type=_text(dt) or None,
                            bit_size=self.opt_child_int(v, "BitSize", "Variable") or 0,
                            bit_offs=self.opt_child_int(v, "BitOffs", "Variable") or 0,
                        )
                    )
        return EniConfig(
            master_name=name,
            destination=dest,
            source=src,
            slaves=tuple(slaves),
            cycle_time_us=cycle,
            frames=tuple(frames),
            input_bytes=sizes["Inputs"],
            output_bytes=sizes["Outputs"],
            inputs=tuple(variables["Inputs"]),
            outputs=tuple(variables["Outputs"]),
        )


def parse_eni(
    data: bytes, source: str = "<bytes>", *, max_bytes: int = DEFAULT_MAX_BYTES
) -> EniConfig:
    """Parse ENI XML (same safety rules as ESI: no DTD, no network, bounded size)."""
    return _Reader(source).config(_safe_xml_root(data, source, max_bytes))


def load_eni(path: str | os.PathLike[str], *, max_bytes: int = DEFAULT_MAX_BYTES) -> EniConfig:
    """Read and parse an ENI file (the size is checked before reading)."""
    name, data = _read_bounded(path, max_bytes)
    return parse_eni(data, name, max_bytes=max_bytes)
