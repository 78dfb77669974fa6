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
import re
from collections.abc import Callable, Iterator
from typing import Any

from lxml import etree

from pyethercat.errors import ConfigError, EsiError
from pyethercat.esi.model import (
    EsiCoe,
    EsiDataType,
    EsiDc,
    EsiDcOpMode,
    EsiDevice,
    EsiDeviceInfo,
    EsiDictionary,
    EsiEeprom,
    EsiEoe,
    EsiFile,
    EsiFlags,
    EsiFmmu,
    EsiGroup,
    EsiInitCmd,
    EsiMailbox,
    EsiObject,
    EsiObjectSubItem,
    EsiPdo,
    EsiPdoEntry,
    EsiProfile,
    EsiSm,
    EsiSubItemType,
    EsiValueInfo,
    EsiVendor,
    PdoDirection,
    Text,
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

#: Largest input accepted unless the caller says otherwise. Real catalogues are
#: a few MB; this leaves room and still bounds memory (lxml needs ~10x input).
DEFAULT_MAX_BYTES = 64 * 1024 * 1024

_Element = etree._Element

# "#x0x6041" is in the wild (poulpe Orbita ESI): a "#x" and a "0x" prefix stacked.
_INT_RE = re.compile(r"^\s*(-?)\s*(?:(?:#[xX](?:0[xX])?|0[xX])([0-9A-Fa-f]+)|([0-9]+))\s*$")
#: No ESI number needs more digits (a 64-bit value has 20 decimal digits); longer
#: ones are refused before int() spends time on them.
_MAX_DIGITS = 40
_DOCTYPE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)
_SPACE = re.compile(r"\s+")
_DC_TIMES = {
    "CycleTimeSync0": "cycle_time_sync0",
    "ShiftTimeSync0": "shift_time_sync0",
    "CycleTimeSync1": "cycle_time_sync1",
    "ShiftTimeSync1": "shift_time_sync1",
}


# --- value helpers (public: the ENI / SII code reads the same spellings) -------


def parse_int(text: str | None) -> int:
    """Parse an ESI number: ``#x1600``, ``0x1600``, ``5632``, ``-1`` (and ``#x0x1600``).

    Raises ``ValueError`` for anything else (callers add file and line).
    """
    if text is None:
        raise ValueError("missing number")
    m = _INT_RE.match(text)
    if m is None:
        raise ValueError(f"{_show(text)} is not a number")
    digits = m.group(2) if m.group(2) is not None else m.group(3)
    if len(digits) > _MAX_DIGITS:
        raise ValueError(f"{_show(text)} has {len(digits)} digits, too many for a number")
    value = int(digits, 16) if m.group(2) is not None else int(digits, 10)
    return -value if m.group(1) else value


def _show(text: str, limit: int = 40) -> str:
    """``text`` quoted for an error message, cut when it is long."""
    t = text.strip()
    return repr(t) if len(t) <= limit else f"{t[:limit]!r}... ({len(t)} characters)"


def parse_bool(text: str | None) -> bool:
    """Parse an xs:boolean: ``true``/``false``/``1``/``0`` (any case, spaces ok)."""
    t = (text or "").strip().lower()
    if t in ("true", "1"):
        return True
    if t in ("false", "0"):
        return False
    raise ValueError(f"{_show(text or '')} is not a boolean")


def parse_hex_bytes(text: str | None) -> bytes:
    """Parse hexBinary (whitespace allowed): ``"0500030000"`` -> ``b"\\x05\\x00..."``."""
    t = _SPACE.sub("", text or "")
    if t[:2] in ("0x", "0X", "#x", "#X"):
        t = t[2:]
    if len(t) % 2:
        raise ValueError(f"hex data has an odd number of digits ({len(t)})")
    try:
        return bytes.fromhex(t)
    except ValueError:
        raise ValueError("hex data has a non-hex character") from None


# --- safety --------------------------------------------------------------------


def _check_prolog(data: bytes, source: str) -> None:
    """Refuse DTDs before libxml2 parses them (entity bombs, XXE)."""
    head = data
    # UTF-32 BOMs first: the UTF-32-LE BOM starts with the UTF-16-LE one.
    for bom, codec in (
        (b"\x00\x00\xfe\xff", "utf-32-be"),
        (b"\xff\xfe\x00\x00", "utf-32-le"),
        (b"\xfe\xff", "utf-16-be"),
        (b"\xff\xfe", "utf-16-le"),
    ):
        if data.startswith(bom):
            # Look at the prolog as text; a cut character at the end is harmless.
            head = data[len(bom) : 1 << 20].decode(codec, errors="ignore").encode("utf-8")
            break
    # Walk the prolog item by item: comments and processing instructions may hold
    # "<x" or "<!DOCTYPE" text of their own, which is neither a root nor a DTD.
    pos = 0
    while True:
        lt = head.find(b"<", pos)
        if lt < 0:
            return
        if head.startswith(b"<?", lt):
            end = head.find(b"?>", lt + 2)
            pos = end + 2
        elif head.startswith(b"<!--", lt):
            end = head.find(b"-->", lt + 4)
            pos = end + 3
        else:
            break
        if end < 0:
            return  # unterminated: libxml2 reports the malformed document
    m = _DOCTYPE.match(head, lt)
    if m is None:
        return  # the root element: no DTD
    decl_end = head.find(b">", m.end())
    decl = head[m.end() : decl_end if decl_end >= 0 else len(head)]
    if b"[" in decl or b"SYSTEM" in decl.upper() or b"PUBLIC" in decl.upper():
        line = head.count(b"\n", 0, m.start()) + 1
        raise EsiError(
            "document type declaration with a DTD (entities or an external reference) "
            "is not allowed in an ESI file",
            source,
            line,
        )


def _make_parser() -> etree.XMLParser:
    return etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_blank_text=False,
        collect_ids=False,
    )


# --- the parser ----------------------------------------------------------------


def _local(tag: object) -> str | None:
    """Element name without namespace; None for comments / PIs / entities."""
    if not isinstance(tag, str):
        return None
    return tag.rpartition("}")[2] if tag[:1] == "{" else tag


def _kids(el: _Element) -> Iterator[tuple[str, _Element]]:
    # iterchildren(Element) skips comments, PIs and entity nodes in C.
    for c in el.iterchildren(etree.Element):
        tag = c.tag
        assert isinstance(tag, str)
        yield (tag.rpartition("}")[2] if tag[0] == "{" else tag), c


def _line(el: _Element) -> int | None:
    line: object = el.sourceline  # lxml-stubs types this loosely
    return line if isinstance(line, int) else None


def _text(el: _Element | None) -> str:
    if el is None or el.text is None:
        return ""
    return el.text.strip()


class _Parser:
    """One parse: holds the source name for error messages."""

    def __init__(self, source: str) -> None:
        self.source = source

    # -- errors and typed reads

    def error(self, el: _Element | None, message: str) -> EsiError:
        line = _line(el) if el is not None else None
        return EsiError(message, self.source, line)

    def _convert(
        self, el: _Element, what: str, raw: str | None, fn: Callable[[str | None], object]
    ) -> object:
        try:
            return fn(raw)
        except ValueError as exc:
            raise self.error(el, f"{what}: {exc}") from None

    def _ranged(self, el: _Element, what: str, value: int, bits: int | None) -> int:
        """``value`` checked to be an unsigned number of ``bits`` bits (if given)."""
        if bits is not None and not 0 <= value < (1 << bits):
            raise self.error(el, f"{what}: {value} is out of range (0 to 0x{(1 << bits) - 1:X})")
        return value

    def int_text(self, el: _Element, what: str, bits: int | None = None) -> int:
        """The element's text as a number (unsigned, ``bits`` wide, when ``bits`` is given)."""
        value = self._convert(el, what, el.text, parse_int)
        assert isinstance(value, int)
        return self._ranged(el, what, value, bits)

    def int_attr(
        self, el: _Element, name: str, default: int | None = None, bits: int | None = None
    ) -> int | None:
        """Attribute ``name`` as a number, ``default`` when absent (range as :meth:`int_text`)."""
        raw = el.get(name)
        if raw is None:
            return default
        what = f"{_local(el.tag)}@{name}"
        value = self._convert(el, what, raw, parse_int)
        assert isinstance(value, int)
        return self._ranged(el, what, value, bits)

    def bool_attr(self, el: _Element, name: str, default: bool = False) -> bool:
        raw = el.get(name)
        if raw is None:
            return default
        value = self._convert(el, f"{_local(el.tag)}@{name}", raw, parse_bool)
        assert isinstance(value, bool)
        return value

    def bool_text(self, el: _Element, what: str) -> bool:
        if not _text(el):
            return False
        value = self._convert(el, what, el.text, parse_bool)
        assert isinstance(value, bool)
        return value

    def hex_text(self, el: _Element, what: str) -> bytes:
        value = self._convert(el, what, el.text, parse_hex_bytes)
        assert isinstance(value, bytes)
        return value

    def child_int(self, el: _Element, name: str, what: str, bits: int | None = None) -> int:
        """A required numeric child element."""
        c = self.child(el, name)
        if c is None:
            raise self.error(el, f"{what}: missing <{name}>")
        return self.int_text(c, f"{what}/{name}", bits)

    def opt_child_int(self, el: _Element, name: str, what: str) -> int | None:
        c = self.child(el, name)
        if c is None or not _text(c):
            return None
        return self.int_text(c, f"{what}/{name}")

    @staticmethod
    def child(el: _Element, name: str) -> _Element | None:
        for n, c in _kids(el):
            if n == name:
                return c
        return None

    @staticmethod
    def texts(elements: list[_Element]) -> Text:
        items: list[tuple[int | None, str]] = []
        for e in elements:
            raw = e.get("LcId")
            lcid: int | None
            try:
                lcid = parse_int(raw) if raw is not None else None
            except ValueError:
                lcid = None  # a bad LcId should not lose the name
            items.append((lcid, _text(e)))
        return Text(tuple(items))

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

    # -- profile and dictionary

    def profile(self, el: _Element) -> EsiProfile:
        nos: list[int] = []
        add_info = None
        channels = None
        dictionary = None
        for name, c in _kids(el):
            if name == "ProfileNo":
                nos.append(self.int_text(c, "Profile/ProfileNo"))
            elif name == "AddInfo" and _text(c):
                add_info = self.int_text(c, "Profile/AddInfo")
            elif name == "ChannelCount" and _text(c):
                channels = self.int_text(c, "Profile/ChannelCount")
            elif name == "Dictionary":
                dictionary = self.dictionary(c)
        return EsiProfile(
            profile_no=tuple(nos), add_info=add_info, channel_count=channels, dictionary=dictionary
        )

    def dictionary(self, el: _Element) -> EsiDictionary:
        types: dict[str, EsiDataType] = {}
        objects: list[EsiObject] = []
        for name, c in _kids(el):
            if name == "DataTypes":
                for n, t in _kids(c):
                    if n == "DataType":
                        dt = self.data_type(t)
                        types[dt.name] = dt
            elif name == "Objects":
                objects.extend(self.obj(o) for n, o in _kids(c) if n == "Object")
        return EsiDictionary(data_types=types, objects=tuple(objects))

    def flags(self, el: _Element | None) -> EsiFlags:
        if el is None:
            return EsiFlags()
        kw: dict[str, object] = {}
        for name, c in _kids(el):
            if name == "Access":
                kw["access"] = _text(c) or None
                kw["write_restrictions"] = c.get("WriteRestrictions")
            elif name == "PdoMapping":
                kw["pdo_mapping"] = _text(c) or None
            elif name == "Category":
                kw["category"] = _text(c) or None
            elif name == "Backup":
                kw["backup"] = self.bool_text(c, "Flags/Backup")
            elif name == "Setting":
                kw["setting"] = self.bool_text(c, "Flags/Setting")
        return EsiFlags(**kw)  # type: ignore[arg-type]

    def data_type(self, el: _Element) -> EsiDataType:
        name = ""
        bit_size = 0
        base = None
        lbound = None
        elements = None
        subs: list[EsiSubItemType] = []
        enums: list[tuple[int, str]] = []
        for tag, c in _kids(el):
            if tag == "Name":
                name = _text(c)
            elif tag == "BitSize":
                bit_size = self.int_text(c, "DataType/BitSize")
            elif tag == "BaseType":
                base = _text(c) or None
            elif tag == "ArrayInfo" and elements is None:
                lbound = self.opt_child_int(c, "LBound", "DataType/ArrayInfo")
                elements = self.opt_child_int(c, "Elements", "DataType/ArrayInfo")
            elif tag == "SubItem":
                subs.append(self.sub_item_type(c))
            elif tag == "EnumInfo":
                value = self.child_int(c, "Enum", "DataType/EnumInfo")
                txt = self.child(c, "Text")
                enums.append((value, _text(txt)))
        return EsiDataType(
            name=name,
            bit_size=bit_size,
            base_type=base,
            array_lbound=lbound,
            array_elements=elements,
            sub_items=tuple(subs),
            enums=tuple(enums),
        )

    def sub_item_type(self, el: _Element) -> EsiSubItemType:
        sub = self.opt_child_int(el, "SubIdx", "DataType/SubItem")
        return EsiSubItemType(
            subindex=sub,
            name=_text(self.child(el, "Name")),
            type=_text(self.child(el, "Type")),
            bit_size=self.opt_child_int(el, "BitSize", "DataType/SubItem") or 0,
            bit_offset=self.opt_child_int(el, "BitOffs", "DataType/SubItem") or 0,
            flags=self.flags(self.child(el, "Flags")),
        )

    def value_info(
        self, el: _Element | None, what: str
    ) -> tuple[EsiValueInfo, tuple[EsiObjectSubItem, ...]]:
        if el is None:
            return EsiValueInfo(), ()
        kw: dict[str, object] = {}
        subs: list[EsiObjectSubItem] = []
        for name, c in _kids(el):
            if name == "DefaultData":
                kw["default_data"] = self.hex_text(c, f"{what}/DefaultData")
            elif name == "DefaultValue":
                kw["default_value"] = _text(c)
            elif name == "DefaultString":
                kw["default_string"] = c.text or ""
            elif name == "MinValue":
                kw["min_value"] = _text(c)
            elif name == "MaxValue":
                kw["max_value"] = _text(c)
            elif name == "Unit":
                kw["unit"] = _text(c)
            elif name == "SubItem":
                info, _ = self.value_info(self.child(c, "Info"), f"{what}/SubItem/Info")
                subs.append(EsiObjectSubItem(name=_text(self.child(c, "Name")), info=info))
        return EsiValueInfo(**kw), tuple(subs)  # type: ignore[arg-type]

    def obj(self, el: _Element) -> EsiObject:
        index: int | None = None
        names: list[_Element] = []
        type_ = ""
        bit_size = 0
        info_el = None
        flags_el = None
        for name, c in _kids(el):
            if name == "Index":
                index = self.int_text(c, "Object/Index", 16)
            elif name == "Name":
                names.append(c)
            elif name == "Type":
                type_ = _text(c)
            elif name == "BitSize":
                bit_size = self.int_text(c, "Object/BitSize")
            elif name == "Info":
                info_el = c
            elif name == "Flags":
                flags_el = c
        if index is None:
            raise self.error(el, "Object: missing <Index>")
        info, subs = self.value_info(info_el, "Object/Info")
        return EsiObject(
            index=index,
            name=self.texts(names),
            type=type_,
            bit_size=bit_size,
            info=info,
            sub_items=subs,
            flags=self.flags(flags_el),
            line=_line(el),
        )


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


def _safe_xml_root(
    data: bytes | bytearray | memoryview, source: str, max_bytes: int
) -> etree._Element:
    """Root element of an ESI or ENI document: bounded size, no DTD, no network."""
    data = bytes(data)
    if len(data) > max_bytes:
        raise EsiError(f"file is {len(data)} bytes, more than the limit of {max_bytes}", source)
    if not data.strip():
        raise EsiError("file is empty", source)
    _check_prolog(data, source)
    try:
        root = etree.fromstring(data, parser=_make_parser())
    except etree.XMLSyntaxError as exc:
        line = exc.lineno if exc.lineno else None
        # libxml2 messages may hold a newline; an EsiError is one line.
        raise EsiError(f"malformed XML: {' '.join(exc.msg.split())}", source, line) from None
    # Belt and braces: the prolog check should already have refused these.
    docinfo: Any = root.getroottree().docinfo  # lxml-stubs lacks system_url / iterentities
    dtd = docinfo.internalDTD
    if docinfo.system_url or docinfo.public_id or (dtd is not None and any(dtd.iterentities())):
        raise EsiError("document type declaration with a DTD is not allowed", source, 1)
    return root


def _read_bounded(path: str | os.PathLike[str], max_bytes: int) -> tuple[str, bytes]:
    """(file name, contents) of an ESI or ENI file; the size is checked before reading."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size > max_bytes:
                raise EsiError(f"file is {size} bytes, more than the limit of {max_bytes}", name)
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise EsiError(f"cannot read: {exc.strerror or exc}", name) from None
    return name, data


def load_esi(path: str | os.PathLike[str], *, max_bytes: int = DEFAULT_MAX_BYTES) -> EsiFile:
    """Read and parse an ESI file (the size is checked before reading)."""
    name, data = _read_bounded(path, max_bytes)
    return parse_esi(data, name, max_bytes=max_bytes)
