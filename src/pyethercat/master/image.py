"""The process image: one contiguous buffer per group, PDO entries by name.

A ``ProcessImage`` owns the ``bytearray`` of one group (outputs first, then
inputs, as ``master.config`` lays them out). The cyclic loop copies whole
slices of it into and out of datagrams; nothing on that path looks at single
slaves. Applications reach values three ways:

- by slave and name, decoded by data type::

      slave.inputs["Input 1"]          # -> True / 17 / 3.5
      slave.outputs["Output 1"] = 1

- as raw memory: ``image.outputs`` / ``image.inputs`` (memoryviews),
  ``image.outputs_view()`` / ``image.inputs_view()`` (numpy ``uint8`` arrays
  sharing the buffer), ``image.buffer`` itself;
- as a compiled accessor for hot loops: ``var = image.variable(3, "Input 1")``
  then ``var.get()`` / ``var.set(v)`` skip the name lookup.

Inputs are refreshed only by an exchange that came back whole (every working
counter of the group as expected); otherwise they keep their last good
values and age: ``image.input_age`` (``slave.inputs.age``) counts the
group's exchanges since the last refresh, ``slave.inputs.stale`` says
whether they are old. ``image.safe`` holds the outputs an orderly stop
sends (zero unless set, e.g. ``master.safe_outputs(3)["Output 1"] = 1``).

An image may take its buffer from outside (``ProcessImage(group, buffer=...)``):
the isolated cyclic engine (:mod:`pyethercat.master.engine`) keeps it in
memory shared with the engine's process and gives an :class:`ImageSync`, so
that a value is never read half old, half new and the engine never sends an
output half written. ``with image.writing():`` makes several output writes
one: the engine sends all of them in the same frame or none.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable, Iterator, MutableMapping
from typing import Protocol

import numpy as np
import numpy.typing as npt

from pyethercat.errors import ConfigError
from pyethercat.master.config import GroupConfig, PdoDirection, PdoVariable, ProcessDataConfig
from pyethercat.wire.mailbox.datatypes import DATA_TYPE_BITS, DataType

__all__ = ["ImageSync", "ProcessImage", "SlaveIO", "Variable", "build_images"]

PdoValue = bool | int | float | bytes
#: What an image's buffer may be: its own bytearray, or a view of shared memory.
Buffer = bytearray | memoryview


class ImageSync(Protocol):
    """Access to an image that another process exchanges (see the module text)."""

    def read(self, get: Callable[[], PdoValue]) -> PdoValue:
        """``get()`` over input bytes that no exchange changed meanwhile."""
        ...

    def begin_write(self) -> None:
        """Outputs are being written: the exchange keeps sending the last whole ones."""
        ...

    def end_write(self) -> None:
        """The outputs are whole again."""
        ...

_SIGNED = {DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER24, DataType.INTEGER32,
           DataType.INTEGER40, DataType.INTEGER48, DataType.INTEGER56, DataType.INTEGER64}
_STRUCT_BY_TYPE: dict[tuple[int, int], str] = {
    (DataType.INTEGER8, 8): "<b", (DataType.INTEGER16, 16): "<h",
    (DataType.INTEGER32, 32): "<i", (DataType.INTEGER64, 64): "<q",
    (DataType.REAL32, 32): "<f", (DataType.REAL64, 64): "<d",
}
_STRUCT_UNSIGNED = {8: "<B", 16: "<H", 32: "<I", 64: "<Q"}


def _type_name(code: int) -> str:
    try:
        return DataType(code).name
    except ValueError:
        return f"0x{code:04X}"


class Variable:
    """A PDO entry bound to a buffer: ``get()`` and ``set(value)`` decode and encode it."""

    __slots__ = ("_buf", "_kind", "_struct", "_sync", "bit_length", "bit_offset", "data_type",
                 "info", "_mask", "_nbytes", "_shift", "_start")

    def __init__(self, info: PdoVariable, buffer: Buffer, image_bit_offset: int = 0,
                 sync: ImageSync | None = None) -> None:
        self.info = info
        self._buf = buffer
        self._sync = sync
        self.bit_offset = info.bit_offset - image_bit_offset
        self.bit_length = info.bit_length
        self.data_type = info.data_type
        self._start = self.bit_offset // 8
        self._shift = self.bit_offset % 8
        self._nbytes = (self._shift + self.bit_length + 7) // 8
        self._mask = ((1 << self.bit_length) - 1) << self._shift
        self._struct: struct.Struct | None = None
        code = info.data_type
        try:
            dtype: DataType | None = DataType(code)
        except ValueError:
            dtype = None
        if self._shift == 0 and (code, self.bit_length) in _STRUCT_BY_TYPE:
            self._struct = struct.Struct(_STRUCT_BY_TYPE[(code, self.bit_length)])
            self._kind = "struct"
        elif dtype is DataType.BOOLEAN or (dtype is None and self.bit_length == 1):
            self._kind = "bool"
        elif dtype in (DataType.REAL32, DataType.REAL64):
            self._kind = "real"
        elif dtype in _SIGNED:
            self._kind = "signed"
        elif self.bit_length > 64:
            self._kind = "bytes"
        elif self._shift == 0 and self.bit_length in _STRUCT_UNSIGNED:
            self._struct = struct.Struct(_STRUCT_UNSIGNED[self.bit_length])
            self._kind = "struct"
        else:
            self._kind = "unsigned"
        if (self._kind == "real" and dtype is not None
                and DATA_TYPE_BITS.get(dtype) != self.bit_length):
            # The SII says REAL32 but not 32 bits: trust the bit length.
            self._kind = "unsigned"

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def type_name(self) -> str:
        return _type_name(self.data_type)

    def _raw(self) -> int:
        chunk = self._buf[self._start:self._start + self._nbytes]
        return (int.from_bytes(chunk, "little") & self._mask) >> self._shift

    def get(self) -> PdoValue:
        """The current value, decoded by data type."""
        sync = self._sync
        if sync is not None:
            return sync.read(self._get)
        return self._get()

    def _get(self) -> PdoValue:
        kind = self._kind
        if kind == "struct":
            assert self._struct is not None
            value: PdoValue = self._struct.unpack_from(self._buf, self._start)[0]
            return value
        raw = self._raw()
        if kind == "bool":
            return bool(raw)
        if kind == "signed":
            sign = 1 << (self.bit_length - 1)
            return raw - (sign << 1) if raw & sign else raw
        if kind == "real":
            fmt = "<f" if self.bit_length == 32 else "<d"
            return float(struct.unpack(fmt, raw.to_bytes(self.bit_length // 8, "little"))[0])
        if kind == "bytes":
            return raw.to_bytes((self.bit_length + 7) // 8, "little")
        return raw

    def set(self, value: PdoValue) -> None:
        """Write ``value`` (checked against the type's range) into the buffer."""
        sync = self._sync
        if sync is None:
            self._set(value)
            return
        sync.begin_write()
        try:
            self._set(value)
        finally:
            sync.end_write()

    def _set(self, value: PdoValue) -> None:
        kind = self._kind
        try:
            if kind == "struct":
                assert self._struct is not None
                if isinstance(value, bool) and self._struct.format in ("<f", "<d"):
                    value = float(value)
                self._struct.pack_into(self._buf, self._start, value)
                return
        except struct.error as exc:
            raise ConfigError(f"{self.info.qualified_name}: {value!r} does not fit "
                              f"{self.type_name} ({self.bit_length} bits): {exc}") from None
        raw = self._encode(value)
        if self._shift == 0 and self.bit_length % 8 == 0:
            self._buf[self._start:self._start + self._nbytes] = raw.to_bytes(self._nbytes, "little")
            return
        end = self._start + self._nbytes
        old = int.from_bytes(self._buf[self._start:end], "little")
        new = (old & ~self._mask) | ((raw << self._shift) & self._mask)
        self._buf[self._start:end] = new.to_bytes(self._nbytes, "little")

    def _encode(self, value: PdoValue) -> int:
        bits = self.bit_length
        where = f"{self.info.qualified_name} ({self.type_name}, {bits} bits)"
        if self._kind == "real":
            if isinstance(value, bytes):
                raise ConfigError(f"{where} needs a number, got {value!r}")
            fmt = "<f" if bits == 32 else "<d"
            try:
                return int.from_bytes(struct.pack(fmt, float(value)), "little")
            except (OverflowError, struct.error):
                raise ConfigError(f"{where}: {value!r} does not fit") from None
        if self._kind == "bytes":
            if not isinstance(value, bytes) or len(value) != (bits + 7) // 8:
                raise ConfigError(f"{where} needs {(bits + 7) // 8} bytes, got {value!r}")
            return int.from_bytes(value, "little")
        if isinstance(value, bytes | float) and not (isinstance(value, float) and value.is_integer()):
            raise ConfigError(f"{where} needs an integer, got {value!r}")
        number = int(value)
        if self._kind == "signed":
            lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
            if not lo <= number <= hi:
                raise ConfigError(f"{where}: {number} out of range {lo}..{hi}")
            return number & ((1 << bits) - 1)
        if not 0 <= number < (1 << bits):
            raise ConfigError(f"{where}: {number} out of range 0..{(1 << bits) - 1}")
        return number

    def __repr__(self) -> str:
        return (f"<Variable {self.info.qualified_name} slave {self.info.position} "
                f"{self.type_name}:{self.bit_length} at bit {self.bit_offset} = {self.get()!r}>")


class SlaveIO(MutableMapping[str, PdoValue]):
    """A slave's inputs or outputs by entry name (``"Input 1"``) or ``"PDO.entry"``.

    Entry names that repeat across PDOs (Beckhoff: every channel's entry is
    called ``"Input"``) are reachable by their qualified name
    (``"Channel 1.Input"``), by number in image order (``"Input 1"``), or by
    ``(index, subindex)``.
    Writing inputs is refused.
    """

    def __init__(self, position: int, direction: PdoDirection, variables: list[Variable],
                 image: ProcessImage | None = None) -> None:
        self.position = position
        self.direction = direction
        self._vars = variables
        self._image = image
        self._by_name: dict[str, Variable] = {}
        self._by_object: dict[tuple[int, int], Variable] = {}
        counts: dict[str, int] = {}
        for v in variables:
            counts[v.info.name] = counts.get(v.info.name, 0) + 1
        for v in variables:
            self._by_name[v.info.qualified_name] = v
            self._by_object[(v.info.index, v.info.subindex)] = v
        for v in variables:
            if counts[v.info.name] == 1:
                self._by_name[v.info.name] = v
        # Repeated entry names (every channel's entry is "Input") also answer to
        # "Input 1", "Input 2", ... in image order, unless a real name is taken.
        seen: dict[str, int] = {}
        for v in variables:
            if counts[v.info.name] > 1:
                seen[v.info.name] = seen.get(v.info.name, 0) + 1
                self._by_name.setdefault(f"{v.info.name} {seen[v.info.name]}", v)
        self._primary = [v.info.name if counts[v.info.name] == 1 else v.info.qualified_name
                         for v in variables]

    def variable(self, key: str | tuple[int, int]) -> Variable:
        """The compiled accessor of one entry."""
        found = self._by_object.get(key) if isinstance(key, tuple) else self._by_name.get(key)
        if found is None:
            names = ", ".join(self._primary) or "none"
            shown = f"0x{key[0]:04X}:{key[1]:02X}" if isinstance(key, tuple) else repr(key)
            raise ConfigError(f"slave {self.position} has no {self.direction.value[:-1]} "
                              f"{shown} (its {self.direction.value}: {names})")
        return found

    def __getitem__(self, key: str | tuple[int, int]) -> PdoValue:
        return self.variable(key).get()

    def __setitem__(self, key: str | tuple[int, int], value: PdoValue) -> None:
        if self.direction is PdoDirection.INPUTS:
            raise ConfigError(f"slave {self.position}: inputs are read-only ({key!r})")
        self.variable(key).set(value)

    def __delitem__(self, key: str) -> None:
        raise ConfigError("process-data entries cannot be deleted")

    def __iter__(self) -> Iterator[str]:
        return iter(self._primary)

    def __len__(self) -> int:
        return len(self._vars)

    def __contains__(self, key: object) -> bool:
        if isinstance(key, tuple):
            return key in self._by_object
        return key in self._by_name

    @property
    def age(self) -> int:
        """Exchanges of the slave's group since its inputs were last refreshed (0: fresh)."""
        return self._image.input_age if self._image is not None else 0

    @property
    def stale(self) -> bool:
        """Whether the group's inputs are older than the last exchange (or never came)."""
        img = self._image
        return img is not None and (img.input_age > 0 or not img.inputs_valid)

    def values_dict(self) -> dict[str, PdoValue]:
        """Snapshot of every entry's value."""
        return {name: v.get() for name, v in zip(self._primary, self._vars, strict=True)}

    def __repr__(self) -> str:
        return f"<SlaveIO slave {self.position} {self.direction.value} {self.values_dict()}>"


class ProcessImage:
    """The image of one group: a buffer plus named, typed access.

    ``buffer`` and ``safe`` (``group.size`` bytes each) and ``sync`` come from
    the isolated engine (see the module text); by default the image owns
    bytearrays.
    """

    def __init__(self, group: GroupConfig, buffer: Buffer | None = None,
                 sync: ImageSync | None = None, safe: Buffer | None = None) -> None:
        self.group = group
        self.name = group.name
        for given in (buffer, safe):
            if given is not None and len(given) != group.size:
                raise ConfigError(f"image {group.name!r}: a buffer of {len(given)} bytes for "
                                  f"{group.size}")
        #: The whole image: ``[outputs][inputs][mailbox status]``; datagram data are slices of it.
        self.buffer: Buffer = bytearray(group.size) if buffer is None else buffer
        self.sync = sync
        self.outputs = memoryview(self.buffer)[:group.output_bytes]
        self.inputs = memoryview(self.buffer)[group.output_bytes:group.status_offset]
        #: Outputs sent while an orderly stop runs (same layout as ``buffer``;
        #: only the output bytes matter). Zero unless the application sets values.
        self.safe: Buffer = bytearray(group.size) if safe is None else safe
        #: The group's exchanges since the inputs were last refreshed by a whole one.
        self.input_age = 0
        #: Whether any exchange refreshed the inputs yet.
        self.inputs_valid = False
        self._slave_io: dict[int, tuple[SlaveIO, SlaveIO]] = {}
        self._safe_io: dict[int, SlaveIO] = {}
        for sc in group.slaves:
            outs = [Variable(v, self.buffer, sync=sync) for v in sc.variables
                    if v.direction is PdoDirection.OUTPUTS]
            ins = [Variable(v, self.buffer, sync=sync) for v in sc.variables
                   if v.direction is PdoDirection.INPUTS]
            self._slave_io[sc.position] = (SlaveIO(sc.position, PdoDirection.INPUTS, ins, self),
                                           SlaveIO(sc.position, PdoDirection.OUTPUTS, outs, self))

    @property
    def positions(self) -> list[int]:
        return list(self._slave_io)

    def slave_inputs(self, position: int) -> SlaveIO:
        return self._io(position)[0]

    def slave_outputs(self, position: int) -> SlaveIO:
        return self._io(position)[1]

    def slave_safe_outputs(self, position: int) -> SlaveIO:
        """A slave's outputs in :attr:`safe`: the values an orderly stop sends."""
        io = self._safe_io.get(position)
        if io is None:
            sc = next(s for s in self.group.slaves if s.position == self._known(position))
            io = SlaveIO(position, PdoDirection.OUTPUTS,
                         [Variable(v, self.safe) for v in sc.variables
                          if v.direction is PdoDirection.OUTPUTS], self)
            self._safe_io[position] = io
        return io

    def _known(self, position: int) -> int:
        self._io(position)
        return position

    @property
    def inputs_stale(self) -> bool:
        """Whether the inputs are older than the last exchange (or never came)."""
        return self.input_age > 0 or not self.inputs_valid

    def _io(self, position: int) -> tuple[SlaveIO, SlaveIO]:
        try:
            return self._slave_io[position]
        except KeyError:
            raise ConfigError(f"slave {position} is not in process-data group {self.name!r}") from None

    def variable(self, position: int, key: str | tuple[int, int]) -> Variable:
        """Accessor of an entry of slave ``position`` (inputs searched first, then outputs)."""
        ins, outs = self._io(position)
        if key in ins:
            return ins.variable(key)
        return outs.variable(key)

    def outputs_view(self) -> npt.NDArray[np.uint8]:
        """The outputs as a writable numpy ``uint8`` array sharing the buffer."""
        return np.frombuffer(self.buffer, dtype=np.uint8, count=self.group.output_bytes)

    def inputs_view(self) -> npt.NDArray[np.uint8]:
        """The inputs as a numpy ``uint8`` array sharing the buffer."""
        return np.frombuffer(self.buffer, dtype=np.uint8, count=self.group.input_bytes,
                             offset=self.group.output_bytes)

    def slave_bytes(self, position: int, direction: PdoDirection) -> bytes:
        """The bytes covering a slave's outputs or inputs (packed neighbours included)."""
        sc = next(s for s in self.group.slaves if s.position == position)
        offset = sc.output_bit_offset if direction is PdoDirection.OUTPUTS else sc.input_bit_offset
        bits = sc.output_bits if direction is PdoDirection.OUTPUTS else sc.input_bits
        if offset < 0:
            return b""
        return bytes(self.buffer[offset // 8:(offset + bits + 7) // 8])

    def mailbox_status(self, position: int) -> int | None:
        """SM1 status byte of slave ``position`` as the last cycle read it (None: not mapped)."""
        sc = next((s for s in self.group.slaves if s.position == position), None)
        if sc is None or sc.mailbox_status_offset < 0:
            return None
        return self.buffer[sc.mailbox_status_offset]

    def clear_outputs(self) -> None:
        with self.writing():
            self.buffer[:self.group.output_bytes] = bytes(self.group.output_bytes)

    @contextlib.contextmanager
    def writing(self) -> Iterator[None]:
        """Several output writes as one: an exchange sends all of them or none (see the
        module text; in the loop's own process every write already is one)."""
        sync = self.sync
        if sync is None:
            yield
            return
        sync.begin_write()
        try:
            yield
        finally:
            sync.end_write()

    def snapshot(self) -> bytes:
        """A copy of the whole image taken between two exchanges."""
        sync = self.sync
        if sync is None:
            return bytes(self.buffer)
        got = sync.read(lambda: bytes(self.buffer))
        assert isinstance(got, bytes)
        return got

    def __repr__(self) -> str:
        return (f"<ProcessImage {self.name!r} {self.group.output_bytes} output + "
                f"{self.group.input_bytes} input bytes at 0x{self.group.logical_base:08X}>")


def build_images(config: ProcessDataConfig) -> dict[str, ProcessImage]:
    """One image per group, keyed by group name."""
    return {g.name: ProcessImage(g) for g in config.groups}

