"""Register-level model of one EtherCAT slave controller (ESC).

An :class:`Esc` owns one row of the segment's memory array (see
``sim.memory``) and implements what a real chip does on single-slave
accesses (APxx, FPxx, the reading slave of ARMW/FRMW, and the slow path of
broadcasts): register access rules from its :class:`EscProfile`, sync
manager gating (mailbox full/empty, buffer completion), the AL state machine
with the checks of a real slave, the SII EEPROM interface and the DC
registers' write side effects. The segment handles everything that spans
slaves (logical addressing, broadcasts' fast path, topology, DC latch times).

Documented modelling choices (public sources leave these open):

- SII commands complete at once; with ``Segment.sii_busy_ns > 0`` the busy
  bit stays set for that long (reads of 0x0502 see it), the data are ready at
  once.
- A mailbox written by the master is handed to ``DeviceApp.on_mailbox`` and
  then read by the "firmware" (the SM becomes empty) unless the application
  sets ``mailbox_auto_read = False``.
- A SAFEOP -> OP request before any outputs were received stays pending
  without an error (as KickCAT's emulator does) and completes when the first
  complete output buffer arrives.
- Devices whose SII asks for device emulation (0x0141 bit 0, from SII word 0)
  follow AL control without checks, as ESCs without a microcontroller do.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from pyethercat.errors import SiiError
from pyethercat.sim.device import DeviceApp, Pdi
from pyethercat.sim.profiles import PROFILES, EscProfile, profile
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.sii import SM_NOT_ASSIGNED, SiiInfo, parse_sii, sii_crc

if TYPE_CHECKING:
    from pyethercat.sim.segment import Segment

__all__ = ["PROFILES", "Esc", "EscProfile", "buffer_written", "profile", "register_masks"]

BoolArray = npt.NDArray[np.bool_]

_VALID_STATES = {int(s) for s in (AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP)}
_BELOW_SAFEOP = (AlState.INIT, AlState.PREOP, AlState.BOOT)
# AL control bits a chip in device emulation copies into AL status (state + error ack).
_AL_EMULATION_COPY = R.AL_STATE_MASK | R.AL_ERROR_FLAG
_SM_MODE_MAILBOX = int(R.SmMode.MAILBOX)
_SM_MODE_BUFFERED = int(R.SmMode.BUFFERED)
_SM_STATUS_BUFFER_NONE = 3 << R.SM_STATUS_BUFFER_SHIFT

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
    (R.DC_CYCLIC_UNIT_CONTROL, R.DC_SYNC1_CYCLE + 4),
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
        if reg.access & R.Access.W:
            writable[reg.address: reg.address + reg.size] = True
    # The latch registers and the system time take writes without storing them.
    writable[R.DC_RECEIVE_TIME_PORT0: R.DC_SYSTEM_TIME + 8] = False
    writable[R.RAM_START:] = True
    writable &= impl
    impl.setflags(write=False)
    writable.setflags(write=False)
    _MASK_CACHE[prof] = (impl, writable)
    return impl, writable


def _side_effect_mask() -> BoolArray:
    mask = np.zeros(R.ADDRESS_SPACE, dtype=np.bool_)
    for lo, hi in _SIDE_EFFECT_RANGES:
        mask[lo:hi] = True
    mask.setflags(write=False)
    return mask


#: Register bytes whose writes need the per-slave path (or a vectorised special case).
SIDE_EFFECT_MASK = _side_effect_mask()


def _write_trigger_mask() -> BoolArray:
    """Bytes that take writes without storing them (DC latch, system time)."""
    mask = np.zeros(R.ADDRESS_SPACE, dtype=np.bool_)
    mask[R.DC_RECEIVE_TIME_PORT0: R.DC_SYSTEM_TIME + 8] = True
    mask.setflags(write=False)
    return mask


_WRITE_TRIGGER = _write_trigger_mask()


def buffer_written(status: int) -> int:
    """SM status after a 3-buffer write completed: next buffer index, write event set.

    Buffer 3 ("none written yet") is followed by 0, then 0 -> 1 -> 2 -> 0."""
    cur = (status & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT
    nxt = 0 if cur == 3 else (cur + 1) % 3
    return (status & ~R.SM_STATUS_BUFFER_MASK) | (nxt << R.SM_STATUS_BUFFER_SHIFT) | R.SM_STATUS_WRITE_EVENT


class SmView:
    """Decoded registers of one sync manager (a snapshot)."""

    __slots__ = ("n", "start", "length", "control", "status", "activate", "pdi_control")

    def __init__(self, n: int, raw: bytes) -> None:
        self.n = n
        self.start, self.length, self.control, self.status, self.activate, self.pdi_control = (
            R.SM_STRUCT.unpack(raw))

    @property
    def enabled(self) -> bool:
        return bool(self.activate & R.SM_ACTIVATE_ENABLE) and not (
            self.pdi_control & R.SM_PDI_DEACTIVATE) and self.length > 0

    @property
    def mode(self) -> int:
        return int(self.control & R.SM_CONTROL_MODE_MASK)

    @property
    def ecat_writes(self) -> bool:
        """Direction: ECAT writes / PDI reads (SM0, SM2)."""
        return bool((self.control & R.SM_CONTROL_DIRECTION_MASK) >> R.SM_CONTROL_DIRECTION_SHIFT == 1)

    @property
    def end(self) -> int:
        return int(self.start + self.length)


class Esc:
    """One simulated ESC (see the module docstring)."""

    def __init__(self, segment: Segment, index: int, name: str, sii: bytes, prof: EscProfile,
                 app: DeviceApp | None, alias: int | None = None,
                 initial_inputs: bytes | None = None) -> None:
        self.seg = segment
        self.index = index
        self.name = name
        self.profile = prof
        self.sii = bytearray(sii)
        self.sii_info: SiiInfo | None
        try:
            self.sii_info = parse_sii(bytes(sii)) if len(sii) >= 32 else None
        except SiiError:
            self.sii_info = None
        self.alias_override = alias
        self.app = app
        self.pdi = Pdi(self)
        self.impl, self.writable = register_masks(prof)
        self.powered = False
        self.sii_busy_until = 0
        self.sii_write_cycle_until = 0
        self.last_mailbox_in = b""
        # Firmware side of the repeat request (facts 6.6, the order SOES uses): the
        # mailbox the master read last, a newer one a repeat request took back out
        # of SM1 (posted again once the repeated one is read), and whether SM1
        # holds the repeated mailbox right now.
        self.mailbox_backup = b""
        self.mailbox_again = b""
        self._repeat_posted = False
        self.inputs = bytes(initial_inputs) if initial_inputs else b""
        self.reset_sequence = 0
        #: Input SMs whose next buffer the PDI has begun but not completed.
        self._pdi_staging: set[int] = set()
        self.output_sm, self.input_sm = self._pd_sms()

    # --- identity from the SII -------------------------------------------------

    def _pd_sms(self) -> tuple[int, int]:
        """Sync manager numbers carrying outputs and inputs (from the SII)."""
        out_sm, in_sm = 2, 3
        info = self.sii_info
        if info is None:
            return out_sm, in_sm
        rx = [p.sync_manager for p in info.rx_pdos if p.sync_manager != SM_NOT_ASSIGNED and p.entries]
        tx = [p.sync_manager for p in info.tx_pdos if p.sync_manager != SM_NOT_ASSIGNED and p.entries]
        types = [s.sm_type for s in info.sync_managers]
        if rx:
            out_sm = rx[0]
        elif 3 in types:
            out_sm = types.index(3)
        if tx:
            in_sm = tx[0]
        elif 4 in types:
            in_sm = types.index(4)
        return out_sm, in_sm

    @property
    def output_bytes(self) -> int:
        """Bytes of process-data outputs expected (app's PDO mapping, else SII RxPDOs)."""
        sizes = self.app.process_data_sizes() if self.app is not None else None
        if sizes is not None:
            return sizes[0]
        info = self.sii_info
        return 0 if info is None else (info.output_bits + 7) // 8

    @property
    def input_bytes(self) -> int:
        """Bytes of process-data inputs sent (app's PDO mapping, else SII TxPDOs)."""
        sizes = self.app.process_data_sizes() if self.app is not None else None
        if sizes is not None:
            return sizes[1]
        info = self.sii_info
        return 0 if info is None else (info.input_bits + 7) // 8

    def _sii_word(self, word: int) -> int:
        off = 2 * word
        if off + 2 > len(self.sii):
            return 0xFFFF
        return int(self.sii[off] | (self.sii[off + 1] << 8))

    # --- memory helpers ----------------------------------------------------------

    @property
    def row(self) -> npt.NDArray[np.uint8]:
        row: npt.NDArray[np.uint8] = self.seg.memory.mem[self.index]
        return row

    def u8(self, address: int) -> int:
        return int(self.row[address])

    def u16(self, address: int) -> int:
        row = self.row
        return int(row[address]) | (int(row[address + 1]) << 8)

    def u32(self, address: int) -> int:
        return int.from_bytes(self.row[address: address + 4].tobytes(), "little")

    def u64(self, address: int) -> int:
        return int.from_bytes(self.row[address: address + 8].tobytes(), "little")

    def set_u8(self, address: int, value: int) -> None:
        self.row[address] = value & 0xFF

    def set_u16(self, address: int, value: int) -> None:
        self.row[address: address + 2] = np.frombuffer((value & 0xFFFF).to_bytes(2, "little"), np.uint8)

    def set_bytes(self, address: int, data: bytes) -> None:
        self.row[address: address + len(data)] = np.frombuffer(data, np.uint8)

    def now_ns(self) -> int:
        return self.seg.clock.now_ns()

    def sm(self, n: int) -> SmView:
        base = R.sm_address(n)
        return SmView(n, self.row[base: base + R.SM_SIZE].tobytes())

    def _sms_overlapping(self, lo: int, hi: int) -> list[SmView]:
        out = []
        for n in range(self.profile.sm_count):
            s = self.sm(n)
            if s.enabled and s.start < hi and s.end > lo:
                out.append(s)
        return out

    def set_ecat_event(self, bits: int) -> None:
        self.seg._event_bits |= int(bits)
        row = self.row
        value = self.u16(R.ECAT_EVENT_REQUEST) | bits
        row[R.ECAT_EVENT_REQUEST] = value & 0xFF
        row[R.ECAT_EVENT_REQUEST + 1] = value >> 8
        self.seg.irq_dirty = True

    def clear_ecat_event(self, bits: int) -> None:
        value = self.u16(R.ECAT_EVENT_REQUEST) & ~int(bits)
        self.set_u16(R.ECAT_EVENT_REQUEST, value)
        self.seg.irq_dirty = True

    def set_al_event(self, bits: int) -> None:
        value = self.u32(R.AL_EVENT_REQUEST) | bits
        self.set_bytes(R.AL_EVENT_REQUEST, value.to_bytes(4, "little"))

    # --- power -------------------------------------------------------------------

    def power_on(self) -> None:
        """Load the power-on register values (INIT, station address 0, alias from SII)."""
        mem = self.seg.memory
        mem.clear(self.index)
        p = self.profile
        row = self.row
        row[R.TYPE] = p.esc_type
        row[R.REVISION] = p.revision
        self.set_u16(R.BUILD, p.build)
        row[R.FMMU_COUNT] = p.fmmu_count
        row[R.SM_COUNT] = p.sm_count
        row[R.RAM_SIZE] = p.ram_kib & 0xFF
        row[R.PORT_DESCRIPTOR] = p.port_descriptor
        self.set_u16(R.FEATURES, p.features)
        if p.dc_supported:
            self.set_bytes(R.DC_RECEIVE_TIME_PORT0, p.dc_receive_time_reset)
        self.set_u16(R.AL_STATUS, int(AlState.INIT))
        self.set_u16(R.WATCHDOG_DIVIDER, R.WATCHDOG_DIVIDER_DEFAULT)
        self.set_u16(R.WATCHDOG_TIME_PDI, R.WATCHDOG_TIME_DEFAULT)
        self.set_u16(R.WATCHDOG_TIME_PROCESS_DATA, R.WATCHDOG_TIME_DEFAULT)
        self.set_u16(R.WATCHDOG_STATUS_PROCESS_DATA, 1)
        self.set_u16(R.DC_SPEED_COUNTER_START, R.DC_SPEED_COUNTER_START_DEFAULT)
        row[R.DC_TIME_FILTER_DEPTH] = R.DC_TIME_FILTER_DEPTH_DEFAULT
        row[R.DC_SPEED_FILTER_DEPTH] = R.DC_SPEED_FILTER_DEPTH_DEFAULT
        self.sii_busy_until = 0
        self.sii_write_cycle_until = 0
        self.pending_op = False
        self.mailbox_backup = self.mailbox_again = b""  # the firmware restarts too
        self.reset_sequence = 0
        self._pdi_staging.clear()
        self._sii_load()
        self.powered = True

    def _sii_load(self) -> None:
        """Apply the SII configuration words (power-up and reload)."""
        control = int(R.SiiControl.READ_8_BYTES) if self.profile.sii_read_bytes == 8 else 0
        if self.al_state() in _BELOW_SAFEOP:
            control |= self.profile.sii_control_static
        # EEPROMs of 32 Kbit and more need two address bytes (1-16 Kbit: one).
        if self.sii_info is not None and self.sii_info.eeprom_size_kbit >= 32:
            control |= R.SiiControl.TWO_ADDRESS_BYTES
        ok = len(self.sii) >= 16 and sii_crc(bytes(self.sii[:14])) == self.sii[14]
        if not ok:
            control |= R.SiiControl.CHECKSUM_ERROR
        else:
            word0 = self._sii_word(0)
            self.row[R.PDI_CONTROL] = word0 & 0xFF
            self.row[R.ESC_CONFIG] = word0 >> 8
            self.set_u16(R.DC_SYNC_PULSE_LENGTH, self._sii_word(2))
        old = self.u16(R.SII_CONTROL)
        self.set_u16(R.SII_CONTROL, int(control) | (old & R.SiiControl.WRITE_ENABLE))
        alias = self.alias_override
        if alias is None:
            alias = self._sii_word(4) if ok else 0
        self.set_u16(R.STATION_ALIAS, alias)
        # DL status bit 0: the PDI is operational once the EEPROM was loaded.
        dl = self.u16(R.DL_STATUS)
        # Bit 1 (PDI watchdog reloaded) needs a PDI: the real EK1100 (PDI
        # control 0x00, none) reads 0, EL1004/EL2828/EL2889 (0x04, digital
        # I/O) read 1, in device emulation all of them.
        pdi_ok = int(R.DlStatus.PDI_WATCHDOG_OK) if self.row[R.PDI_CONTROL] else 0
        dl &= ~int(R.DlStatus.PDI_OPERATIONAL | R.DlStatus.PDI_WATCHDOG_OK)
        dl |= (int(R.DlStatus.PDI_OPERATIONAL) | pdi_ok) if ok else 0
        self.set_u16(R.DL_STATUS, dl)
        self.seg.addressing_dirty = True

    @property
    def pending_op(self) -> bool:
        """A SAFEOP -> OP request waits for the first complete outputs."""
        return self.index in self.seg.pending_op

    @pending_op.setter
    def pending_op(self, value: bool) -> None:
        if value:
            self.seg.pending_op.add(self.index)
        else:
            self.seg.pending_op.discard(self.index)

    @property
    def device_emulation(self) -> bool:
        return bool(self.row[R.ESC_CONFIG] & R.EscConfig.DEVICE_EMULATION)

    # --- ECAT access (single slave) ------------------------------------------------

    def ecat_read(self, ado: int, length: int) -> bytes | None:
        """An EtherCAT read; None when it is not performed (no working counter)."""
        lo, hi = ado, ado + length
        if hi > R.ADDRESS_SPACE or length == 0 or not self.impl[lo:hi].any():
            return None
        sms = self._sms_overlapping(lo, hi) if hi > R.SM_BASE else []
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and not s.ecat_writes and not (
                    s.status & R.SM_STATUS_MAILBOX_FULL):
                return None  # empty mailbox: not read, not counted
        self.refresh(lo, hi)
        data = self.row[lo:hi].tobytes()
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_read_complete(s)
        self.after_read(lo, hi)
        return data

    def ecat_write(self, ado: int, data: bytes) -> bool:
        """An EtherCAT write; False when it is not performed (no working counter)."""
        lo, hi = ado, ado + len(data)
        if hi > R.ADDRESS_SPACE or not data or not self.impl[lo:hi].any():
            return False
        sms = self._sms_overlapping(lo, hi) if hi > R.SM_BASE else []
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and s.ecat_writes and s.status & R.SM_STATUS_MAILBOX_FULL:
                return False  # full mailbox: refused
            if not s.ecat_writes:
                return False  # the master may not write a slave->master buffer
        w = self.writable[lo:hi]
        if not w.any() and not (_WRITE_TRIGGER[lo:hi] & self.impl[lo:hi]).any():
            # Read-only registers: the write is not performed and not counted
            # (real ESCs answer e.g. a BWR of 0x092C with working counter 0).
            return False
        row = self.row
        old = row[lo:hi].copy()
        new = np.frombuffer(data, np.uint8)
        row[lo:hi] = np.where(w, new, old)
        if SIDE_EFFECT_MASK[lo:hi].any():
            self._write_side_effects(lo, hi, old, new)
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_write_complete(s)
        return True

    def refresh(self, lo: int, hi: int) -> None:
        """Bring time-dependent registers in [lo, hi) up to date before a read."""
        if (lo < R.SII_CONTROL + 2 and hi > R.SII_CONTROL and self.sii_busy_until
                and self.now_ns() >= self.sii_busy_until):
                self.sii_busy_until = 0
                self.set_u16(R.SII_CONTROL, self.u16(R.SII_CONTROL)
                             & ~(int(R.SiiControl.BUSY) | R.SII_COMMAND_MASK))
        if (lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME and self.profile.dc_supported
                and self.profile.dc_system_time):
            self.seg.refresh_system_time(np.array([self.index]))

    def after_read(self, lo: int, hi: int) -> None:
        """Clear-on-read events."""
        bits = 0
        if lo < R.DL_STATUS + 2 and hi > R.DL_STATUS:
            bits |= R.EcatEvent.DL_STATUS
        if lo < R.AL_STATUS + 2 and hi > R.AL_STATUS:
            bits |= R.EcatEvent.AL_STATUS
        if bits and self.u16(R.ECAT_EVENT_REQUEST) & bits:
            self.clear_ecat_event(bits)

    # --- sync manager events -------------------------------------------------------

    def _set_sm_status(self, n: int, value: int) -> None:
        self.row[R.sm_address(n) + R.SM_STATUS] = value & 0xFF

    def _sm_read_complete(self, s: SmView) -> None:
        """The ECAT side read the last byte of SM ``s``."""
        status = s.status
        if s.mode == _SM_MODE_MAILBOX:
            if s.ecat_writes:
                return
            # What the master has read is what a repeat request brings back.
            self.mailbox_backup = self.row[s.start: s.end].tobytes()
            self._repeat_posted = False
            status &= ~(R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
        status |= R.SM_STATUS_READ_EVENT
        self._set_sm_status(s.n, status)
        if s.control & R.SM_CONTROL_AL_EVENT:
            self.set_al_event(R.al_event_sm(s.n))
        if self.u16(R.ECAT_EVENT_REQUEST) & (R.ecat_event_sm(s.n)):
            self.clear_ecat_event(R.ecat_event_sm(s.n))
        if s.mode == _SM_MODE_MAILBOX and self.mailbox_again:
            # The mailbox a repeat request withdrew goes out before anything newer.
            again, self.mailbox_again = self.mailbox_again, b""
            self._post_again(s.n, again)
        if s.mode == _SM_MODE_MAILBOX and self.app is not None:
            hook = getattr(self.app, "on_mailbox_read", None)
            if hook is not None:
                hook()

    def _sm_write_complete(self, s: SmView) -> None:
        """The ECAT side wrote the last byte of SM ``s``."""
        if s.mode == _SM_MODE_MAILBOX:
            self._set_sm_status(s.n, (s.status | R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
                                & ~R.SM_STATUS_READ_EVENT)
            if s.control & R.SM_CONTROL_AL_EVENT:
                self.set_al_event(R.al_event_sm(s.n))
            data = self.row[s.start: s.end].tobytes()
            app = self.app
            if app is not None:
                app.on_mailbox(data)
            if app is None or getattr(app, "mailbox_auto_read", True):
                self._pdi_consumed_mailbox(s.n)
        else:
            self.seg.complete_write_sms(np.array([self.index], dtype=np.int64))

    def _pdi_consumed_mailbox(self, n: int) -> None:
        """The firmware read the master's mailbox: SM ``n`` is empty again."""
        s = self.sm(n)
        self._set_sm_status(n, (s.status & ~(R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT))
                            | R.SM_STATUS_READ_EVENT)
        if s.control & R.SM_CONTROL_ECAT_EVENT:
            self.set_ecat_event(R.ecat_event_sm(n))

    # --- write side effects ------------------------------------------------------------

    def _write_side_effects(self, lo: int, hi: int, old: npt.NDArray[np.uint8],
                            new: npt.NDArray[np.uint8]) -> None:
        def hit(a: int, size: int) -> bool:
            return lo < a + size and hi > a

        seg = self.seg
        if hit(R.STATION_ADDRESS, 4) or hit(R.DL_CONTROL_ALIAS, 1):
            seg.addressing_dirty = True
        if hit(R.ESC_RESET_ECAT, 1):
            self._reset_byte(int(new[R.ESC_RESET_ECAT - lo]))
            if not self.powered:
                return
        if hit(R.DL_CONTROL_LOOP, 1):
            seg.loop_control_written(self.index, int(old[R.DL_CONTROL_LOOP - lo]),
                                     int(new[R.DL_CONTROL_LOOP - lo]))
        if hit(R.ECAT_EVENT_MASK, 2):
            seg.irq_dirty = True
        if hit(R.RX_ERROR_COUNTER, 0x14):
            # A write to any counter of a group clears the whole group (facts 3.7).
            row = self.row
            for g_lo, g_hi in ((R.RX_ERROR_COUNTER, R.RX_ERROR_COUNTER + 8),
                               (R.FORWARDED_RX_ERROR_COUNTER, R.FORWARDED_RX_ERROR_COUNTER + 4),
                               (R.ECAT_PROCESSING_ERROR_COUNTER, R.ECAT_PROCESSING_ERROR_COUNTER + 1),
                               (R.PDI_ERROR_COUNTER, R.PDI_ERROR_COUNTER + 1),
                               (R.LOST_LINK_COUNTER, R.LOST_LINK_COUNTER + 4)):
                if lo < g_hi and hi > g_lo:
                    row[g_lo:g_hi] = 0
        if hit(R.WATCHDOG_DIVIDER, 0x44):
            if hit(R.WATCHDOG_COUNTER_PROCESS_DATA, 2):
                self.row[R.WATCHDOG_COUNTER_PROCESS_DATA: R.WATCHDOG_COUNTER_PDI + 1] = 0
            seg.watchdog_dirty = True
        if hit(R.SII_CONFIG, 1):
            cfg = self.u8(R.SII_CONFIG)
            if cfg & R.SII_CONFIG_FORCE_ECAT:
                self.row[R.SII_PDI_ACCESS] = 0
        if hit(R.SII_CONTROL, 2):
            self._sii_control_written(lo, old)
        if hit(R.AL_CONTROL, 2):
            self._al_control_written()
        if hit(R.FMMU_BASE, R.SM_BASE - R.FMMU_BASE):
            seg.fmmu_dirty = True
        if hit(R.SM_BASE, 16 * R.SM_SIZE):
            self._sm_registers_written(lo, hi, old)
        if hit(R.DC_RECEIVE_TIME_PORT0, 16):
            seg.latch_receive_times(np.array([self.index], dtype=np.int64))
        if hit(R.DC_SYSTEM_TIME, 8) and self.profile.dc_system_time:
            off = max(0, R.DC_SYSTEM_TIME - lo)
            start = max(lo, R.DC_SYSTEM_TIME)
            end = min(hi, R.DC_SYSTEM_TIME + 8)
            seg.time_loop_write(np.array([self.index], dtype=np.int64),
                                bytes(new[off: off + end - start]), start - R.DC_SYSTEM_TIME)
        if hit(R.DC_SPEED_COUNTER_START, 6):
            self.set_bytes(R.DC_SYSTEM_TIME_DIFFERENCE, bytes(4))
        if hit(R.DC_CYCLIC_UNIT_CONTROL, R.DC_SYNC1_CYCLE + 4 - R.DC_CYCLIC_UNIT_CONTROL):
            seg.sync_config_written(self.index)

    def _reset_byte(self, value: int) -> None:
        """ESC reset: 'R', 'E', 'S' written in three consecutive writes."""
        expected = R.ESC_RESET_SEQUENCE[self.reset_sequence]
        if value == expected:
            self.reset_sequence += 1
            if self.reset_sequence == 3:
                self.reset_sequence = 0
                self.seg.reset_slave(self.index)
        else:
            self.reset_sequence = 1 if value == R.ESC_RESET_SEQUENCE[0] else 0

    # --- SII interface -------------------------------------------------------------------

    def _sii_control_written(self, lo: int, old: npt.NDArray[np.uint8]) -> None:
        base = R.SII_CONTROL - lo
        if base >= 0:
            prev = int(old[base]) | ((int(old[base + 1]) << 8) if base + 1 < len(old) else (
                self.u8(R.SII_CONTROL + 1) << 8))
        else:  # the write started at 0x0503
            prev = self.u8(R.SII_CONTROL) | (int(old[0]) << 8)
        written = self.u16(R.SII_CONTROL)
        now = self.now_ns()
        if self.sii_busy_until and now >= self.sii_busy_until:
            # The previous command finished (no read of 0x0502 since to notice).
            self.sii_busy_until = 0
            prev &= ~(int(R.SiiControl.BUSY) | R.SII_COMMAND_MASK)
        status_bits = prev & ~(R.SII_COMMAND_MASK | int(R.SiiControl.WRITE_ENABLE))
        if prev & R.SiiControl.BUSY:
            # Writes while busy are ignored.
            self.set_u16(R.SII_CONTROL, prev)
            return
        we = written & R.SiiControl.WRITE_ENABLE
        cmd = written & R.SII_COMMAND_MASK
        status = status_bits
        if cmd and now < self.sii_write_cycle_until:
            # The EEPROM is still in its internal write cycle and does not
            # acknowledge: the command is not carried out, bit 13 tells (a real
            # EK1100 reads 0x2040 after such an attempt), write enable is spent.
            self.set_u16(R.SII_CONTROL, status | R.SiiControl.ACK_ERROR)
            return
        owner_pdi = bool(self.u8(R.SII_CONFIG) & R.SII_CONFIG_PDI_OWNS) and not (
            self.u8(R.SII_CONFIG) & R.SII_CONFIG_FORCE_ECAT)
        if cmd == 0:
            status &= ~int(R.SiiControl.ACK_ERROR | R.SiiControl.WRITE_ENABLE_ERROR)
        elif owner_pdi:
            status |= R.SiiControl.ACK_ERROR
        elif cmd == R.SiiControl.CMD_READ:
            address = self.u32(R.SII_ADDRESS) & 0xFFFF
            n = self.profile.sii_read_bytes
            off = 2 * address
            chunk = bytes(self.sii[off: off + n])
            chunk += b"\xff" * (n - len(chunk))
            self.set_bytes(R.SII_DATA, chunk)
            status &= ~int(R.SiiControl.ACK_ERROR | R.SiiControl.WRITE_ENABLE_ERROR)
        elif cmd == R.SiiControl.CMD_WRITE:
            if not we:
                status |= R.SiiControl.WRITE_ENABLE_ERROR
            else:
                address = self.u32(R.SII_ADDRESS) & 0xFFFF
                off = 2 * address
                if off + 2 > len(self.sii):
                    self.sii.extend(b"\xff" * (off + 2 - len(self.sii)))
                self.sii[off: off + 2] = self.row[R.SII_DATA: R.SII_DATA + 2].tobytes()
                status &= ~int(R.SiiControl.ACK_ERROR | R.SiiControl.WRITE_ENABLE_ERROR)
                if self.profile.sii_write_cycle_ns:
                    self.sii_write_cycle_until = now + self.profile.sii_write_cycle_ns
                if off < 16 or off >= 2 * 0x40:
                    self._reparse_sii()
        elif cmd == R.SiiControl.CMD_RELOAD:
            status &= ~int(R.SiiControl.CHECKSUM_ERROR)
            self.set_u16(R.SII_CONTROL, status)
            self._sii_load()
            status = self.u16(R.SII_CONTROL) & ~(R.SII_COMMAND_MASK | int(R.SiiControl.WRITE_ENABLE))
        else:
            status |= R.SiiControl.ACK_ERROR
        busy_ns = self.seg.sii_busy_ns or (
            self.profile.sii_write_ns if cmd == R.SiiControl.CMD_WRITE else self.profile.sii_read_ns)
        if cmd and busy_ns > 0 and not status & R.SiiControl.ACK_ERROR:
            # Real ESCs show busy together with the running command (e.g. 0x8140).
            status |= R.SiiControl.BUSY | cmd
            self.sii_busy_until = now + busy_ns
        # A command spends the write enable bit (real chips read it 0 after
        # a 0x0201 write command); without a command it stays.
        self.set_u16(R.SII_CONTROL, status | (0 if cmd else we))

    def _reparse_sii(self) -> None:
        try:
            self.sii_info = parse_sii(bytes(self.sii))
        except SiiError:
            self.sii_info = None
        self.output_sm, self.input_sm = self._pd_sms()

    # --- sync manager configuration ----------------------------------------------------------

    def _sm_registers_written(self, lo: int, hi: int, old: npt.NDArray[np.uint8]) -> None:
        row = self.row
        first = max(0, (lo - R.SM_BASE) // R.SM_SIZE)
        last = min(self.profile.sm_count - 1, (hi - 1 - R.SM_BASE) // R.SM_SIZE)
        changed_any = False
        for n in range(first, last + 1):
            base = R.sm_address(n)

            def old_byte(addr: int) -> int:
                return int(old[addr - lo]) if lo <= addr < hi else int(row[addr])

            # Status and PDI control are not writable from EtherCAT (the mask
            # already kept them); compare the configuration with the old one.
            before = bytes(old_byte(a) for a in range(base, base + R.SM_SIZE))
            after = row[base: base + R.SM_SIZE].tobytes()
            if before == after:
                continue
            changed_any = True
            self._pdi_staging.discard(n)
            was_enabled = bool(before[R.SM_ACTIVATE] & R.SM_ACTIVATE_ENABLE)
            now_enabled = bool(after[R.SM_ACTIVATE] & R.SM_ACTIVATE_ENABLE)
            s = self.sm(n)
            if now_enabled and (not was_enabled or before[:R.SM_STATUS] != after[:R.SM_STATUS]):
                status = 0 if s.mode == _SM_MODE_MAILBOX else _SM_STATUS_BUFFER_NONE
                self._set_sm_status(n, status)
                if not s.ecat_writes and s.mode == _SM_MODE_BUFFERED and n == self.input_sm and self.inputs:
                    self.row[s.start: s.start + min(len(self.inputs), s.length)] = np.frombuffer(
                        self.inputs[: s.length], np.uint8)
            elif not now_enabled and was_enabled:
                self._set_sm_status(n, 0)
            # Repeat request toggled on the send mailbox (facts 6.6).
            if (now_enabled and s.mode == _SM_MODE_MAILBOX and not s.ecat_writes
                    and (before[R.SM_ACTIVATE] ^ after[R.SM_ACTIVATE]) & R.SM_ACTIVATE_REPEAT):
                self._repeat_mailbox(n)
            self.set_al_event(int(R.AlEvent.SM_ACTIVATION))
        if changed_any:
            self.seg.sm_dirty = True
            self._recheck_running_state()

    def _stop_mailbox(self) -> None:
        """The firmware stops the mailbox on entering INIT.

        SOES deactivates SM0/SM1 through PDI control there (facts 3.13), which
        drops their buffer state: a request or reply left unread does not
        survive into the next session, even when the master then writes the
        same SM configuration again. Modelled as the deactivation's effect; the
        SMs stay enabled to the master (the firmware re-enables them when the
        mailbox starts, before the INIT -> PREOP checks).
        """
        for n in range(min(2, self.profile.sm_count)):
            if self.sm(n).mode == _SM_MODE_MAILBOX:
                self._set_sm_status(n, 0)
        self.mailbox_backup = self.mailbox_again = b""
        self._repeat_posted = False

    def _repeat_mailbox(self, n: int) -> None:
        """Repeat request (facts 6.6): post the mailbox the master read last once more.

        A newer mailbox already posted but not yet read is taken back and posted
        again right after the repeated one has been read (SOES: disable/enable
        SM1, mark it "again", write the backup). Without a read mailbox there is
        nothing to repeat; SM1 keeps what it holds.
        """
        s = self.sm(n)
        if self.mailbox_backup:
            if s.status & R.SM_STATUS_MAILBOX_FULL and not self._repeat_posted:
                self.mailbox_again = self.row[s.start: s.end].tobytes()
            self._post_again(n, self.mailbox_backup)
            self._repeat_posted = True
        repeat = s.activate & R.SM_ACTIVATE_REPEAT
        pdi = int(self.row[R.sm_address(n) + R.SM_PDI_CONTROL])
        self.row[R.sm_address(n) + R.SM_PDI_CONTROL] = (pdi & ~R.SM_PDI_REPEAT_ACK) | (
            R.SM_PDI_REPEAT_ACK if repeat else 0)

    def _recheck_running_state(self) -> None:
        """Continuous checks: SM changes while running drop the slave back (facts 4.3)."""
        if self.device_emulation:
            return
        state = self.al_state()
        if state in (AlState.PREOP, AlState.SAFEOP, AlState.OP) and self._check_mailbox(False):
            self._fail(AlState.INIT, AlStatusCode.INVALID_MAILBOX_CONFIG)
            return
        if state in (AlState.SAFEOP, AlState.OP):
            code = self._check_process_data()
            if code:
                self._fail(AlState.PREOP, code)

    # --- AL state machine -----------------------------------------------------------------

    def al_state(self) -> AlState:
        value = self.u8(R.AL_STATUS) & R.AL_STATE_MASK
        try:
            return AlState(value)
        except ValueError:
            return AlState.INIT

    def _set_status(self, state: int, error: bool, code: int | None) -> None:
        old_value = self.u16(R.AL_STATUS)
        value = (state & R.AL_STATE_MASK) | (R.AL_ERROR_FLAG if error else 0)
        self.set_u16(R.AL_STATUS, value)
        if code is not None:
            self.set_u16(R.AL_STATUS_CODE, code)
        if value != old_value:
            self.set_ecat_event(int(R.EcatEvent.AL_STATUS))
        old_state = old_value & R.AL_STATE_MASK
        if old_state != state & R.AL_STATE_MASK:
            self._state_changed(AlState(old_state) if old_state in _VALID_STATES else AlState.INIT,
                                AlState(state & R.AL_STATE_MASK))

    def _state_changed(self, old: AlState, new: AlState) -> None:
        extra = self.profile.sii_control_static
        if extra and (old in _BELOW_SAFEOP) != (new in _BELOW_SAFEOP):
            # The chip's undocumented SII control bits show only below SAFEOP.
            ctrl = self.u16(R.SII_CONTROL)
            self.set_u16(R.SII_CONTROL, ctrl | extra if new in _BELOW_SAFEOP else ctrl & ~extra)
        self.seg.state_changed(self.index, old, new)
        if new in (AlState.INIT, AlState.PREOP, AlState.BOOT):
            self.pending_op = False
        if new == AlState.INIT and not self.device_emulation:
            self._stop_mailbox()
        if self.app is not None:
            self.app.on_state_change(old, new)

    def _fail(self, state: AlState, code: int) -> None:
        self.pending_op = False
        self._set_status(int(state), True, code)

    def set_al_error(self, code: int, state: AlState | None = None) -> None:
        """Error from the application: error flag, code, optionally a new state."""
        target = self.al_state() if state is None else state
        self._fail(target, code)

    def _al_control_written(self) -> None:
        control = self.u16(R.AL_CONTROL)
        self.set_al_event(int(R.AlEvent.AL_CONTROL))
        requested = control & R.AL_STATE_MASK
        ack = bool(control & R.AL_ERROR_FLAG)
        status = self.u16(R.AL_STATUS)
        current = status & R.AL_STATE_MASK
        error = bool(status & R.AL_ERROR_FLAG)
        if self.device_emulation:
            # No firmware: AL status is a copy of AL control bits 4:0, the
            # acknowledge bit included (real EK1100/EL1004/EL28xx read 0x0011
            # after AL control 0x0011). An error the ESC set itself (watchdog)
            # stays, with its code, until the master acknowledges it.
            if requested in _VALID_STATES:
                copied = control & _AL_EMULATION_COPY
                own_error = error and not ack and bool(self.u16(R.AL_STATUS_CODE))
                self._set_status(requested, bool(copied & R.AL_ERROR_FLAG) or own_error,
                                 None if own_error else 0)
            return
        if error and not ack and requested != AlState.INIT:
            return  # a request without acknowledge is ignored while the error flag is set
        if error:
            # Acknowledge (explicit, or implicit by an INIT request) clears the error.
            self._set_status(current, False, 0)
        if requested == current and requested in _VALID_STATES:
            self.pending_op = False
            return
        if requested not in _VALID_STATES:
            fallback = AlState.SAFEOP if current == AlState.OP else AlState(current)
            self._fail(fallback, AlStatusCode.UNKNOWN_STATE)
            return
        code, fail_state = self._transition_check(AlState(current), AlState(requested))
        if code == -1:  # pending S->O
            self.pending_op = True
            return
        if code:
            self._fail(fail_state, code)
            return
        self._set_status(requested, False, 0)
        if control & R.AL_ID_FLAG:
            self.set_u16(R.AL_STATUS_CODE, self.u16(R.STATION_ALIAS))
            self.set_u16(R.AL_STATUS, self.u16(R.AL_STATUS) | R.AL_ID_FLAG)

    def _transition_check(self, cur: AlState, req: AlState) -> tuple[int, AlState]:
        """AL status code (0 = allowed, -1 = pending) and the state to stay in on failure."""
        I, P, B, S, O = AlState.INIT, AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP  # noqa: E741
        invalid = AlStatusCode.INVALID_STATE_CHANGE
        if cur == B:
            return (0, B) if req == I else (invalid, B)
        if req == B:
            if cur != I:
                return invalid, (S if cur in (S, O) else cur)
            if self.sii_info is None or not self.sii_info.boot_rx_mailbox_size:
                return AlStatusCode.BOOTSTRAP_NOT_SUPPORTED, I
            if self._check_mailbox(True):
                return AlStatusCode.INVALID_MAILBOX_CONFIG_BOOT, I
            return self._app_check(cur, req, I)
        if cur == I:
            if req in (S, O):
                return invalid, I
            if self._check_mailbox(False):
                return AlStatusCode.INVALID_MAILBOX_CONFIG, I
            return self._app_check(cur, req, I)
        if cur == P:
            if req == O:
                return invalid, P
            if req == S:
                code = self._check_process_data()
                if code:
                    return code, P
                return self._app_check(cur, req, P)
            return self._app_check(cur, req, P)
        if cur == S and req == O:
            code = self._check_process_data()
            if code:
                return code, S
            code, state = self._app_check(cur, req, S)
            if code:
                return code, state
            if self.output_bytes and not self.seg.outputs_received[self.index]:
                return -1, S
            return 0, S
        # Downward transitions are always allowed.
        return self._app_check(cur, req, cur)

    def _app_check(self, cur: AlState, req: AlState, stay: AlState) -> tuple[int, AlState]:
        if self.app is not None:
            code = self.app.check_transition(cur, req)
            if code:
                return code, stay
        return 0, stay

    def _check_mailbox(self, boot: bool) -> bool:
        """True when the mailbox SMs do not match the SII's (standard or boot) mailbox."""
        info = self.sii_info
        if info is None:
            return False
        if boot:
            rx_off, rx_size = info.boot_rx_mailbox_offset, info.boot_rx_mailbox_size
            tx_off, tx_size = info.boot_tx_mailbox_offset, info.boot_tx_mailbox_size
        else:
            rx_off, rx_size = info.rx_mailbox_offset, info.rx_mailbox_size
            tx_off, tx_size = info.tx_mailbox_offset, info.tx_mailbox_size
        if not rx_size and not tx_size:
            return False
        sm0, sm1 = self.sm(0), self.sm(1)
        ok0 = (sm0.enabled and sm0.start == rx_off and sm0.length == rx_size
               and sm0.mode == _SM_MODE_MAILBOX and sm0.ecat_writes)
        ok1 = (sm1.enabled and sm1.start == tx_off and sm1.length == tx_size
               and sm1.mode == _SM_MODE_MAILBOX and not sm1.ecat_writes)
        return not (ok0 and ok1)

    def _check_process_data(self) -> int:
        """0 when the process-data SMs match the PDO layout, else 0x001D/0x001E."""
        if self.sii_info is None:
            return 0
        out_len, in_len = self.output_bytes, self.input_bytes
        if out_len:
            s = self.sm(self.output_sm) if self.output_sm < self.profile.sm_count else None
            if s is None or not s.enabled or s.length != out_len or not s.ecat_writes or (
                    s.mode != _SM_MODE_BUFFERED):
                return AlStatusCode.INVALID_OUTPUT_CONFIG
        if in_len:
            s = self.sm(self.input_sm) if self.input_sm < self.profile.sm_count else None
            if s is None or not s.enabled or s.length != in_len or s.ecat_writes or (
                    s.mode != _SM_MODE_BUFFERED):
                return AlStatusCode.INVALID_INPUT_CONFIG
        return 0

    def outputs_arrived(self) -> None:
        """Called by the segment when a pending S->O request can complete."""
        if self.pending_op and self.al_state() == AlState.SAFEOP:
            self.pending_op = False
            self._set_status(int(AlState.OP), False, 0)

    def watchdog_expired(self) -> None:
        """Process-data watchdog ran out: OP falls back to SAFEOP + 0x001B."""
        self.set_u16(R.WATCHDOG_STATUS_PROCESS_DATA, 0)
        count = self.u8(R.WATCHDOG_COUNTER_PROCESS_DATA)
        self.row[R.WATCHDOG_COUNTER_PROCESS_DATA] = min(255, count + 1)
        self.set_al_event(int(R.AlEvent.WATCHDOG))
        if self.al_state() == AlState.OP:
            self._fail(AlState.SAFEOP, AlStatusCode.SM_WATCHDOG)

    # --- PDI side --------------------------------------------------------------------------

    def pdi_read(self, address: int, length: int) -> bytes:
        lo, hi = address, address + length
        if lo < 0 or hi > R.ADDRESS_SPACE:
            raise ValueError(f"PDI read 0x{address:04X}+{length} outside the 64 KiB space")
        self.refresh(lo, hi)
        data = self.row[lo:hi].tobytes()
        if lo < R.AL_CONTROL + 2 and hi > R.AL_CONTROL:
            self.set_bytes(R.AL_EVENT_REQUEST, (self.u32(R.AL_EVENT_REQUEST)
                                                & ~int(R.AlEvent.AL_CONTROL)).to_bytes(4, "little"))
        for s in self._sms_overlapping(lo, hi):
            if s.ecat_writes and hi >= s.end and s.mode == _SM_MODE_MAILBOX:
                self._pdi_consumed_mailbox(s.n)
        return data

    def pdi_write(self, address: int, data: bytes) -> None:
        lo, hi = address, address + len(data)
        if lo < 0 or hi > R.ADDRESS_SPACE:
            raise ValueError(f"PDI write 0x{address:04X}+{len(data)} outside the 64 KiB space")
        sms = self._sms_overlapping(lo, hi)
        # A process-data input buffer (3-buffer mode, PDI writes) is published
        # only when its last byte is written: until then EtherCAT reads the
        # newest complete buffer. The buffer being written is staged in the
        # slave's shadow row (unused for input SMs), seeded from the published one.
        staged = [(s, self.row[s.start: s.end].copy()) for s in sms
                  if not s.ecat_writes and s.mode == _SM_MODE_BUFFERED]
        shadow = self.seg.memory.shadow[self.index]
        for s, published in staged:
            if s.n not in self._pdi_staging:
                shadow[s.start: s.end] = published
                self._pdi_staging.add(s.n)
        new = np.frombuffer(bytes(data), np.uint8)
        self.row[lo:hi] = new
        for s, published in staged:
            a, b = max(lo, s.start), min(hi, s.end)
            shadow[a:b] = new[a - lo: b - lo]
            self.row[s.start: s.end] = published
        if lo < R.AL_STATUS + 2 and hi > R.AL_STATUS:
            self.set_ecat_event(int(R.EcatEvent.AL_STATUS))
        for s in sms:
            if not s.ecat_writes and hi >= s.end:
                if s.mode == _SM_MODE_MAILBOX:
                    self._mailbox_posted(s)
                else:
                    self.row[s.start: s.end] = shadow[s.start: s.end]
                    self._pdi_staging.discard(s.n)
                    self._inputs_written(s)

    def _post_again(self, n: int, data: bytes) -> None:
        """Write a repeated or withdrawn mailbox into SM ``n`` and mark it full."""
        s = self.sm(n)
        self.row[s.start: s.end] = np.frombuffer(data[: s.length].ljust(s.length, b"\x00"), np.uint8)
        self._mailbox_posted(s)

    def _mailbox_posted(self, s: SmView) -> None:
        self._repeat_posted = False
        self.last_mailbox_in = self.row[s.start: s.end].tobytes()
        self._set_sm_status(s.n, (s.status | R.SM_STATUS_MAILBOX_FULL | R.SM_STATUS_WRITE_EVENT)
                            & ~R.SM_STATUS_READ_EVENT)
        if s.control & R.SM_CONTROL_ECAT_EVENT:
            self.set_ecat_event(R.ecat_event_sm(s.n))

    def _inputs_written(self, s: SmView) -> None:
        self._set_sm_status(s.n, buffer_written(s.status))

    def pdi_outputs(self) -> bytes:
        if self.output_sm >= self.profile.sm_count:
            return b""
        s = self.sm(self.output_sm)
        if not s.enabled or not self.seg.outputs_received[self.index]:
            return b""
        return self.seg.memory.shadow[self.index, s.start: s.end].tobytes()

    def pdi_set_inputs(self, data: bytes) -> None:
        self.inputs = bytes(data)
        if self.input_sm >= self.profile.sm_count:
            return
        s = self.sm(self.input_sm)
        if s.enabled and s.mode == _SM_MODE_BUFFERED and not s.ecat_writes:
            n = min(len(data), s.length)
            self.row[s.start: s.start + n] = np.frombuffer(bytes(data[:n]), np.uint8)
            self._inputs_written(s)

    def pdi_post_mailbox(self, data: bytes) -> bool:
        s = self.sm(1) if self.profile.sm_count > 1 else None
        if s is None or not s.enabled or s.mode != _SM_MODE_MAILBOX or s.ecat_writes:
            return False
        if s.status & R.SM_STATUS_MAILBOX_FULL:
            return False
        payload = bytes(data[: s.length]).ljust(s.length, b"\x00")
        self.row[s.start: s.end] = np.frombuffer(payload, np.uint8)
        self._mailbox_posted(s)
        return True
