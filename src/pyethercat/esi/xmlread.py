"""Reading ESI and ENI XML safely: bounded input, no DTD, typed values with file and line.

Both documents come from vendors and configuration tools, so the reading is
defensive (see :mod:`pyethercat.esi.parse`): no network, no DTD loading, no
entity expansion, a size limit, and every problem an
:class:`~pyethercat.errors.EsiError` naming the file, the line and the element.
:class:`XmlReader` holds the typed reads both parsers share; the value helpers
read the spellings real files use (``#x1600``, ``0x1600``, ``5632``, ``true``/``1``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from typing import Any

from lxml import etree

from pyethercat.errors import EsiError

__all__ = [
    "DEFAULT_MAX_BYTES",
    "XmlReader",
    "parse_bool",
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


# --- elements --------------------------------------------------------------


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



# --- typed reads -----------------------------------------------------------


class XmlReader:
    """One document's reads: holds the source name for error messages."""

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

    def need(self, el: _Element, name: str, what: str) -> _Element:
        """The required child element ``name``."""
        c = self.child(el, name)
        if c is None:
            raise self.error(el, f"{what}: missing <{name}>")
        return c

    def child_int(self, el: _Element, name: str, what: str, bits: int | None = None) -> int:
        """A required numeric child element."""
        return self.int_text(self.need(el, name, what), f"{what}/{name}", bits)

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



# --- documents -------------------------------------------------------------


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
