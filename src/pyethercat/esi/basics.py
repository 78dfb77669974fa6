"""The building blocks of the ESI device model: texts per language and data types.

An ESI file names its texts per language (``<Name LcId="1033">``, :class:`Text`)
and its data types the IEC 61131 way (``UDINT``, ``ARRAY [0..3] OF BYTE``);
:func:`type_info` maps such a name to the CANopen data type the CoE codec and
the object dictionary use (ETG.2000 and ETG.1000.6 name the same types).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from pyethercat.wire.mailbox.datatypes import DATA_TYPE_BITS, DataType

__all__ = [
    "BASE_TYPES",
    "ESI_TYPE_NAMES",
    "LCID_ENGLISH",
    "LCID_GERMAN",
    "Text",
    "TypeInfo",
    "type_info",
]

#: LcId of US English, the language ESI tools fall back to.
LCID_ENGLISH = 1033
#: LcId of German, the other language common in vendor files.
LCID_GERMAN = 1031


# --- languages -----------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Text:
    """A text given in one or more languages (ESI ``<Name LcId="1033">``).

    ``items`` keeps file order; an LcId of ``None`` means the file gave none.
    :meth:`pick` chooses one language; ``str(text)`` is the English (or first)
    variant.
    """

    items: tuple[tuple[int | None, str], ...] = ()

    def pick(self, lcid: int | None = LCID_ENGLISH) -> str:
        """The text in language ``lcid``; else English; else untagged; else the first."""
        if not self.items:
            return ""
        for wanted in (lcid, LCID_ENGLISH, None):
            for code, value in self.items:
                if code == wanted:
                    return value
        return self.items[0][1]

    @property
    def languages(self) -> tuple[int | None, ...]:
        """LcIds present, in file order."""
        return tuple(code for code, _ in self.items)

    def __bool__(self) -> bool:
        return bool(self.items)

    def __str__(self) -> str:
        return self.pick()


# --- data types ----------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TypeInfo:
    """CANopen view of an ESI data type name.

    ``code`` is the CANopen data type (``DataType.UNSIGNED32`` for UDINT); ``bit_size``
    is the size of one value (for arrays: of the whole array); ``element`` is
    set for ``ARRAY [..] OF X`` and ``STRING(n)`` with ``count`` elements.
    """

    name: str
    code: DataType
    bit_size: int
    count: int = 1
    element: TypeInfo | None = None


# ESI base type name -> CANopen data type (codes and sizes live in
# wire/mailbox/datatypes.py, shared with the CoE codec). ESI spells types the
# IEC 61131 way (UDINT) and, in some files, the C way (UINT16).
_DT = DataType
BASE_TYPES: Mapping[str, DataType] = {
    "BOOL": _DT.BOOLEAN,
    "BOOLEAN": _DT.BOOLEAN,
    "BIT": _DT.BOOLEAN,
    "SINT": _DT.INTEGER8,
    "INT8": _DT.INTEGER8,
    "INT": _DT.INTEGER16,
    "INT16": _DT.INTEGER16,
    "INT24": _DT.INTEGER24,
    "DINT": _DT.INTEGER32,
    "INT32": _DT.INTEGER32,
    "INT40": _DT.INTEGER40,
    "INT48": _DT.INTEGER48,
    "INT56": _DT.INTEGER56,
    "LINT": _DT.INTEGER64,
    "INT64": _DT.INTEGER64,
    "USINT": _DT.UNSIGNED8,
    "UINT8": _DT.UNSIGNED8,
    "UINT": _DT.UNSIGNED16,
    "UINT16": _DT.UNSIGNED16,
    "UINT24": _DT.UNSIGNED24,
    "UDINT": _DT.UNSIGNED32,
    "UINT32": _DT.UNSIGNED32,
    "UINT40": _DT.UNSIGNED40,
    "UINT48": _DT.UNSIGNED48,
    "UINT56": _DT.UNSIGNED56,
    "ULINT": _DT.UNSIGNED64,
    "UINT64": _DT.UNSIGNED64,
    "REAL": _DT.REAL32,
    "REAL32": _DT.REAL32,
    "FLOAT": _DT.REAL32,
    "LREAL": _DT.REAL64,
    "REAL64": _DT.REAL64,
    "DOUBLE": _DT.REAL64,
    "TIME_OF_DAY": _DT.TIME_OF_DAY,
    "TIME_DIFFERENCE": _DT.TIME_DIFFERENCE,
    "GUID": _DT.GUID,
    "BYTE": _DT.BYTE,
    # WORD/DWORD have no code of their own in the shared table; they carry
    # the same bits as the unsigned types.
    "WORD": _DT.UNSIGNED16,
    "DWORD": _DT.UNSIGNED32,
    "BITARR8": _DT.BITARR8,
    "BITARR16": _DT.BITARR16,
    "BITARR32": _DT.BITARR32,
    **{f"BIT{n}": DataType(_DT.BIT1 + n - 1) for n in range(1, 9)},
}
#: CANopen data type -> the name an ESI/ENI file written by pyethercat uses for
#: it: the first spelling of the code in :data:`BASE_TYPES` (IEC 61131: UINT).
ESI_TYPE_NAMES: Mapping[int, str] = {
    code: name for name, code in reversed(list(BASE_TYPES.items()))
}
# Variable-length types: the size comes with the name (STRING(n)) or the object.
_STRING_CODES: Mapping[str, tuple[DataType, int]] = {
    "STRING": (_DT.VISIBLE_STRING, 8),
    "VISIBLE_STRING": (_DT.VISIBLE_STRING, 8),
    "OCTET_STRING": (_DT.OCTET_STRING, 8),
    "UNICODE_STRING": (_DT.UNICODE_STRING, 16),
}
_STRING_RE = re.compile(r"^\s*(\w+)\s*\(\s*(\d+)\s*\)\s*$")
_ARRAY_RE = re.compile(
    r"^\s*ARRAY\s*\[\s*(-?\d+)\s*\.\.\s*(-?\d+)\s*\]\s*OF\s+(.+?)\s*$", re.IGNORECASE
)


def type_info(name: str) -> TypeInfo | None:
    """Map an ESI type name to its CANopen code and bit size.

    Knows the base names (``UINT``, ``BIT2``, ``UDINT``, ...), ``STRING(n)``
    (and OCTET_STRING/UNICODE_STRING), ``DOMAIN`` (size 0) and
    ``ARRAY [lo..hi] OF X``. Returns ``None`` for names it does not know, such
    as the file's own ``DT1018``-style types (see :meth:`EsiDictionary.type_info`).
    """
    key = name.strip()
    upper = key.upper()
    base = BASE_TYPES.get(upper)
    if base is not None:
        return TypeInfo(key, base, DATA_TYPE_BITS[base])
    if upper == "DOMAIN":
        return TypeInfo(key, DataType.DOMAIN, 0)
    if upper in _STRING_CODES:
        code, unit = _STRING_CODES[upper]
        return TypeInfo(key, code, 0, 0, TypeInfo(upper, code, unit))
    m = _STRING_RE.match(upper)
    if m and m.group(1) in _STRING_CODES:
        code, unit = _STRING_CODES[m.group(1)]
        n = int(m.group(2))
        return TypeInfo(key, code, unit * n, n, TypeInfo(m.group(1), code, unit))
    m = _ARRAY_RE.match(key)
    if m:
        lo, hi = int(m.group(1)), int(m.group(2))
        elem = type_info(m.group(3))
        if elem is None or hi < lo:
            return None
        n = hi - lo + 1
        return TypeInfo(key, elem.code, elem.bit_size * n, n, elem)
    return None
