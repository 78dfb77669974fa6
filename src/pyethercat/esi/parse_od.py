"""ESI XML -> the object dictionary of a device (``<Profile>``, ``<Dictionary>``).

The ``<Dictionary>`` of an ESI profile (ETG.2000, the object dictionary part)
lists the device's data types and CoE objects; the master reads it to know a
drive's objects without SDO Information, the simulator to build a device's
object dictionary. :class:`DictionaryReader` is the part of the ESI parse
(:mod:`pyethercat.esi.parse`) that reads it.
"""

from __future__ import annotations

from pyethercat.esi.basics import Text
from pyethercat.esi.model import (
    EsiDataType,
    EsiDictionary,
    EsiFlags,
    EsiObject,
    EsiObjectSubItem,
    EsiProfile,
    EsiSubItemType,
    EsiValueInfo,
)
from pyethercat.esi.xmlread import XmlReader, _Element, _kids, _line, _text, parse_int

__all__ = ["DictionaryReader"]


class DictionaryReader(XmlReader):
    """Reads texts per language and the object dictionary of an ESI profile."""

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

