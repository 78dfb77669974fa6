"""Register access of one simulated ESC: which bytes exist, which take writes, the SM view.

:class:`EscRegisters` is one slave's row of the segment memory with typed
accessors and the two event-request registers; the parts of an ESC model
(``sim.esc``, ``sim.al_state``, ``sim.eeprom``, ``sim.esc_mailbox``) share one.
It reports to its host (``sim.host.EscHost``) only through the calls that
protocol names.

:func:`register_masks` derives from an :class:`EscProfile` which bytes of the
64 KiB space a chip implements and which ones the EtherCAT side may write
(ESC datasheets, section I "Register overview": FMMUs and SMs beyond the
chip's counts and the DC block of a chip without DC are absent; reads and
writes there are not counted).
"""

from __future__ import annotations

import struct

import numpy as np
import numpy.typing as npt

from pyethercat.sim.host import EscHost
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.profiles import EscProfile
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState

__all__ = [
    "SIDE_EFFECT_MASK",
    "SM_LOWEST",
    "WRITE_TRIGGER",
    "EscRegisters",
    "SmView",
    "buffer_written",
    "register_masks",
]

BoolArray = npt.NDArray[np.bool_]

_VALID_STATES = frozenset(int(s) for s in AlState if s != AlState.NONE)

# Register ranges whose ECAT writes have side effects beyond storing the bytes.
_SIDE_EFFECT_RANGES: tuple[tuple[int, int], ...] = (
    (R.STATION_ADDRESS, R.STATION_ALIAS + 2),
    (R.ESC_RESET_ECAT, R.ESC_RESET_ECAT + 1),
    (R.DL_CONTROL, R.DL_CONTROL + 4),
    (R.AL_CONTROL, R.AL_CONTROL + 2),
    (R.ECAT_EVENT_MASK, R.ECAT_EVENT_MASK + 2),
    (R.RX_ERROR_COUNTER, R.LOST_LINK_COUNTER + 4),
    (R.WATCHDOG_DIVIDER, R.WATCHDOG_COUNTER_PDI + 1),
    (R.SII_CONFIG, R.SII_DATA + 8),
    (R.FMMU_BASE, R.SM_BASE),
    (R.SM_BASE, R.SM_BASE + 16 * R.SM_SIZE),
    (R.DC_RECEIVE_TIME_PORT0, R.DC_SYSTEM_TIME + 8),
    (R.DC_SPEED_COUNTER_START, R.DC_SPEED_FILTER_DEPTH + 1),
    (R.DC_CYCLIC_UNIT_CONTROL, R.DC_LATCH1_CONTROL + 1),
)

_MASK_CACHE: dict[EscProfile, tuple[BoolArray, BoolArray]] = {}


def register_masks(prof: EscProfile) -> tuple[BoolArray, BoolArray]:
    """(implemented, ecat_writable) byte masks of the 64 KiB space for a profile.

    Implemented: the register area 0x0000-0x0FFF except what the chip lacks
    (FMMUs and SMs beyond its counts, the DC block without DC support) and the
    process RAM up to its size. Writable: the bytes of registers the register
    map marks as written by EtherCAT, restricted to implemented bytes, plus
    all RAM. Bytes that are written but not stored (DC receive-time latch,
    system time) are handled as side effects.
    """
    cached = _MASK_CACHE.get(prof)
    if cached is not None:
        return cached
    impl = np.zeros(R.ADDRESS_SPACE, dtype=np.bool_)
    writable = np.zeros(R.ADDRESS_SPACE, dtype=np.bool_)
    impl[: R.RAM_START] = True
    impl[R.fmmu_address(prof.fmmu_count): R.SM_BASE] = False
    impl[R.sm_address(prof.sm_count): R.SM_BASE + 16 * R.SM_SIZE] = False
    if not prof.dc_supported:
        impl[R.DC_RECEIVE_TIME_PORT0: R.DC_RECEIVE_TIME_PORT0 + 0x100] = False
    elif not prof.dc_system_time:
        # Receive-time latches only (real EL2828/EL1004): nothing from 0x0910 on.
        impl[R.DC_SYSTEM_TIME: R.DC_RECEIVE_TIME_PORT0 + 0x100] = False
    impl[R.RAM_START: prof.ram_end] = True
    for reg in R.REGISTERS:
        if reg.access & R.RegisterAccess.W:
            writable[reg.address: reg.address + reg.size] = True
    # The latch registers and the system time take writes without storing them.
    writable[R.DC_RECEIVE_TIME_PORT0: R.DC_SYSTEM_TIME + 8] = False
    writable[R.RAM_START:] = True
    writable &= impl
    impl.setflags(write=False)
    writable.setflags(write=False)
    _MASK_CACHE[prof] = (impl, writable)
    return impl, writable


def _range_mask(ranges: tuple[tuple[int, int], ...]) -> BoolArray:
    mask = np.zeros(R.ADDRESS_SPACE, dtype=np.bool_)
    for lo, hi in ranges:
        mask[lo:hi] = True
    mask.setflags(write=False)
    return mask


#: Register bytes whose writes need the per-slave path (or a vectorised special case).
SIDE_EFFECT_MASK = _range_mask(_SIDE_EFFECT_RANGES)
#: Bytes that take writes without storing them (DC receive-time latch, system time).
WRITE_TRIGGER = _range_mask(((R.DC_RECEIVE_TIME_PORT0, R.DC_SYSTEM_TIME + 8),))


def buffer_written(status: int) -> int:
    """SM status after a 3-buffer write completed: next buffer index, write event set.

    Buffer 3 ("none written yet") is followed by 0, then 0 -> 1 -> 2 -> 0."""
    cur = (status & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT
    nxt = 0 if cur == 3 else (cur + 1) % 3
    return (status & ~R.SM_STATUS_BUFFER_MASK) | (nxt << R.SM_STATUS_BUFFER_SHIFT) | R.SM_STATUS_WRITE_EVENT


#: Lowest address a sync manager governs: the digital I/O registers 0x0F00-0x0FFF
#: (ET1200 terminals such as the EL2004 put their outputs there) and the process
#: RAM. Registers below are never governed by an SM, whatever the SM registers
#: say: an SM configured over them takes no part in any access, so that a
#: hostile SM window over 0x0800 cannot lock the SM registers themselves.
SM_LOWEST = R.DIGITAL_OUTPUT

_EV_DL_STATUS = int(R.EcatEvent.DL_STATUS)
_EV_AL_STATUS = int(R.EcatEvent.AL_STATUS)


def cleared_by_read(lo: int, hi: int) -> int:
    """The ECAT event request bits (0x0210) an EtherCAT read of [lo, hi) clears: DL status
    change by reading 0x0110, AL status change by reading 0x0130 (ESC datasheet section II)."""
    bits = 0
    if lo < R.DL_STATUS + 2 and hi > R.DL_STATUS:
        bits |= _EV_DL_STATUS
    if lo < R.AL_STATUS + 2 and hi > R.AL_STATUS:
        bits |= _EV_AL_STATUS
    return bits


class SmView:
    """Decoded registers of one sync manager (a snapshot)."""

    __slots__ = ("n", "start", "length", "control", "status", "activate", "pdi_control",
                 "ram_end", "end")

    def __init__(self, n: int, raw: bytes, ram_end: int = R.ADDRESS_SPACE) -> None:
        self.n = n
        self.start, self.length, self.control, self.status, self.activate, self.pdi_control = (
            R.SM_STRUCT.unpack(raw))
        #: First address after the chip's process RAM.
        self.ram_end = ram_end
        #: First address after the SM's area.
        self.end = self.start + self.length

    @property
    def enabled(self) -> bool:
        """Activated, not deactivated by the PDI, not empty, and over memory an SM may govern.

        An SM window reaching past the chip's process RAM is not activated
        (the datasheets do not say what the chips do; the simulator keeps
        every buffer inside memory that exists)."""
        return bool(self.activate & R.SM_ACTIVATE_ENABLE) and not (
            self.pdi_control & R.SM_PDI_DEACTIVATE) and self.length > 0 and (
            self.start >= SM_LOWEST and self.start + self.length <= self.ram_end)

    @property
    def mode(self) -> int:
        return int(self.control & R.SM_CONTROL_MODE_MASK)

    @property
    def ecat_writes(self) -> bool:
        """Direction: ECAT writes / PDI reads (SM0, SM2)."""
        return bool((self.control & R.SM_CONTROL_DIRECTION_MASK) >> R.SM_CONTROL_DIRECTION_SHIFT == 1)

    def with_status(self, status: int) -> SmView:
        """A copy of this view with another status byte (cheaper than decoding anew)."""
        view = SmView.__new__(SmView)
        view.n, view.start, view.length, view.control = self.n, self.start, self.length, self.control
        view.status, view.activate, view.pdi_control = status, self.activate, self.pdi_control
        view.ram_end, view.end = self.ram_end, self.end
        return view


_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_AL_EVENT = int(R.AL_EVENT_REQUEST)
_NO_ROW = np.zeros(0, np.uint8)

#: Per SM register block: every byte but the status (byte 5), which the mailbox flips
#: on each access and which does not decide whether or where an SM applies.
_SM_STATIC_INT = int.from_bytes(bytes(0 if b == R.SM_STATUS else 0xFF for b in range(R.SM_SIZE)) * 16,
                                "little")


class EscRegisters:
    """One ESC's row of the segment memory, its profile and its host."""

    def __init__(self, host: EscHost, memory: EscMemory, index: int, prof: EscProfile) -> None:
        self.host = host
        self.memory = memory
        self.index = index
        self.profile = prof
        memory.fit(prof.ram_end)  # (rows as wide as this chip's RAM; the host recompiles)
        self.impl, self.writable = register_masks(prof)
        self._row_of: npt.NDArray[np.uint8] | None = None
        self._row: npt.NDArray[np.uint8] = _NO_ROW  # (the row may not exist yet)
        self._buf = _NO_ROW.data
        # The enabled SMs as last decoded, and their registers without the status bytes
        # (as one int) they were decoded from.
        self._sm_raw = -1
        self._sm_enabled: list[SmView] = []

    @property
    def row(self) -> npt.NDArray[np.uint8]:
        """The slave's memory as the EtherCAT side sees it (a view; moves when memory grows)."""
        mem = self.memory.mem
        if mem is not self._row_of:
            self._follow(mem)
        return self._row

    @property
    def buf(self) -> memoryview:
        """:attr:`row` as a writable buffer (what ``struct`` reads and writes)."""
        mem = self.memory.mem
        if mem is not self._row_of:
            self._follow(mem)
        return self._buf

    def _follow(self, mem: npt.NDArray[np.uint8]) -> None:
        # (a row view costs a numpy call; a mailbox frame asks for it a dozen times)
        self._row_of = mem
        self._row = mem[self.index]
        self._buf = self._row.data

    @property
    def shadow(self) -> npt.NDArray[np.uint8]:
        """The complete-buffer shadow row (what the PDI sees of write SMs)."""
        row: npt.NDArray[np.uint8] = self.memory.shadow[self.index]
        return row

    def u8(self, address: int) -> int:
        return int(self.row[address])

    # (struct reads and writes the row's buffer directly: one C call, no numpy scalars)
    def u16(self, address: int) -> int:
        return int(_U16.unpack_from(self.buf, address)[0])

    def u32(self, address: int) -> int:
        return int(_U32.unpack_from(self.buf, address)[0])

    def u64(self, address: int) -> int:
        return int.from_bytes(self.row[address: address + 8].tobytes(), "little")

    def set_u8(self, address: int, value: int) -> None:
        self.row[address] = value & 0xFF

    def set_u16(self, address: int, value: int) -> None:
        _U16.pack_into(self.buf, address, value & 0xFFFF)

    def set_bytes(self, address: int, data: bytes) -> None:
        self.row[address: address + len(data)] = np.frombuffer(data, np.uint8)

    def sm(self, n: int) -> SmView:
        base = R.sm_address(n)
        return SmView(n, self.row[base: base + R.SM_SIZE].tobytes(), self.profile.ram_end)

    def set_sm_status(self, n: int, value: int) -> None:
        self.row[R.sm_address(n) + R.SM_STATUS] = value & 0xFF

    def sms_overlapping(self, lo: int, hi: int) -> list[SmView]:
        """The enabled SMs whose area overlaps [lo, hi)."""
        # Decoding every SM on each access was most of a mailbox frame's cost: decode
        # them again only when their registers other than the status changed (one
        # masked compare tells); the status is read fresh each time.
        count = self.profile.sm_count
        raw = self.row[R.SM_BASE: R.SM_BASE + R.SM_SIZE * count].tobytes()
        # (the masked compare on a Python int: a tenth of what the numpy one cost)
        static = int.from_bytes(raw, "little") & _SM_STATIC_INT
        if static != self._sm_raw:
            self._sm_raw = static
            ram_end = self.profile.ram_end
            views = (SmView(n, raw[R.SM_SIZE * n: R.SM_SIZE * (n + 1)], ram_end)
                     for n in range(count))
            self._sm_enabled = [v for v in views if v.enabled]
        return [s.with_status(raw[R.SM_SIZE * s.n + R.SM_STATUS])
                for s in self._sm_enabled if s.start < hi and s.end > lo]

    def set_ecat_event(self, bits: int) -> None:
        """Set ECAT event request bits (0x0210); the host recomputes the IRQ field."""
        value = self.u16(R.ECAT_EVENT_REQUEST) | bits
        self.set_u16(R.ECAT_EVENT_REQUEST, value)
        self.host.ecat_event_raised(int(bits))

    def clear_ecat_event(self, bits: int) -> None:
        value = self.u16(R.ECAT_EVENT_REQUEST) & ~int(bits)
        self.set_u16(R.ECAT_EVENT_REQUEST, value)
        self.host.ecat_event_raised(0)

    def set_al_event(self, bits: int) -> None:
        buf = self.buf
        _U32.pack_into(buf, _AL_EVENT, (_U32.unpack_from(buf, _AL_EVENT)[0] | int(bits)) & 0xFFFFFFFF)

    def clear_al_event(self, bits: int) -> None:
        buf = self.buf
        _U32.pack_into(buf, _AL_EVENT, _U32.unpack_from(buf, _AL_EVENT)[0] & ~int(bits) & 0xFFFFFFFF)

    @property
    def device_emulation(self) -> bool:
        return bool(self.row[R.ESC_CONFIG] & R.EscConfig.DEVICE_EMULATION)

    def al_state(self) -> AlState:
        """AL status bits 3:0 (INIT for a value that is no state)."""
        value = int(self.row[R.AL_STATUS]) & R.AL_STATE_MASK
        return AlState(value) if value in _VALID_STATES else AlState.INIT
