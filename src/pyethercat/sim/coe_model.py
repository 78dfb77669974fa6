"""Process data of CoE devices as arrays: one device model per CoE device kind.

A CoE slave's process data are the values of the objects its PDOs map
(``sim.pdo_mapping``). :class:`CoeModel` keeps those values for all
instances of a kind in one array, the *object image*: a row per instance, a
fixed byte range per object entry a PDO may map (and per entry the kind's
behaviour reads). Each instance has its own object dictionary and CoE server
for SDO traffic (rare events); the dictionary's image entries read and write
the image, so an SDO upload of an input object returns the value the last
cycle computed, and an SDO download of a parameter reaches the behaviour.

Per frame, for the instances whose output buffer completed, grouped by PDO
layout (instances of a kind usually share one):

1. one gather of their output buffers (``sim.pdio.ProcessIo.outputs``) and
   one scatter into the image (bit-sized entries: a few more operations);
2. :meth:`CoeModel.compute`: the kind's behaviour, numpy over image columns
   (:meth:`CoeModel.field` gives a typed column);
3. one gather of the input entries from the image and one scatter into the
   input buffers (``ProcessIo.set_inputs``).

A kind without behaviour on outputs (``output_events = False``, the default)
does nothing per frame: an SDO read of an object mapped into its RxPDOs
takes the value from the output buffer then; its inputs are published when
the instance enters SAFEOP.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from pyethercat.sim.cache import ArrayKeyCache
from pyethercat.sim.coe import CoeServer
from pyethercat.sim.mailbox import MailboxDevice
from pyethercat.sim.model import DeviceModel
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.sim.pdio import ProcessIo
from pyethercat.sim.pdo_mapping import MappedEntry, PdoMapping
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.coe import ObjectAccess
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.mailbox.objects import StandardObject, SyncSub
from pyethercat.wire.sii import SiiInfo

__all__ = ["CoeModel"]

I64 = npt.NDArray[np.int64]
U8 = npt.NDArray[np.uint8]
Key = tuple[int, int]
_EMPTY = np.zeros(0, np.int64)

#: numpy types of the CoE basic data types (little endian), for typed image columns.
_NUMPY: dict[DataType, str] = {
    DataType.BOOLEAN: "u1", DataType.INTEGER8: "i1", DataType.INTEGER16: "<i2",
    DataType.INTEGER32: "<i4", DataType.INTEGER64: "<i8", DataType.UNSIGNED8: "u1",
    DataType.UNSIGNED16: "<u2", DataType.UNSIGNED32: "<u4", DataType.UNSIGNED64: "<u8",
    DataType.REAL32: "<f4", DataType.REAL64: "<f8",
}
_MAPPABLE = int(ObjectAccess.RXPDO_MAPPABLE | ObjectAccess.TXPDO_MAPPABLE)
_ACTIVE = (AlState.SAFEOP, AlState.OP)
_CYCLE_TIME: Key = (int(StandardObject.SM_OUTPUT_SYNC), int(SyncSub.CYCLE_TIME))


@dataclass(frozen=True)
class _Field:
    offset: int
    size: int
    dtype: str | None


class _BitCopy:
    """Bits moved between a buffer and the image: (source byte, shift) -> (target byte, shift),
    OR-combined per target byte."""

    __slots__ = ("src", "src_shift", "dst_shift", "targets", "order", "starts", "single")

    def __init__(self, bits: list[tuple[int, int, int, int]]) -> None:
        src, ssh, dst, dsh = (np.array(c, np.int64) for c in zip(*bits, strict=True))
        order = np.argsort(dst, kind="stable")
        self.src, self.src_shift = src[order], ssh[order].astype(np.uint8)
        self.dst_shift = dsh[order].astype(np.uint8)
        dst = dst[order]
        first = np.ones(len(dst), bool)
        first[1:] = dst[1:] != dst[:-1]
        self.starts = np.nonzero(first)[0]
        self.targets = dst[first]
        self.order = order
        self.single = len(self.targets) == len(dst)

    def values(self, source: U8) -> U8:
        """(rows, targets) bytes assembled from the bits of ``source`` (rows, bytes)."""
        vals = (((source[:, self.src] >> self.src_shift) & 1) << self.dst_shift).astype(np.uint8)
        if self.single:
            return vals
        out: U8 = np.bitwise_or.reduceat(vals, self.starts, axis=1)
        return out


class _Layout:
    """How one PDO layout moves between the buffers and the image."""

    def __init__(self, outputs: tuple[MappedEntry, ...], inputs: tuple[MappedEntry, ...],
                 fields: dict[Key, _Field]) -> None:
        self.out_len = (sum(m.bits for m in outputs) + 7) // 8
        self.in_len = (sum(m.bits for m in inputs) + 7) // 8
        self.rx_keys = frozenset((m.index, m.subindex) for m in outputs if m.entry is not None)
        self.tx_keys = frozenset((m.index, m.subindex) for m in inputs if m.entry is not None)
        # outputs: buffer -> image; inputs: image -> buffer
        self.out_buf, self.out_img, out_bits = self._plan(outputs, fields, True)
        self.in_buf, self.in_img, in_bits = self._plan(inputs, fields, False)
        self.out_bits = _BitCopy(out_bits) if out_bits else None
        self.in_bits = _BitCopy(in_bits) if in_bits else None
        #: Every input byte comes from one image byte, in buffer order (one gather).
        self.in_direct = not in_bits and np.array_equal(self.in_buf, np.arange(self.in_len))

    @staticmethod
    def _plan(entries: tuple[MappedEntry, ...], fields: dict[Key, _Field],
              outputs: bool) -> tuple[I64, I64, list[tuple[int, int, int, int]]]:
        buf: list[int] = []
        img: list[int] = []
        bits: list[tuple[int, int, int, int]] = []
        for m in entries:
            f = fields.get((m.index, m.subindex)) if m.entry is not None else None
            if f is None:
                continue  # a gap (or an entry the image lacks): zeros in, ignored out
            if m.bit_offset % 8 == 0 and m.bits % 8 == 0 and m.bits // 8 <= f.size:
                n, b0 = m.bits // 8, m.bit_offset // 8
                buf.extend(range(b0, b0 + n))
                img.extend(range(f.offset, f.offset + n))
                continue
            for i in range(min(m.bits, 8 * f.size)):
                b = m.bit_offset + i
                pair = ((b >> 3, b & 7, f.offset + i // 8, i % 8) if outputs
                        else (f.offset + i // 8, i % 8, b >> 3, b & 7))
                bits.append(pair)
        return np.array(buf, np.int64), np.array(img, np.int64), bits


class _Group:
    """Instances sharing one layout, with their index arrays (cached per instance set).

    ``out_src``/``out_dst`` move the mapped output bytes from the PDI's buffers
    straight into the image (one gather, one scatter), ``in_src``/``in_dst`` the
    input entries from the image into the input buffers: flat indices fused
    from the layout and the SM positions (``ProcessIo.plan``) while ``version``
    is the ProcessIo's; None where the layout or a buffer needs the general path
    (bit-sized entries, gaps, a buffer not enabled)."""

    __slots__ = ("layout", "rows", "slaves", "full", "version", "out_src", "out_dst",
                 "in_src", "in_dst", "in_status")

    def __init__(self, layout: _Layout, rows: I64, slaves: I64, full: bool) -> None:
        self.layout = layout
        self.rows = rows
        self.slaves = slaves
        self.full = full
        self.version = -1
        self.out_src: I64 | None = None
        self.out_dst: I64 | None = None
        self.in_src: I64 | None = None
        self.in_dst: I64 | None = None
        self.in_status: I64 = _EMPTY

    def fuse(self, io: ProcessIo, width: int) -> None:
        """The fused index arrays for the SM configuration of ``io`` now."""
        lay = self.layout
        self.version = io.version
        self.out_src = self.out_dst = self.in_src = self.in_dst = None
        base = self.rows[:, None] * width
        if lay.out_len and lay.out_bits is None:
            g = io.plan(self.slaves, lay.out_len, True)
            if g.all_valid:
                self.out_src = g.idx[:, lay.out_buf].ravel()
                self.out_dst = (base + lay.out_img).ravel()
        if lay.in_len and lay.in_direct:
            g = io.plan(self.slaves, lay.in_len, False)
            if g.all_valid:
                self.in_src = (base + lay.in_img).ravel()
                self.in_dst = g.idx.ravel()
                self.in_status = g.status


class CoeModel(DeviceModel):
    """Process data of one CoE device kind for all its instances (see the module docstring).

    ``dictionary(info, app)`` builds one instance's object dictionary (``app``
    is the instance's mailbox device, for objects that read the ESC through
    its PDI); ``details`` are the SII CoE details the kind announces;
    ``capacity_out``/``capacity_in`` the largest SM2/SM3 buffers it takes.
    ``fields`` names entries beyond the mappable ones that :meth:`compute`
    reads (parameters): they get image columns too.
    """

    def __init__(self, dictionary: Callable[[SiiInfo, MailboxDevice], SimObjectDictionary], *,
                 details: int, capacity_out: int = 128, capacity_in: int = 128,
                 fields: Iterable[Key] = ()) -> None:
        super().__init__()
        self.dictionary = dictionary
        self.details = details
        self.capacity_out = capacity_out
        self.capacity_in = capacity_in
        self._extra = tuple(fields)
        self.fields: dict[Key, _Field] = {}
        self.width = 0
        self.image: U8 = np.zeros((0, 0), np.uint8)
        #: The image as one flat view (the fused index arrays address it).
        self._flat: U8 = self.image.reshape(-1)
        self._views: dict[Key, npt.NDArray[Any]] = {}
        self._column_sets: dict[tuple[Key, ...], tuple[npt.NDArray[Any], ...]] = {}
        self._live_columns: dict[tuple[Key, ...], tuple[npt.NDArray[Any], ...]] = {}
        self.layout_id = self.array("layout_id", np.int32, -1)
        self.last_out_ns = self.array("last_out_ns", np.int64, -1)
        self.prev_out_ns = self.array("prev_out_ns", np.int64, -1)
        self.apps: list[MailboxDevice] = []
        self._mappings: list[PdoMapping] = []
        self._layouts: list[_Layout] = []
        self._layout_ids: dict[tuple[Any, ...], int] = {}
        self._groups: ArrayKeyCache[tuple[_Group, ...]] = ArrayKeyCache(256)

    # --- instances ---------------------------------------------------------------------

    def instance_app(self, info: SiiInfo) -> tuple[int, MailboxDevice]:
        """A new instance: its mailbox device with a CoE server on its own dictionary."""
        instance = self.new_instance()
        app = self.new_app(instance)
        od = self.dictionary(info, app)
        if not self.fields:
            self._define_fields(od)
        mapping = PdoMapping(od, capacity_out=self.capacity_out, capacity_in=self.capacity_in,
                             on_change=partial(self._layout_changed, instance))
        app.layout = mapping
        app.add_protocol(CoeServer(od, app.sender(MailboxType.COE), app.al_state,
                                   lambda: app.mailbox_sizes()[1], self.details))
        self.apps.append(app)
        self._mappings.append(mapping)
        self._hook(instance, od)
        self._layout_changed(instance)
        return instance, app

    def new_app(self, instance: int) -> MailboxDevice:
        """The mailbox device of a new instance (a kind with its own AL checks returns a subclass)."""
        return MailboxDevice()

    def _define_fields(self, od: SimObjectDictionary) -> None:
        """Image columns: every PDO-mappable entry and the declared ones, in dictionary order."""
        offset = 0
        wanted = set(self._extra)
        for obj in od:
            for sub, e in obj.entries.items():
                key = (obj.index, sub)
                if not (e.access & _MAPPABLE or key in wanted) or e.variable:
                    continue
                size = e.byte_size or 1
                if size in (2, 4, 8):
                    offset += -offset % size
                self.fields[key] = _Field(offset, size, _NUMPY.get(e.data_type))
                offset += size
        # Aligned columns (each entry at a multiple of its size, rows a multiple of 8
        # bytes): numpy's loops take unaligned data through a buffer, at about twice
        # the cost per call.
        self.width = max(8, offset + -offset % 8)
        self.image = np.zeros((len(self.slaves), self.width), np.uint8)
        self._flat = self.image.reshape(-1)

    def _grow(self, capacity: int) -> None:
        super()._grow(capacity)
        image = np.zeros((capacity, self.width), np.uint8)
        image[: len(self.image)] = self.image
        self.image = image
        self._flat = image.reshape(-1)
        self._views.clear()
        self._column_sets.clear()
        self._live_columns.clear()
        self._groups.clear()

    def _hook(self, instance: int, od: SimObjectDictionary) -> None:
        """The instance's image entries read and write its image row."""
        for (index, sub), f in self.fields.items():
            obj = od.find(index)
            e = obj.entries.get(sub) if obj is not None else None
            if e is None:
                continue
            raw = bytes(e.raw[: f.size]).ljust(f.size, b"\x00")
            self.image[instance, f.offset: f.offset + f.size] = np.frombuffer(raw, np.uint8)
            e.on_read = partial(self._read, instance, (index, sub))
            e.on_write = partial(self._write, instance, (index, sub))
        sync = od.find(_CYCLE_TIME[0])
        if sync is not None and _CYCLE_TIME[1] in sync.entries:
            sync.entries[_CYCLE_TIME[1]].on_read = partial(self._cycle_time, instance)

    def _read(self, instance: int, key: Key) -> bytes:
        io = self.io
        if (not self.output_events and io is not None and io.has_outputs(int(self.slaves[instance]))
                and key in self._layouts[self.layout_id[instance]].rx_keys):
            self._unpack(np.array([instance], np.int64))  # the outputs, read when asked
        f = self.fields[key]
        return self.image[instance, f.offset: f.offset + f.size].tobytes()

    def _write(self, instance: int, key: Key, raw: bytes) -> None:
        f = self.fields[key]
        data = bytes(raw[: f.size]).ljust(f.size, b"\x00")
        self.image[instance, f.offset: f.offset + f.size] = np.frombuffer(data, np.uint8)

    def _cycle_time(self, instance: int) -> bytes:
        last, prev = int(self.last_out_ns[instance]), int(self.prev_out_ns[instance])
        cycle = max(0, min(last - prev, 0xFFFFFFFF)) if prev >= 0 else 0
        return cycle.to_bytes(4, "little")

    def _layout_changed(self, instance: int) -> None:
        mapping = self._mappings[instance]

        def shape(entries: tuple[MappedEntry, ...]) -> tuple[tuple[int, int, int, int], ...]:
            return tuple((m.index if m.entry is not None else 0, m.subindex, m.bit_offset, m.bits)
                         for m in entries)

        key = (shape(mapping.outputs), shape(mapping.inputs))
        lid = self._layout_ids.get(key)
        if lid is None:
            lid = self._layout_ids[key] = len(self._layouts)
            self._layouts.append(_Layout(mapping.outputs, mapping.inputs, self.fields))
        self.layout_id[instance] = lid
        self._groups.clear()

    # --- typed image columns -------------------------------------------------------------

    def field(self, index: int, subindex: int) -> npt.NDArray[Any]:
        """The values of entry ``index:subindex`` of all instances, as a typed writable column."""
        key = (index, subindex)
        view = self._views.get(key)
        if view is None:
            f = self.fields[key]
            if f.dtype is None:
                raise KeyError(f"0x{index:04X}:{subindex:02X} has no numeric type")
            view = self.image[:, f.offset: f.offset + f.size].view(f.dtype)[:, 0]
            self._views[key] = view
        return view

    def fields_of(self, keys: tuple[Key, ...]) -> tuple[npt.NDArray[Any], ...]:
        """The columns of several entries (:meth:`field` each), looked up once and cached:
        a ``compute`` that names its entries in a constant tuple pays one lookup per frame."""
        cols = self._column_sets.get(keys)
        if cols is None:
            cols = self._column_sets[keys] = tuple(self.field(i, s) for i, s in keys)
        return cols

    def live_fields(self, keys: tuple[Key, ...]) -> tuple[npt.NDArray[Any], ...]:
        """:meth:`fields_of` cut to the instances there are (rows ``0..count-1``): for a
        ``compute`` over every instance, which then needs no index at all."""
        n = self.count
        cols = self._live_columns.get(keys)
        if cols is None or len(cols[0]) != n:
            cols = self._live_columns[keys] = tuple(c[:n] for c in self.fields_of(keys))
        return cols

    def rows(self, instances: I64) -> I64 | slice:
        """``instances`` as an index: a slice when it is every instance (views, not copies)."""
        n = len(instances)
        return slice(0, n) if n == self.count else instances

    # --- the frame path ----------------------------------------------------------------------

    def _grouped(self, instances: I64) -> tuple[_Group, ...]:
        groups = self._groups.get(instances)
        if groups is None:
            lids = self.layout_id[instances]
            out = []
            for lid in np.unique(lids).tolist():
                rows = np.sort(instances[lids == lid])
                full = len(rows) == self.count  # (unique instances: all of them, in order)
                out.append(_Group(self._layouts[lid], rows, self.slaves[rows], full))
            groups = tuple(out)
            self._groups.put(instances, groups)
        return groups

    def _unpack(self, instances: I64) -> tuple[_Group, ...]:
        """Output buffers of ``instances`` into the image."""
        io = self.io
        groups = self._grouped(instances)
        if io is None:
            return groups
        for g in groups:
            lay = g.layout
            if not lay.out_len:
                continue
            if g.version != io.version:
                g.fuse(io, self.width)
            if g.out_src is not None:
                self._flat[g.out_dst] = io.memory.shadow_flat[g.out_src]
                continue
            out = io.outputs(g.slaves, lay.out_len)
            rows: I64 | slice = slice(0, self.count) if g.full else g.rows[:, None]
            if len(lay.out_img):
                self.image[rows, lay.out_img] = out[:, lay.out_buf]
            if lay.out_bits is not None:
                self.image[rows, lay.out_bits.targets] = lay.out_bits.values(out)
        return groups

    def publish(self, instances: I64) -> None:
        """Input entries of ``instances`` from the image into their input buffers."""
        io = self.io
        if io is None:
            return
        for g in self._grouped(instances):
            lay = g.layout
            if not lay.in_len:
                continue
            if g.version != io.version:
                g.fuse(io, self.width)
            if g.in_src is not None:
                io.memory.flat[g.in_dst] = self._flat[g.in_src]
                io.inputs_written(g.in_status)
                continue
            img = self.image[: self.count] if g.full else self.image[g.rows]
            if lay.in_direct:
                data = img[:, lay.in_img]
            else:
                data = np.zeros((len(g.rows), lay.in_len), np.uint8)
                if len(lay.in_img):
                    data[:, lay.in_buf] = img[:, lay.in_img]
                if lay.in_bits is not None:
                    data[:, lay.in_bits.targets] = lay.in_bits.values(img)
            io.set_inputs(g.slaves, data)

    def on_outputs(self, instances: I64) -> None:
        self._unpack(instances)
        if self.io is not None:
            now = self.io.now_ns()
            if len(instances) == self.count:
                # Every instance: the arrays trade places (one fill, no copy).
                self.prev_out_ns, self.last_out_ns = self.last_out_ns, self.prev_out_ns
                self.last_out_ns[: self.count] = now
            else:
                self.prev_out_ns[instances] = self.last_out_ns[instances]
                self.last_out_ns[instances] = now
        self.compute(instances)
        self.publish(instances)

    def compute(self, instances: I64) -> None:
        """The kind's behaviour: input entries from output entries and parameters (override)."""

    def on_state_change(self, instance: int, old: AlState, new: AlState) -> None:
        if new in _ACTIVE and old not in _ACTIVE:
            one = np.array([instance], np.int64)
            self.last_out_ns[instance] = self.prev_out_ns[instance] = -1
            if self.output_events:
                self.compute(one)
            self.publish(one)
