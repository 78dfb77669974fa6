"""Object dictionary of a simulated CoE slave.

An :class:`SimObjectDictionary` holds :class:`SimOdObject` s (object code VAR,
ARRAY or RECORD), each with :class:`SimOdEntry` s: a CANopen data type
(:class:`~pyethercat.wire.mailbox.datatypes.DataType`), access rights per AL
state and PDO-mappable flags (the :class:`~pyethercat.wire.mailbox.coe.ObjectAccess`
bits an entry description reports), a default, an optional value range and a
current value kept as the little-endian bytes an SDO transfer carries.

:meth:`SimObjectDictionary.upload` and :meth:`SimObjectDictionary.download` are what
the CoE server calls: they enforce access rights, lengths and value ranges and
raise :class:`~pyethercat.errors.SdoAbort` with the abort code a real slave
answers (SOES ``soes/esc.h`` ``ABORT_*``). Local code (the device application) reads and writes
values with :meth:`SimObjectDictionary.value` / :meth:`SimObjectDictionary.set_value`,
which skip every check.

Modelling choices (public sources leave these open):

- Complete access covers subindex 0 (as 8 bits plus 8 padding bits, except
  for a VAR) when asked for subindex 0, then every existing entry from 1 up
  to the value of subindex 0, packed bit by bit. Entries that cannot be read
  in the current state read as zeros; a complete-access write may carry an
  unchanged value for a read-only entry (such as subindex 0 of a record).
- Objects holding a variable-length entry (strings, octet strings, domains)
  refuse complete access with 0x06010004.
- An expedited download without size indication (4 data bytes) to a shorter
  fixed-size entry takes the low bytes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field

from pyethercat.errors import MailboxError, SdoAbort
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import (
    ObjectAccess,
    ObjectCode,
    OdListType,
    SdoAbortCode,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.datatypes import DataType, Value, decode_value, encode_value

__all__ = [
    "RO",
    "RW",
    "WO",
    "RW_PREOP",
    "CONST",
    "RXPDO",
    "TXPDO",
    "ObjectHook",
    "SimOdEntry",
    "SimOdObject",
    "SimObjectDictionary",
    "sdo_abort",
]

#: Readable in PREOP, SAFEOP and OP; never writable.
RO = int(ObjectAccess.READ)
#: Constant: same rights as :data:`RO` (the entry description cannot tell them apart).
CONST = RO
#: Readable and writable in PREOP, SAFEOP and OP.
RW = int(ObjectAccess.READ_WRITE)
#: Writable in every state, never readable.
WO = int(ObjectAccess.WRITE)
#: Readable always, writable in PREOP only (PDO mapping and assignment objects).
RW_PREOP = int(ObjectAccess.READ | ObjectAccess.WRITE_PREOP)
#: Flag: the entry may be mapped into an RxPDO (outputs, master -> slave).
RXPDO = int(ObjectAccess.RXPDO_MAPPABLE)
#: Flag: the entry may be mapped into a TxPDO (inputs, slave -> master).
TXPDO = int(ObjectAccess.TXPDO_MAPPABLE)

_READ_BITS = {AlState.SAFEOP: int(ObjectAccess.READ_SAFEOP), AlState.OP: int(ObjectAccess.READ_OP)}
_WRITE_BITS = {AlState.SAFEOP: int(ObjectAccess.WRITE_SAFEOP), AlState.OP: int(ObjectAccess.WRITE_OP)}
_VARIABLE = frozenset({DataType.VISIBLE_STRING, DataType.OCTET_STRING, DataType.UNICODE_STRING,
                       DataType.DOMAIN})
_NUMERIC_SKIP = frozenset({DataType.TIME_OF_DAY, DataType.TIME_DIFFERENCE, DataType.GUID})


def sdo_abort(code: int, index: int, subindex: int, why: str = "") -> SdoAbort:
    """The :class:`SdoAbort` for ``code`` at ``index:subindex`` (``why`` appended to the text)."""
    text = sdo_abort_name(code)
    if why:
        text = f"{text} ({why})"
    return SdoAbort(code, text, index, subindex)


def _read_bit(state: AlState) -> int:
    # Outside PREOP/SAFEOP/OP no SDO traffic reaches the dictionary; treat as PREOP.
    return _READ_BITS.get(state, int(ObjectAccess.READ_PREOP))


def _write_bit(state: AlState) -> int:
    return _WRITE_BITS.get(state, int(ObjectAccess.WRITE_PREOP))


@dataclass(eq=False)
class SimOdEntry:
    """One subindex: type, access, value range, current value (raw bytes).

    ``max_length`` is the capacity in bytes of a variable-length entry
    (strings, octet strings, domains); it gives the bit length the entry
    description reports. ``allowed`` lists the only values accepted
    (anything else: abort 0x06090030); ``minimum``/``maximum`` bound numbers
    (0x06090032/0x06090031). ``on_read`` supplies a live value (e.g. a
    register the application reads through its PDI); ``on_write`` sees an
    accepted value before it is stored and may raise :class:`SdoAbort`.
    """

    subindex: int
    name: str
    data_type: DataType
    access: int = RO
    default: Value | None = None
    minimum: Value | None = None
    maximum: Value | None = None
    allowed: frozenset[int] | None = None
    max_length: int | None = None
    unit: int = 0
    on_read: Callable[[], bytes] | None = None
    on_write: Callable[[bytes], None] | None = None
    raw: bytearray = field(default_factory=bytearray)

    def __post_init__(self) -> None:
        self.subindex = int(self.subindex)  # a SyncSub/IdentitySub member becomes the number
        if not 0 <= self.subindex <= 0xFF:
            raise MailboxError(f"subindex {self.subindex} out of range 0..255")
        self.data_type = DataType(self.data_type)
        size = self.data_type.byte_size
        if size is None and self.max_length is None:
            default = self.default
            self.max_length = len(default) if isinstance(default, (bytes, str)) else 0
        if self.default is None:
            self.raw = bytearray(size or 0)
        else:
            self.raw = bytearray(encode_value(self.data_type, self.default))
            if self.max_length is not None and len(self.raw) > self.max_length:
                raise MailboxError(
                    f"default of {self.name!r} has {len(self.raw)} bytes, capacity {self.max_length}")

    @property
    def variable(self) -> bool:
        """True for strings, octet strings and domains (length not fixed by the type)."""
        return self.data_type.byte_size is None or self.data_type in _VARIABLE

    @property
    def bit_length(self) -> int:
        """Bits of the entry (capacity for variable-length entries)."""
        bits = self.data_type.bit_size
        if bits is not None:
            return bits
        return 8 * (self.max_length or 0)

    @property
    def byte_size(self) -> int | None:
        """Bytes an SDO transfer carries for a fixed-size entry; None when variable."""
        return None if self.variable else self.data_type.byte_size

    def readable(self, state: AlState) -> bool:
        """Readable by SDO in ``state``."""
        return bool(self.access & _read_bit(state))

    def writable(self, state: AlState) -> bool:
        """Writable by SDO in ``state``."""
        return bool(self.access & _write_bit(state))

    def read(self) -> bytes:
        """Current value bytes (the live value when there is an ``on_read`` hook)."""
        if self.on_read is not None:
            return bytes(self.on_read())
        return bytes(self.raw)

    @property
    def value(self) -> Value:
        """Current value, decoded."""
        return decode_value(self.data_type, self.read())

    def check_value(self, raw: bytes, index: int) -> None:
        """Raise :class:`SdoAbort` unless ``raw`` is an acceptable value (length and range)."""
        size = self.byte_size
        sub = self.subindex
        if size is not None:
            if len(raw) > size:
                raise sdo_abort(SdoAbortCode.LENGTH_TOO_HIGH, index, sub,
                                f"{len(raw)} bytes for {self.data_type.name}")
            if len(raw) < size:
                raise sdo_abort(SdoAbortCode.LENGTH_TOO_LOW, index, sub,
                                f"{len(raw)} bytes for {self.data_type.name}")
        elif self.max_length is not None and len(raw) > self.max_length:
            raise sdo_abort(SdoAbortCode.LENGTH_TOO_HIGH, index, sub,
                            f"{len(raw)} bytes, capacity {self.max_length}")
        if self.variable or self.data_type in _NUMERIC_SKIP:
            return
        value = decode_value(self.data_type, raw)
        if self.data_type is DataType.BOOLEAN and raw[0] > 1:
            raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, sub, f"BOOLEAN byte 0x{raw[0]:02X}")
        if (isinstance(value, float) and math.isnan(value)
                and (self.minimum is not None or self.maximum is not None)):
            # NaN compares false with both limits: without this it passes any range.
            raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, sub,
                            f"NaN outside {self.minimum!r}..{self.maximum!r}")
        if self.allowed is not None and value not in self.allowed:
            raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, sub, f"value {value!r} not allowed")
        if self.maximum is not None and value > self.maximum:  # type: ignore[operator]
            raise sdo_abort(SdoAbortCode.VALUE_TOO_HIGH, index, sub,
                            f"{value!r} > maximum {self.maximum!r}")
        if self.minimum is not None and value < self.minimum:  # type: ignore[operator]
            raise sdo_abort(SdoAbortCode.VALUE_TOO_LOW, index, sub,
                            f"{value!r} < minimum {self.minimum!r}")

    def store(self, raw: bytes) -> None:
        """Store an accepted value (runs ``on_write`` first)."""
        if self.on_write is not None:
            self.on_write(raw)
        self.raw = bytearray(raw)


ObjectHook = Callable[["SimOdObject", dict[int, bytes], bool], None]
"""``hook(obj, changes, complete)``: validate (raise :class:`SdoAbort`) or react to writes.

``changes`` maps subindex to the new raw value; ``complete`` is True for a
complete-access write.
"""


@dataclass(eq=False)
class SimOdObject:
    """One object: index, name, object code and its entries by subindex.

    ``check`` runs before a download is stored (after the entry checks), with
    every subindex the download changes; ``after`` runs once it is stored.
    The PDO mapping and assignment rules are such hooks (``sim.coe``).
    """

    index: int
    name: str
    object_code: ObjectCode
    data_type: int
    entries: dict[int, SimOdEntry]
    check: ObjectHook | None = None
    after: ObjectHook | None = None

    def __post_init__(self) -> None:
        self.index = int(self.index)  # a StandardObject member is kept as the plain number
        if not 0 <= self.index <= 0xFFFF:
            raise MailboxError(f"object index {self.index} out of range")
        if 0 not in self.entries:
            raise MailboxError(f"object 0x{self.index:04X} needs a subindex 0")
        self.entries = dict(sorted(self.entries.items()))

    @property
    def max_subindex(self) -> int:
        """Highest subindex (0 for a VAR), as the object description reports it."""
        return 0 if self.object_code == ObjectCode.VAR else max(self.entries)

    @property
    def variable(self) -> bool:
        """True when an entry has a variable length (no complete access)."""
        return any(e.variable for e in self.entries.values())

    def entry(self, subindex: int) -> SimOdEntry:
        """The entry at ``subindex``; :class:`SdoAbort` 0x06090011 if there is none."""
        e = self.entries.get(subindex)
        if e is None:
            raise sdo_abort(SdoAbortCode.NO_SUBINDEX, self.index, subindex)
        return e

    def count(self) -> int:
        """Value of subindex 0 of an ARRAY/RECORD (number of entries in use)."""
        raw = self.entries[0].read()
        return raw[0] if raw else 0

    def copy(self) -> SimOdObject:
        """An independent copy (values copied, no hooks: the copy's owner attaches its own)."""
        # Attribute copies without __post_init__ or copy.copy (a copy per slave
        # of a kind with thousands of instances: this is the cost of each).
        entries = {}
        new_entry = SimOdEntry.__new__
        for sub, e in self.entries.items():
            c = new_entry(SimOdEntry)
            c.__dict__.update(e.__dict__)
            c.raw = bytearray(e.raw)
            c.on_read = c.on_write = None
            entries[sub] = c
        obj = SimOdObject.__new__(SimOdObject)
        obj.__dict__.update(self.__dict__)
        obj.entries = entries
        obj.check = obj.after = None
        return obj

    def ca_entries(self, count: int) -> list[SimOdEntry]:
        """Entries 1..count that exist, in order (what complete access covers)."""
        return [e for s, e in self.entries.items() if 1 <= s <= count]


class SimObjectDictionary:
    """Objects by index, with the SDO access rules (see the module docstring)."""

    def __init__(self) -> None:
        self._objects: dict[int, SimOdObject] = {}
        #: (index, subindex) of entries mapped into the active RxPDOs (set by the PDO layer):
        #: SDO downloads to them are refused in SAFEOP and OP with 0x06010006.
        self.rx_mapped: frozenset[tuple[int, int]] = frozenset()

    def copy(self) -> SimObjectDictionary:
        """An independent copy of every object (a device kind builds one template, copies it per slave)."""
        od = SimObjectDictionary()
        od._objects = {i: o.copy() for i, o in self._objects.items()}
        return od

    # --- building ---------------------------------------------------------------

    def add(self, obj: SimOdObject) -> SimOdObject:
        """Add (or replace) an object."""
        self._objects[obj.index] = obj
        if len(self._objects) > 1 and obj.index < max(self._objects):
            self._objects = dict(sorted(self._objects.items()))
        return obj

    def var(self, index: int, name: str, data_type: DataType, access: int = RO,
            default: Value | None = None, **kw: object) -> SimOdObject:
        """Add a VAR object (its value is subindex 0); ``kw`` goes to :class:`SimOdEntry`."""
        entry = SimOdEntry(0, name, data_type, access, default, **kw)  # type: ignore[arg-type]
        return self.add(SimOdObject(index, name, ObjectCode.VAR, int(data_type), {0: entry}))

    def array(self, index: int, name: str, data_type: DataType, values: Iterable[Value],
              access: int = RO, *, count_access: int = RO, length: int | None = None,
              names: Iterable[str] | None = None, **kw: object) -> SimOdObject:
        """Add an ARRAY: subindex 0 = count (UNSIGNED8), subindex n = ``values[n-1]``.

        ``length`` defines more subindices than ``values`` fills (the rest get
        the type's zero); subindex 0 starts at ``len(values)``.
        """
        vals = list(values)
        total = max(len(vals), length or 0)
        labels = list(names) if names is not None else []
        entries = {0: SimOdEntry(0, "Number of entries", DataType.UNSIGNED8, count_access, len(vals),
                              maximum=total)}
        for n in range(1, total + 1):
            label = labels[n - 1] if n - 1 < len(labels) else f"SubIndex {n:03d}"
            default = vals[n - 1] if n - 1 < len(vals) else None
            entries[n] = SimOdEntry(n, label, data_type, access, default, **kw)  # type: ignore[arg-type]
        return self.add(SimOdObject(index, name, ObjectCode.ARRAY, int(data_type), entries))

    def record(self, index: int, name: str, entries: Iterable[SimOdEntry],
               data_type: int = 0, count_access: int = RO) -> SimOdObject:
        """Add a RECORD; subindex 0 (UNSIGNED8, the highest subindex) is added for you."""
        subs = {e.subindex: e for e in entries}
        if 0 in subs:
            raise MailboxError(f"record 0x{index:04X}: subindex 0 is generated")
        top = max(subs) if subs else 0
        subs[0] = SimOdEntry(0, "Number of entries", DataType.UNSIGNED8, count_access, top)
        return self.add(SimOdObject(index, name, ObjectCode.RECORD, data_type, subs))

    # --- lookup -------------------------------------------------------------------

    def __contains__(self, index: object) -> bool:
        return index in self._objects

    def __iter__(self) -> Iterator[SimOdObject]:
        return iter(self._objects.values())

    def __len__(self) -> int:
        return len(self._objects)

    def get(self, index: int) -> SimOdObject:
        """The object at ``index``; :class:`SdoAbort` 0x06020000 if there is none."""
        obj = self._objects.get(index)
        if obj is None:
            raise sdo_abort(SdoAbortCode.NO_OBJECT, index, 0)
        return obj

    def find(self, index: int) -> SimOdObject | None:
        """The object at ``index`` or None."""
        return self._objects.get(index)

    def entry(self, index: int, subindex: int) -> SimOdEntry:
        """The entry ``index:subindex`` (aborts 0x06020000 / 0x06090011)."""
        return self.get(index).entry(subindex)

    def value(self, index: int, subindex: int = 0) -> Value:
        """Current value of an entry, decoded (no access check)."""
        return self.entry(index, subindex).value

    def set_value(self, index: int, subindex: int, value: Value) -> None:
        """Set an entry's value from local code (no access or range check, no hooks)."""
        e = self.entry(index, subindex)
        e.raw = bytearray(encode_value(e.data_type, value))

    def indices(self, list_type: int) -> tuple[int, ...]:
        """Object indices of an OD list (list type 0 gives the five list lengths; SOES ``esc_coe.c``)."""
        if list_type == OdListType.LENGTHS:
            return tuple(len(self.indices(t)) for t in range(1, 6))
        flags: dict[int, int] = {
            OdListType.ALL: 0,
            OdListType.RXPDO_MAPPABLE: int(ObjectAccess.RXPDO_MAPPABLE),
            OdListType.TXPDO_MAPPABLE: int(ObjectAccess.TXPDO_MAPPABLE),
            OdListType.BACKUP: int(ObjectAccess.BACKUP),
            OdListType.SETTINGS: int(ObjectAccess.SETTINGS),
        }
        flag = flags.get(list_type)
        if flag is None:
            raise sdo_abort(SdoAbortCode.VALUE_RANGE, 0, 0, f"OD list type {list_type}")
        if flag == 0:
            return tuple(self._objects)
        return tuple(i for i, o in self._objects.items()
                     if any(e.access & flag for e in o.entries.values()))

    # --- SDO access ---------------------------------------------------------------

    def upload(self, index: int, subindex: int, state: AlState,
               complete_access: bool = False) -> bytes:
        """Bytes an SDO upload returns; raises :class:`SdoAbort`."""
        obj = self.get(index)
        if complete_access:
            return self._ca_upload(obj, subindex, state)
        e = obj.entry(subindex)
        if not e.readable(state):
            code = (SdoAbortCode.DEVICE_STATE if e.access & int(ObjectAccess.READ)
                    else SdoAbortCode.WRITE_ONLY)
            raise sdo_abort(code, index, subindex, f"in {state.name}")
        return e.read()

    def check_download(self, index: int, subindex: int, size: int | None, state: AlState,
                       complete_access: bool = False) -> None:
        """Checks a download's initiate frame allows (object, access, announced size)."""
        obj = self.get(index)
        if complete_access:
            self._ca_target(obj, subindex)
            return
        e = obj.entry(subindex)
        self._check_writable(obj, e, state)
        if size is None:
            return
        fixed = e.byte_size
        if fixed is not None and size != fixed:
            code = SdoAbortCode.LENGTH_TOO_HIGH if size > fixed else SdoAbortCode.LENGTH_TOO_LOW
            raise sdo_abort(code, index, subindex, f"{size} bytes for {e.data_type.name}")
        if fixed is None and e.max_length is not None and size > e.max_length:
            raise sdo_abort(SdoAbortCode.LENGTH_TOO_HIGH, index, subindex,
                            f"{size} bytes, capacity {e.max_length}")

    def download(self, index: int, subindex: int, data: bytes, state: AlState,
                 complete_access: bool = False, size_indicated: bool = True,
                 expedited: bool = False) -> None:
        """Store an SDO download; raises :class:`SdoAbort` and then stores nothing.

        Without size indication an expedited download carries 4 bytes (the low
        ones count); a normal one whose length does not fit a fixed-size entry
        aborts with 0x06070010 (with size indication: 0x06070012/0x06070013).
        """
        obj = self.get(index)
        if complete_access:
            self._ca_download(obj, subindex, bytes(data), state)
            return
        e = obj.entry(subindex)
        self._check_writable(obj, e, state)
        raw = bytes(data)
        size = e.byte_size
        if not size_indicated and size is not None and len(raw) != size:
            if not (expedited and len(raw) > size):
                raise sdo_abort(SdoAbortCode.LENGTH_MISMATCH, index, subindex,
                                f"{len(raw)} bytes for {e.data_type.name}")
            raw = raw[:size]
        e.check_value(raw, index)
        changes = {subindex: raw}
        if obj.check is not None:
            obj.check(obj, changes, False)
        e.store(raw)
        if obj.after is not None:
            obj.after(obj, changes, False)

    def _check_writable(self, obj: SimOdObject, e: SimOdEntry, state: AlState) -> None:
        if not e.writable(state):
            code = (SdoAbortCode.DEVICE_STATE if e.access & int(ObjectAccess.WRITE)
                    else SdoAbortCode.READ_ONLY)
            raise sdo_abort(code, obj.index, e.subindex, f"in {state.name}")
        if state in (AlState.SAFEOP, AlState.OP) and (obj.index, e.subindex) in self.rx_mapped:
            raise sdo_abort(SdoAbortCode.MAPPED_TO_RXPDO, obj.index, e.subindex)

    # --- complete access ------------------------------------------------------------

    def _ca_target(self, obj: SimOdObject, subindex: int) -> None:
        if subindex not in (0, 1):
            raise sdo_abort(SdoAbortCode.UNSUPPORTED_ACCESS, obj.index, subindex,
                            "complete access needs subindex 0 or 1")
        if obj.variable:
            raise sdo_abort(SdoAbortCode.CA_VARIABLE_LENGTH, obj.index, subindex)

    def _ca_upload(self, obj: SimOdObject, subindex: int, state: AlState) -> bytes:
        self._ca_target(obj, subindex)
        if obj.object_code == ObjectCode.VAR:
            return self.upload(obj.index, 0, state)
        acc = 0
        pos = 0
        if subindex == 0:
            acc = obj.count()
            pos = 16  # subindex 0 travels as 16 bits (SOES esc_coe.c SDO_upload_complete_access)
        for e in obj.ca_entries(obj.count()):
            bits = e.bit_length
            if e.readable(state):
                raw = e.read()
                acc |= (int.from_bytes(raw, "little") & ((1 << bits) - 1)) << pos
            pos += bits
        return acc.to_bytes((pos + 7) // 8, "little")

    def _ca_download(self, obj: SimOdObject, subindex: int, data: bytes, state: AlState) -> None:
        self._ca_target(obj, subindex)
        if obj.object_code == ObjectCode.VAR:
            self.download(obj.index, 0, data, state)
            return
        changes: dict[int, bytes] = {}
        pos = 0
        if subindex == 0:
            if not data:
                raise sdo_abort(SdoAbortCode.LENGTH_TOO_LOW, obj.index, 0, "no data")
            changes[0] = data[:1]
            count = data[0]
            pos = 16
            if obj.entries[0].writable(state):
                obj.entries[0].check_value(changes[0], obj.index)  # the count first
        else:
            count = obj.count()
        entries = obj.ca_entries(count)
        need = pos + sum(e.bit_length for e in entries)
        have = 8 * len(data)
        if have > (need + 7) // 8 * 8:
            raise sdo_abort(SdoAbortCode.LENGTH_TOO_HIGH, obj.index, subindex,
                            f"{len(data)} bytes, object has {(need + 7) // 8}")
        if have < need:
            raise sdo_abort(SdoAbortCode.LENGTH_TOO_LOW, obj.index, subindex,
                            f"{len(data)} bytes, object has {(need + 7) // 8}")
        bits_all = int.from_bytes(data, "little")
        for e in entries:
            bits = e.bit_length
            value = (bits_all >> pos) & ((1 << bits) - 1)
            size = e.byte_size or (bits + 7) // 8
            changes[e.subindex] = value.to_bytes(size, "little")
            pos += bits
        for sub, raw in changes.items():
            e = obj.entries[sub]
            if not e.writable(state):
                if raw == e.read()[: len(raw)].ljust(len(raw), b"\x00"):
                    continue  # an unchanged read-only value rides along
                self._check_writable(obj, e, state)
            elif (obj.index, sub) in self.rx_mapped and state in (AlState.SAFEOP, AlState.OP):
                raise sdo_abort(SdoAbortCode.MAPPED_TO_RXPDO, obj.index, sub)
            e.check_value(raw, obj.index)
        if obj.check is not None:
            obj.check(obj, changes, True)
        for sub, raw in changes.items():
            e = obj.entries[sub]
            if e.writable(state):
                e.store(raw)
        if obj.after is not None:
            obj.after(obj, changes, True)

    def describe(self) -> Mapping[int, SimOdObject]:
        """Read-only view of the objects by index (for documentation and tests)."""
        return dict(self._objects)
