"""PDO mapping of a simulated CoE slave: the mapping and assignment objects define the process data.

:class:`PdoMapping` makes the mapping objects real (CiA 301 PDO mapping;
IEC 61158-6-12 5.6.7, as gatorcat ``mailbox/coe.zig`` and SOES
``soes/esc_coe.c`` implement them):
0x1C12/0x1C13 (PDO assignment of SM2/SM3) and 0x1600.../0x1A00... (PDO
mapping) define the process-data layout. They are writable in PREOP only,
follow the CiA 301 sequence (write subindex 0 = 0, write the entries, write
subindex 0 = n) and are validated (mapped object exists, is mappable in that
direction, bit length matches, the SM buffer is large enough). The resulting
byte sizes are what the ESC compares with the SM2/SM3 lengths on PREOP ->
SAFEOP (``DeviceApp.process_data_sizes``); the layout (:attr:`PdoMapping.outputs`,
:attr:`PdoMapping.inputs`) is how a device model moves outputs into its
object values and input values into the SM3 buffer (``sim.coe_model``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pyethercat.sim.od import SimObjectDictionary, SimOdEntry, SimOdObject, sdo_abort
from pyethercat.wire.mailbox.coe import ObjectAccess, SdoAbortCode
from pyethercat.wire.mailbox.objects import (
    StandardObject,
    is_pdo_mapping,
    is_rxpdo_mapping,
    is_txpdo_mapping,
    split_mapping_word,
)

__all__ = ["MappedEntry", "PdoMapping"]

_RX_ASSIGN = int(StandardObject.RXPDO_ASSIGNMENT)
_TX_ASSIGN = int(StandardObject.TXPDO_ASSIGNMENT)


@dataclass(frozen=True, slots=True)
class MappedEntry:
    """One entry of the process image: where it sits and which OD entry it is."""

    index: int
    subindex: int
    bit_offset: int
    bits: int
    entry: SimOdEntry | None  # None: a gap (mapping index 0)


class PdoMapping:
    """The mapping and assignment objects of one slave and the layout they define.

    ``capacity_out``/``capacity_in`` are the largest SM2/SM3 buffers (bytes)
    the device has room for (0x06040042 beyond). ``configurable`` (SII CoE
    detail "PDO configuration") makes 0x16xx/0x1Axx writable in PREOP;
    ``assignable`` ("PDO assign") does the same for 0x1C12/0x1C13.
    ``on_change`` is called after a change of the layout.
    """

    def __init__(self, od: SimObjectDictionary, *, capacity_out: int = 128,
                 capacity_in: int = 128, on_change: Callable[[], None] | None = None) -> None:
        self.od = od
        self.capacity = {_RX_ASSIGN: capacity_out, _TX_ASSIGN: capacity_in}
        self.on_change = on_change
        self.outputs: tuple[MappedEntry, ...] = ()
        self.inputs: tuple[MappedEntry, ...] = ()
        self.output_bits = 0
        self.input_bits = 0
        for obj in od:
            if is_pdo_mapping(obj.index) or obj.index in (_RX_ASSIGN, _TX_ASSIGN):
                obj.check = self._check
                obj.after = self._after
        self.rebuild()

    # --- layout -------------------------------------------------------------------

    def _values(self, index: int, overlay: dict[int, bytes] | None = None) -> list[int]:
        """Subindices 1..n of an assignment (PDO numbers) or mapping object (mapping words),
        n = subindex 0; ``overlay`` holds values of a download not stored yet."""
        obj = self.od.find(index)
        if obj is None:
            return []
        count = _u(overlay, obj, 0)
        return [_u(overlay, obj, s) for s in range(1, count + 1) if s in obj.entries]

    def _layout(self, assign_index: int) -> tuple[tuple[MappedEntry, ...], int]:
        out: list[MappedEntry] = []
        pos = 0
        for pdo in self._values(assign_index):
            for word in self._values(pdo):
                index, sub, bits = split_mapping_word(word)
                entry = None
                if index:
                    obj = self.od.find(index)
                    entry = obj.entries.get(sub) if obj is not None else None
                out.append(MappedEntry(index, sub, pos, bits, entry))
                pos += bits
        return tuple(out), pos

    def rebuild(self) -> None:
        """Recompute the layout from the current objects."""
        self.outputs, self.output_bits = self._layout(_RX_ASSIGN)
        self.inputs, self.input_bits = self._layout(_TX_ASSIGN)
        self.od.rx_mapped = frozenset((m.index, m.subindex) for m in self.outputs if m.entry)

    def sizes(self) -> tuple[int, int]:
        """(output bytes, input bytes) the SM2/SM3 buffers must have."""
        return (self.output_bits + 7) // 8, (self.input_bits + 7) // 8

    # --- validation hooks ------------------------------------------------------------

    def _check(self, obj: SimOdObject, changes: dict[int, bytes], complete: bool) -> None:
        index = obj.index
        if not complete:
            subs = [s for s in changes if s != 0]
            if subs and obj.count() != 0:
                raise sdo_abort(SdoAbortCode.SUBINDEX_WRITE, index, subs[0],
                                "write subindex 0 = 0 first")
        if index in (_RX_ASSIGN, _TX_ASSIGN):
            self._check_assignment(obj, changes)
        else:
            self._check_mapping(obj, changes)

    def _check_mapping(self, obj: SimOdObject, changes: dict[int, bytes]) -> None:
        index = obj.index
        rx = is_rxpdo_mapping(index)
        flag = int(ObjectAccess.RXPDO_MAPPABLE if rx else ObjectAccess.TXPDO_MAPPABLE)
        for sub, raw in changes.items():
            if sub:
                self._check_word(index, sub, int.from_bytes(raw, "little"), flag)
        if 0 in changes:
            words = self._values(index, changes)
            for n, word in enumerate(words, 1):
                self._check_word(index, n, word, flag)
            bits = sum(w & 0xFF for w in words)
            assign = _RX_ASSIGN if rx else _TX_ASSIGN
            total = bits + sum(sum(w & 0xFF for w in self._values(p))
                               for p in self._values(assign) if p != index)
            limit = 8 * self.capacity[assign]
            if bits > limit or (index in self._values(assign) and total > limit):
                raise sdo_abort(SdoAbortCode.PDO_LENGTH_EXCEEDED, index, 0,
                                f"{bits} bits, SM buffer holds {limit}")

    def _check_word(self, pdo: int, sub: int, word: int, flag: int) -> None:
        index, subindex, bits = split_mapping_word(word)
        if index == 0:
            return  # a gap of `bits` bits
        obj = self.od.find(index)
        if obj is None:
            raise sdo_abort(SdoAbortCode.NO_OBJECT, pdo, sub, f"0x{index:04X} does not exist")
        e = obj.entries.get(subindex)
        if e is None:
            raise sdo_abort(SdoAbortCode.NO_SUBINDEX, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} does not exist")
        if not e.access & flag:
            raise sdo_abort(SdoAbortCode.NOT_MAPPABLE, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} is not mappable here")
        if bits != e.bit_length:
            raise sdo_abort(SdoAbortCode.PARAMETER_INCOMPATIBLE, pdo, sub,
                            f"0x{index:04X}:{subindex:02X} has {e.bit_length} bits, not {bits}")

    def _check_assignment(self, obj: SimOdObject, changes: dict[int, bytes]) -> None:
        index = obj.index
        of_direction = is_rxpdo_mapping if index == _RX_ASSIGN else is_txpdo_mapping
        for sub, raw in changes.items():
            if sub:
                pdo = int.from_bytes(raw, "little")
                if not (of_direction(pdo) and pdo in self.od):
                    raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, sub,
                                    f"0x{pdo:04X} is no PDO of this direction")
        if 0 in changes:
            pdos = self._values(index, changes)
            for n, pdo in enumerate(pdos, 1):
                if not (of_direction(pdo) and pdo in self.od):
                    raise sdo_abort(SdoAbortCode.VALUE_RANGE, index, n,
                                    f"0x{pdo:04X} is no PDO of this direction")
            if len(set(pdos)) != len(pdos):
                raise sdo_abort(SdoAbortCode.PARAMETER_INCOMPATIBLE, index, 0,
                                "a PDO is assigned twice")
            bits = sum(sum(w & 0xFF for w in self._values(p)) for p in pdos)
            if bits > 8 * self.capacity[index]:
                raise sdo_abort(SdoAbortCode.PDO_LENGTH_EXCEEDED, index, 0,
                                f"{bits} bits, SM buffer holds {8 * self.capacity[index]}")

    def _after(self, obj: SimOdObject, changes: dict[int, bytes], complete: bool) -> None:
        self.rebuild()
        if self.on_change is not None:
            self.on_change()


def _u(overlay: dict[int, bytes] | None, obj: SimOdObject, sub: int) -> int:
    if overlay is not None and sub in overlay:
        return int.from_bytes(overlay[sub], "little")
    e = obj.entries.get(sub)
    return int.from_bytes(e.read(), "little") if e is not None else 0
