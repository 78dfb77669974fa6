"""ESI XML -> :mod:`pyethercat.esi.model`.

The parser is defensive: ESI files come from vendors and from the internet.

* It never fetches anything: no network, no DTD loading, no entity expansion.
  A document with a DTD (an internal subset or an external reference) is
  refused before libxml2 sees it, which rules out "billion laughs" entity
  bombs and external-entity (XXE) reads; ``huge_tree`` stays off, so libxml2's
  own depth and size limits apply too.
* Input is bounded (64 MiB by default, see ``max_bytes``).
* Every problem is an :class:`~pyethercat.errors.EsiError` carrying the file
  name and line, e.g. ``dev.xml:42: RxPdo/Entry/BitLen: 'x8' is not a number``.

It accepts the spellings real files use: ``#x1600``, ``0x1600`` and ``5632``
for numbers, ``true``/``1`` for booleans, missing optional elements, any
encoding libxml2 knows (the Beckhoff catalogues are ISO-8859-1), and an
optional XML namespace on the elements.
"""

from __future__ import annotations

import os

from pyethercat.errors import ConfigError
from pyethercat.esi.model import (
    EsiCoe,
    EsiDc,
    EsiDcOpMode,
    EsiDevice,
    EsiDeviceInfo,
    EsiEeprom,
    EsiEoe,
    EsiFile,
    EsiFmmu,
    EsiGroup,
    EsiInitCmd,
    EsiMailbox,
    EsiPdo,
    EsiPdoEntry,
    EsiProfile,
    EsiSm,
    EsiVendor,
    PdoDirection,
)
from pyethercat.esi.parse_od import DictionaryReader
from pyethercat.esi.xmlread import (
    DEFAULT_MAX_BYTES,
    _Element,
    _kids,
    _line,
    _local,
    _read_bounded,
    _safe_xml_root,
    _text,
    parse_bool,
    parse_hex_bytes,
    parse_int,
)
from pyethercat.wire.al import TRANSITIONS, parse_transition

__all__ = [
    "DEFAULT_MAX_BYTES",
    "load_esi",
    "parse_bool",
    "parse_esi",
    "parse_hex_bytes",
    "parse_int",
]


_DC_TIMES = {
    "CycleTimeSync0": "cycle_time_sync0",
    "ShiftTimeSync0": "shift_time_sync0",
    "CycleTimeSync1": "cycle_time_sync1",
    "ShiftTimeSync1": "shift_time_sync1",
}


class _Parser(DictionaryReader):
    """One ESI parse: the file, its devices and their parts."""

    # -- top level

    def file(self, root: _Element) -> EsiFile:
        if _local(root.tag) != "EtherCATInfo":
            raise self.error(root, f"root element is <{_local(root.tag)}>, expected <EtherCATInfo>")
        vendor_el = self.child(root, "Vendor")
        if vendor_el is None:
            raise self.error(root, "EtherCATInfo: missing <Vendor>")
        vendor = self.vendor(vendor_el)
        groups: list[EsiGroup] = []
        devices: list[EsiDevice] = []
        desc = self.child(root, "Descriptions")
        if desc is None:
            raise self.error(root, "EtherCATInfo: missing <Descriptions>")
        for name, el in _kids(desc):
            if name == "Groups":
                groups.extend(self.group(g) for n, g in _kids(el) if n == "Group")
            elif name == "Devices":
                devices.extend(self.device(d) for n, d in _kids(el) if n == "Device")
        return EsiFile(
            source=self.source,
            vendor=vendor,
            version=root.get("Version"),
            groups=tuple(groups),
            devices=tuple(devices),
        )

    def vendor(self, el: _Element) -> EsiVendor:
        names: list[_Element] = []
        vid: int | None = None
        image = None
        for name, c in _kids(el):
            if name == "Id":
                vid = self.int_text(c, "Vendor/Id", 32)
            elif name == "Name":
                names.append(c)
            elif name == "ImageData16x14" and _text(c):
                image = self.hex_text(c, "Vendor/ImageData16x14")
        if vid is None:
            raise self.error(el, "Vendor: missing <Id>")
        return EsiVendor(
            id=vid,
            name=self.texts(names),
            file_version=self.int_attr(el, "FileVersion"),
            image=image,
        )

    def group(self, el: _Element) -> EsiGroup:
        names: list[_Element] = []
        type_ = ""
        parent = None
        image = None
        for name, c in _kids(el):
            if name == "Type":
                type_ = _text(c)
            elif name == "Name":
                names.append(c)
            elif name == "ParentGroup":
                parent = _text(c) or None
            elif name == "ImageData16x14" and _text(c):
                image = self.hex_text(c, "Group/ImageData16x14")
        return EsiGroup(
            type=type_,
            name=self.texts(names),
            sort_order=self.int_attr(el, "SortOrder"),
            parent=parent,
            image=image,
        )

    # -- device

    def device(self, el: _Element) -> EsiDevice:
        type_el: _Element | None = None
        names: list[_Element] = []
        urls: list[_Element] = []
        hide: list[int] = []
        alt: list[int] = []
        fmmus: list[EsiFmmu] = []
        sms: list[EsiSm] = []
        rx: list[EsiPdo] = []
        tx: list[EsiPdo] = []
        profiles: list[EsiProfile] = []
        info = EsiDeviceInfo()
        group_type = None
        mailbox = None
        dc = None
        eeprom = None
        image = None
        for name, c in _kids(el):
            if name == "Type":
                type_el = c
            elif name == "Name":
                names.append(c)
            elif name == "URL":
                urls.append(c)
            elif name == "HideType":
                rev = self.int_attr(c, "RevisionNo", bits=32)
                if rev is not None:
                    hide.append(rev)
            elif name == "AlternativeType":
                rev = self.int_attr(c, "RevisionNo", bits=32)
                if rev is not None:
                    alt.append(rev)
            elif name == "Info":
                info = self.info(c)
            elif name == "GroupType":
                group_type = _text(c) or None
            elif name == "Fmmu":
                fmmus.append(
                    EsiFmmu(
                        index=len(fmmus),
                        name=_text(c),
                        sm=self.int_attr(c, "Sm"),
                        su=self.int_attr(c, "Su"),
                        op_only=self.bool_attr(c, "OpOnly"),
                    )
                )
            elif name == "Sm":
                sms.append(self.sm(c, len(sms)))
            elif name == "RxPdo":
                rx.append(self.pdo(c, "rx"))
            elif name == "TxPdo":
                tx.append(self.pdo(c, "tx"))
            elif name == "Mailbox":
                mailbox = self.mailbox(c)
            elif name == "Dc":
                dc = self.dc(c)
            elif name == "Eeprom":
                eeprom = self.eeprom(c)
            elif name == "Profile":
                profiles.append(self.profile(c))
            elif name == "ImageData16x14" and _text(c):
                image = self.hex_text(c, "Device/ImageData16x14")
        if type_el is None:
            raise self.error(el, "Device: missing <Type>")
        return EsiDevice(
            product_code=self.int_attr(type_el, "ProductCode", 0, 32) or 0,
            revision=self.int_attr(type_el, "RevisionNo", 0, 32) or 0,
            type_name=_text(type_el),
            check_revision=type_el.get("CheckRevisionNo"),
            name=self.texts(names),
            physics=el.get("Physics"),
            group_type=group_type,
            url=self.texts(urls),
            hide_revisions=tuple(hide),
            alternative_revisions=tuple(alt),
            info=info,
            fmmus=tuple(fmmus),
            sms=tuple(sms),
            rx_pdos=tuple(rx),
            tx_pdos=tuple(tx),
            mailbox=mailbox,
            dc=dc,
            eeprom=eeprom,
            profiles=tuple(profiles),
            image=image,
            line=_line(el),
        )

    def info(self, el: _Element) -> EsiDeviceInfo:
        values: dict[str, int | None] = {}
        paths = {
            ("Electrical", "EBusCurrent"): "ebus_current",
            ("Mailbox", "Timeout", "RequestTimeout"): "request_timeout",
            ("Mailbox", "Timeout", "ResponseTimeout"): "response_timeout",
            ("StateMachine", "Timeout", "PreopTimeout"): "preop_timeout",
            ("StateMachine", "Timeout", "SafeopOpTimeout"): "safeop_op_timeout",
            ("StateMachine", "Timeout", "BackToInitTimeout"): "back_to_init_timeout",
            ("StateMachine", "Timeout", "BackToSafeopTimeout"): "back_to_safeop_timeout",
            ("EtherCATController", "DpramSize"): "dpram_size",
            ("EtherCATController", "SmCount"): "sm_count",
            ("EtherCATController", "FmmuCount"): "fmmu_count",
        }
        for path, attr in paths.items():
            node: _Element | None = el
            for step in path:
                node = self.child(node, step) if node is not None else None
            if node is not None and _text(node):
                values[attr] = self.int_text(node, "Info/" + "/".join(path))
        return EsiDeviceInfo(**values)

    def sm(self, el: _Element, index: int) -> EsiSm:
        return EsiSm(
            index=index,
            name=_text(el),
            start_address=self.int_attr(el, "StartAddress", bits=16),
            control_byte=self.int_attr(el, "ControlByte", bits=8),
            default_size=self.int_attr(el, "DefaultSize", bits=16),
            min_size=self.int_attr(el, "MinSize", bits=16),
            max_size=self.int_attr(el, "MaxSize", bits=16),
            enable=self.bool_attr(el, "Enable"),
            virtual=self.bool_attr(el, "Virtual"),
            op_only=self.bool_attr(el, "OpOnly"),
            line=_line(el),
        )

    def pdo(self, el: _Element, direction: PdoDirection) -> EsiPdo:
        what = "RxPdo" if direction == "rx" else "TxPdo"
        index: int | None = None
        names: list[_Element] = []
        entries: list[EsiPdoEntry] = []
        excludes: list[int] = []
        for name, c in _kids(el):
            if name == "Index":
                index = self.int_text(c, f"{what}/Index", 16)
            elif name == "Name":
                names.append(c)
            elif name == "Entry":
                entries.append(self.entry(c, what))
            elif name == "Exclude":
                excludes.append(self.int_text(c, f"{what}/Exclude", 16))
        if index is None:
            raise self.error(el, f"{what}: missing <Index>")
        return EsiPdo(
            direction=direction,
            index=index,
            name=self.texts(names),
            entries=tuple(entries),
            sm=self.int_attr(el, "Sm", bits=8),
            su=self.int_attr(el, "Su"),
            fixed=self.bool_attr(el, "Fixed"),
            mandatory=self.bool_attr(el, "Mandatory"),
            virtual=self.bool_attr(el, "Virtual"),
            excludes=tuple(excludes),
            os_fac=self.int_attr(el, "OSFac"),
            os_min=self.int_attr(el, "OSMin"),
            os_max=self.int_attr(el, "OSMax"),
            os_index_inc=self.int_attr(el, "OSIndexInc"),
            line=_line(el),
        )

    def entry(self, el: _Element, what: str) -> EsiPdoEntry:
        index: int | None = None
        subindex = 0
        bit_len: int | None = None
        names: list[_Element] = []
        data_type = None
        comment = None
        for name, c in _kids(el):
            if name == "Index":
                index = self.int_text(c, f"{what}/Entry/Index")
            elif name == "SubIndex":
                if _text(c):
                    subindex = self.int_text(c, f"{what}/Entry/SubIndex")
            elif name == "BitLen":
                bit_len = self.int_text(c, f"{what}/Entry/BitLen")
            elif name == "Name":
                names.append(c)
            elif name == "DataType":
                data_type = _text(c) or None
            elif name == "Comment":
                comment = _text(c) or None
        if index is None:
            raise self.error(el, f"{what}/Entry: missing <Index>")
        if bit_len is None:
            raise self.error(el, f"{what}/Entry: missing <BitLen>")
        if not (0 <= index <= 0xFFFF and 0 <= subindex <= 0xFF and 0 <= bit_len <= 0xFFFF):
            raise self.error(
                el,
                f"{what}/Entry: index 0x{index:X}, subindex {subindex} or bit length {bit_len} out of range",
            )
        return EsiPdoEntry(
            index=index,
            subindex=subindex,
            bit_len=bit_len,
            name=self.texts(names),
            data_type=data_type,
            comment=comment,
        )

    # -- mailbox

    def mailbox(self, el: _Element) -> EsiMailbox:
        protocols: list[str] = []
        coe = None
        eoe = None
        soe_cmds: tuple[EsiInitCmd, ...] = ()
        for name, c in _kids(el):
            if name in ("AoE", "EoE", "CoE", "FoE", "SoE", "VoE"):
                protocols.append(name)
            if name == "CoE":
                coe = self.coe(c)
            elif name == "EoE":
                eoe = EsiEoe(
                    ip=self.bool_attr(c, "IP"),
                    mac=self.bool_attr(c, "MAC"),
                    time_stamp=self.bool_attr(c, "TimeStamp"),
                )
            elif name == "SoE":
                soe_cmds = tuple(self.init_cmd(x, "SoE") for n, x in _kids(c) if n == "InitCmd")
        return EsiMailbox(
            protocols=tuple(protocols),
            data_link_layer=self.bool_attr(el, "DataLinkLayer"),
            coe=coe,
            eoe=eoe,
            soe_init_cmds=soe_cmds,
        )

    def coe(self, el: _Element) -> EsiCoe:
        cmds: list[EsiInitCmd] = []
        # Older files (the bundled Metronix drive, for one) give the EDS file as an attribute.
        eds = el.get("EdsFile") or None
        for name, c in _kids(el):
            if name == "InitCmd":
                cmds.append(self.init_cmd(c, "CoE"))
            elif name == "EdsFile":
                eds = _text(c) or None
        ds402 = self.int_attr(el, "DS402Channels", 0, 8) or 0
        return EsiCoe(
            sdo_info=self.bool_attr(el, "SdoInfo"),
            pdo_assign=self.bool_attr(el, "PdoAssign"),
            pdo_config=self.bool_attr(el, "PdoConfig"),
            pdo_upload=self.bool_attr(el, "PdoUpload"),
            complete_access=self.bool_attr(el, "CompleteAccess"),
            segmented_sdo=self.bool_attr(el, "SegmentedSdo", True),
            sdo_upload_with_max_length=self.bool_attr(el, "SdoUploadWithMaxLength"),
            diag_history=self.bool_attr(el, "DiagHistory"),
            ds402_channels=ds402,
            init_cmds=tuple(cmds),
            eds_file=eds,
        )

    def init_cmd(self, el: _Element, proto: str) -> EsiInitCmd:
        what = f"{proto}/InitCmd"
        transitions: list[str] = []
        index: int | None = None
        subindex = 0
        data = b""
        comment = None
        timeout = None
        for name, c in _kids(el):
            if name == "Transition":
                try:
                    transitions.append(parse_transition(_text(c)))
                except ConfigError:
                    raise self.error(c, f"{what}/Transition: {_text(c)!r} is no state "
                                        f"transition ({', '.join(TRANSITIONS)})") from None
            elif name in ("Index", "IDN"):
                index = self.int_text(c, f"{what}/{name}", 16)
            elif name == "SubIndex":
                subindex = self.int_text(c, f"{what}/SubIndex", 8)
            elif name == "Data":
                data = self.hex_text(c, f"{what}/Data")
            elif name == "Comment":
                comment = _text(c) or None
            elif name == "Timeout":
                timeout = self.int_text(c, f"{what}/Timeout")
        if index is None:
            raise self.error(el, f"{what}: missing <Index>")
        return EsiInitCmd(
            transitions=tuple(transitions),
            index=index,
            subindex=subindex,
            data=data,
            comment=comment,
            complete_access=self.bool_attr(el, "CompleteAccess"),
            fixed=self.bool_attr(el, "Fixed"),
            timeout_ms=timeout,
            line=_line(el),
        )

    # -- DC, EEPROM

    def dc(self, el: _Element) -> EsiDc:
        modes = tuple(self.op_mode(c) for n, c in _kids(el) if n == "OpMode")
        return EsiDc(op_modes=modes, pdo_oversampling=self.bool_attr(el, "PdoOversampling"))

    def op_mode(self, el: _Element) -> EsiDcOpMode:
        kw: dict[str, object] = {}
        sm_pdos: list[tuple[int, tuple[int, ...]]] = []
        name = ""
        for tag, c in _kids(el):
            if tag == "Name":
                name = _text(c)
            elif tag == "Desc":
                kw["desc"] = _text(c) or None
            elif tag == "AssignActivate":
                kw["assign_activate"] = self.int_text(c, "Dc/OpMode/AssignActivate", 16)
            elif tag in _DC_TIMES:
                base = _DC_TIMES[tag]
                kw[base] = self.int_text(c, f"Dc/OpMode/{tag}") if _text(c) else 0
                factor = self.int_attr(c, "Factor")
                if factor is not None:
                    kw[base + "_factor"] = factor
                if tag == "ShiftTimeSync0":
                    kw["shift_time_sync0_input"] = self.bool_attr(c, "Input")
            elif tag == "Sm":
                no = self.int_attr(c, "No")
                if no is None:
                    raise self.error(c, "Dc/OpMode/Sm: missing No attribute")
                pdos = tuple(
                    self.int_text(p, "Dc/OpMode/Sm/Pdo", 16) for n, p in _kids(c) if n == "Pdo"
                )
                sm_pdos.append((no, pdos))
        return EsiDcOpMode(name=name, sm_pdos=tuple(sm_pdos), **kw)  # type: ignore[arg-type]

    def eeprom(self, el: _Element) -> EsiEeprom:
        kw: dict[str, object] = {}
        cats: list[tuple[int, bytes]] = []
        for name, c in _kids(el):
            if name == "ByteSize":
                kw["byte_size"] = self.int_text(c, "Eeprom/ByteSize")
            elif name == "ConfigData":
                kw["config_data"] = self.hex_text(c, "Eeprom/ConfigData")
            elif name == "BootStrap":
                kw["bootstrap"] = self.hex_text(c, "Eeprom/BootStrap")
            elif name == "Data":
                kw["data"] = self.hex_text(c, "Eeprom/Data")
            elif name == "Category":
                no = self.child_int(c, "CatNo", "Eeprom/Category", 16)
                data_el = self.child(c, "Data")
                data = (
                    self.hex_text(data_el, "Eeprom/Category/Data") if data_el is not None else b""
                )
                cats.append((no, data))
        return EsiEeprom(categories=tuple(cats), **kw)  # type: ignore[arg-type]


# --- entry points --------------------------------------------------------------


def parse_esi(
    data: bytes, source: str = "<bytes>", *, max_bytes: int = DEFAULT_MAX_BYTES
) -> EsiFile:
    """Parse an ESI document given as bytes.

    ``source`` names the document in error messages. Raises
    :class:`~pyethercat.errors.EsiError` for input larger than ``max_bytes``,
    unsafe input (a DTD), malformed XML and content that is not a valid ESI.
    """
    if not isinstance(data, bytes | bytearray | memoryview):
        raise TypeError("parse_esi takes bytes (the encoding is declared inside the XML)")
    return _Parser(source).file(_safe_xml_root(data, source, max_bytes))


def load_esi(path: str | os.PathLike[str], *, max_bytes: int = DEFAULT_MAX_BYTES) -> EsiFile:
    """Read and parse an ESI file (the size is checked before reading)."""
    name, data = _read_bounded(path, max_bytes)
    return parse_esi(data, name, max_bytes=max_bytes)
