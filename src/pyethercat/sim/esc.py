"""Register-level model of one EtherCAT slave controller (ESC).

An :class:`Esc` owns one row of the segment's memory array (see
``sim.memory``) and implements what a real chip does on single-slave
accesses (APxx, FPxx, the reading slave of ARMW/FRMW, and the slow path of
broadcasts): register access rules from its :class:`EscProfile`, sync
manager gating (mailbox full/empty, buffer completion) and the write side
effects of the registers. Its parts live in their own modules:

- ``sim.access``: the register row, which bytes exist and take writes;
- ``sim.al_state``: the AL state machine (AL control, status, checks);
- ``sim.eeprom``: the SII EEPROM interface;
- ``sim.esc_mailbox``: the mailbox SMs and the firmware's side of them.

Everything beyond its own registers goes through the host protocol
(``sim.host.EscHost``): the segment handles what spans slaves (logical
addressing, broadcasts' fast path, topology, DC times).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.sim.access import (
    SIDE_EFFECT_MASK,
    SM_LOWEST,
    WRITE_TRIGGER,
    EscRegisters,
    SmView,
    buffer_written,
    cleared_by_read,
)
from pyethercat.sim.al_state import AlStateMachine
from pyethercat.sim.device import DeviceApp, Pdi
from pyethercat.sim.eeprom import SiiInterface
from pyethercat.sim.esc_mailbox import MailboxSms
from pyethercat.sim.host import Dirty, EscHost
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.profiles import EscProfile
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import SiiInfo

__all__ = ["Esc"]

_SM_MODE_MAILBOX = int(R.SmMode.MAILBOX)
_SII_END = R.SII_DATA + 8
_SM_MODE_BUFFERED = int(R.SmMode.BUFFERED)
_SM_STATUS_BUFFER_NONE = 3 << R.SM_STATUS_BUFFER_SHIFT
# Process RAM takes every byte and no write there has a register side effect
# (ET1100 datasheet section II, "Process RAM"): accesses that lie wholly in it
# (mailbox and process-data buffers) skip the register masks.
_RAM_PLAIN = not (SIDE_EFFECT_MASK[R.RAM_START:].any() or WRITE_TRIGGER[R.RAM_START:].any())
# Error counter groups: a write to any counter of a group clears the whole
# group (ET1100 datasheet section II, registers 0x0300-0x0313).
_COUNTER_GROUPS = ((R.RX_ERROR_COUNTER, R.RX_ERROR_COUNTER + 8),
                   (R.FORWARDED_RX_ERROR_COUNTER, R.FORWARDED_RX_ERROR_COUNTER + 4),
                   (R.ECAT_PROCESSING_ERROR_COUNTER, R.ECAT_PROCESSING_ERROR_COUNTER + 1),
                   (R.PDI_ERROR_COUNTER, R.PDI_ERROR_COUNTER + 1),
                   (R.LOST_LINK_COUNTER, R.LOST_LINK_COUNTER + 4))


class Esc(EscRegisters):
    """One simulated ESC (see the module docstring)."""

    def __init__(self, host: EscHost, memory: EscMemory, index: int, name: str, sii: bytes,
                 prof: EscProfile, app: DeviceApp | None, alias: int | None = None,
                 initial_inputs: bytes | None = None, sii_info: SiiInfo | None = None) -> None:
        super().__init__(host, memory, index, prof)
        self.name = name
        self.app = app
        self.pdi = Pdi(self)
        self.eeprom = SiiInterface(self, sii, alias, sii_info)
        self.mailbox = MailboxSms(self, app)
        self.al = AlStateMachine(self, self.eeprom, self.mailbox, app)
        self.powered = False
        self.inputs = bytes(initial_inputs) if initial_inputs else b""
        self.reset_sequence = 0
        #: Input SMs whose next buffer the PDI has begun but not completed.
        self._pdi_staging: set[int] = set()
        #: End of the process RAM when accesses inside it may take the plain path (else 0).
        self._ram_end = prof.ram_end if _RAM_PLAIN else 0

    # --- parts ---------------------------------------------------------------------

    @property
    def sii(self) -> bytearray:
        """The EEPROM image (changed by SII write commands)."""
        return self.eeprom.image

    @property
    def sii_info(self) -> SiiInfo | None:
        """The parsed EEPROM image (None when it does not parse)."""
        return self.eeprom.info

    @property
    def output_sm(self) -> int:
        """Sync manager carrying the outputs (from the SII)."""
        return self.eeprom.output_sm

    @property
    def input_sm(self) -> int:
        """Sync manager carrying the inputs (from the SII)."""
        return self.eeprom.input_sm

    def now_ns(self) -> int:
        return self.host.now_ns()

    def set_al_error(self, code: int, state: AlState | None = None) -> None:
        """Error from the application: error flag, code, optionally a new state."""
        self.al.set_error(code, state)

    # --- power -------------------------------------------------------------------

    def power_on(self) -> None:
        """Load the power-on register values (INIT, station address 0, alias from SII)."""
        self.memory.clear(self.index)
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
        self.al.power_on()
        self.mailbox.power_on()
        self.reset_sequence = 0
        self._pdi_staging.clear()
        self.eeprom.power_on()
        self.powered = True

    # --- ECAT access (single slave) ------------------------------------------------

    def ecat_read(self, ado: int, length: int) -> bytes | None:
        """An EtherCAT read; None when it is not performed (no working counter)."""
        lo, hi = ado, ado + length
        if lo >= R.RAM_START and hi <= self._ram_end and length:
            return self._ram_read(lo, hi)
        if hi > R.ADDRESS_SPACE or length == 0 or not self.impl[lo:hi].any():
            return None
        # (SMs govern the digital I/O registers and the process RAM only: other
        # register accesses, the DC ones of every cycle among them, need not look)
        sms = self.sms_overlapping(lo, hi) if hi > SM_LOWEST else []
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and not s.ecat_writes and not (
                    s.status & R.SM_STATUS_MAILBOX_FULL):
                return None  # empty mailbox: not read, not counted
        self.refresh(lo, hi)
        data = self.row[lo:hi].tobytes()
        if len(data) < length:  # past the row: memory the chip lacks reads 0
            data += bytes(length - len(data))
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_read_complete(s)
        self.after_read(lo, hi)
        return data

    def _ram_read(self, lo: int, hi: int) -> bytes | None:
        """``ecat_read`` of bytes that all lie in process RAM (no register behind them)."""
        sms = self.sms_overlapping(lo, hi)
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and not s.ecat_writes and not (
                    s.status & R.SM_STATUS_MAILBOX_FULL):
                return None  # empty mailbox: not read, not counted
        data = self.row[lo:hi].tobytes()
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_read_complete(s)
        return data

    def _ram_write(self, lo: int, hi: int, data: bytes) -> bool:
        """``ecat_write`` of bytes that all lie in process RAM (all writable, no side effects)."""
        sms = self.sms_overlapping(lo, hi)
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and s.ecat_writes and s.status & R.SM_STATUS_MAILBOX_FULL:
                return False  # full mailbox: refused
            if not s.ecat_writes:
                return False  # the master may not write a slave->master buffer
        self.row[lo:hi] = np.frombuffer(data, np.uint8)
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_write_complete(s)
        return True

    def ecat_write(self, ado: int, data: bytes) -> bool:
        """An EtherCAT write; False when it is not performed (no working counter)."""
        lo, hi = ado, ado + len(data)
        if lo >= R.RAM_START and hi <= self._ram_end and data:
            return self._ram_write(lo, hi, data)
        if hi > R.ADDRESS_SPACE or not data or not self.impl[lo:hi].any():
            return False
        # (SMs govern the digital I/O registers and the process RAM only: other
        # register accesses, the DC ones of every cycle among them, need not look)
        sms = self.sms_overlapping(lo, hi) if hi > SM_LOWEST else []
        for s in sms:
            if s.mode == _SM_MODE_MAILBOX and s.ecat_writes and s.status & R.SM_STATUS_MAILBOX_FULL:
                return False  # full mailbox: refused
            if not s.ecat_writes:
                return False  # the master may not write a slave->master buffer
        w = self.writable[lo:hi]
        if not w.any() and not (WRITE_TRIGGER[lo:hi] & self.impl[lo:hi]).any():
            # Read-only registers: the write is not performed and not counted
            # (real ESCs answer e.g. a BWR of 0x092C with working counter 0).
            return False
        if lo < _SII_END and hi > R.SII_CONTROL and self.eeprom.busy():
            # While a command runs the SII registers keep their values (ET1100
            # datasheet section II, 0x0502-0x050F: written only when not busy);
            # the registers exist and are writable, so the access is counted.
            w = w.copy()
            w[max(R.SII_CONTROL - lo, 0): _SII_END - lo] = False
        row = self.row
        new = np.frombuffer(data, np.uint8)
        if hi > len(row):  # past the row: memory the chip lacks (nothing writable there)
            hi = len(row)
            w, new = w[: hi - lo], new[: hi - lo]
        old = row[lo:hi].copy()
        row[lo:hi] = np.where(w, new, old)
        if SIDE_EFFECT_MASK[lo:hi].any():
            self._write_side_effects(lo, hi, old, new)
        for s in sms:
            if hi >= s.end and lo < s.end:
                self._sm_write_complete(s)
        return True

    def refresh(self, lo: int, hi: int, pdi: bool = False) -> None:
        """Bring time-dependent registers in [lo, hi) up to date before a read (``pdi``: by the PDI)."""
        if lo < R.SII_CONTROL + 2 and hi > R.SII_CONTROL:
            self.eeprom.refresh()
        if (lo < R.DC_SYSTEM_TIME + 8 and hi > R.DC_SYSTEM_TIME and self.profile.dc_supported
                and self.profile.dc_system_time):
            self.host.dc_refresh(self.index)
        if (lo <= R.DC_SYNC1_STATUS and hi > R.DC_SYNC0_STATUS and self.profile.dc_supported
                and self.profile.dc_system_time):
            self.host.dc_sync_status(self.index, lo, hi, pdi)

    def after_read(self, lo: int, hi: int) -> None:
        """Clear-on-read events."""
        bits = cleared_by_read(lo, hi)
        if bits and self.u16(R.ECAT_EVENT_REQUEST) & bits:
            self.clear_ecat_event(bits)

    # --- sync manager events -------------------------------------------------------

    def _sm_read_complete(self, s: SmView) -> None:
        """The ECAT side read the last byte of SM ``s``."""
        mailbox = s.mode == _SM_MODE_MAILBOX
        if mailbox:
            if s.ecat_writes:
                return
            status = self.mailbox.read_complete(s)
        else:
            status = s.status | R.SM_STATUS_READ_EVENT
        self.set_sm_status(s.n, status)
        if s.control & R.SM_CONTROL_AL_EVENT:
            self.set_al_event(R.al_event_sm(s.n))
        if self.u16(R.ECAT_EVENT_REQUEST) & (R.ecat_event_sm(s.n)):
            self.clear_ecat_event(R.ecat_event_sm(s.n))
        if mailbox:
            self.mailbox.after_read(s)

    def _sm_write_complete(self, s: SmView) -> None:
        """The ECAT side wrote the last byte of SM ``s``."""
        if s.mode == _SM_MODE_MAILBOX:
            self.mailbox.write_complete(s)
        else:
            self.host.output_buffer_completed(self.index)

    # --- write side effects ------------------------------------------------------------

    def _write_side_effects(self, lo: int, hi: int, old: npt.NDArray[np.uint8],
                            new: npt.NDArray[np.uint8]) -> None:
        def hit(a: int, size: int) -> bool:
            return lo < a + size and hi > a

        host = self.host
        if hit(R.STATION_ADDRESS, 4) or hit(R.DL_CONTROL_ALIAS, 1):
            host.invalidate(Dirty.ADDRESSING)
        if hit(R.ESC_RESET_ECAT, 1):
            self._reset_byte(int(new[R.ESC_RESET_ECAT - lo]))
            if not self.powered:
                return
        if hit(R.DL_CONTROL_LOOP, 1):
            host.loop_control_written(self.index, int(old[R.DL_CONTROL_LOOP - lo]),
                                      int(new[R.DL_CONTROL_LOOP - lo]))
        if hit(R.ECAT_EVENT_MASK, 2):
            host.invalidate(Dirty.IRQ)
        if hit(R.RX_ERROR_COUNTER, 0x14):
            row = self.row
            for g_lo, g_hi in _COUNTER_GROUPS:
                if lo < g_hi and hi > g_lo:
                    row[g_lo:g_hi] = 0
        if hit(R.WATCHDOG_DIVIDER, 0x44):
            if hit(R.WATCHDOG_COUNTER_PROCESS_DATA, 2):
                self.row[R.WATCHDOG_COUNTER_PROCESS_DATA: R.WATCHDOG_COUNTER_PDI + 1] = 0
            host.invalidate(Dirty.WATCHDOG)
        if hit(R.SII_CONFIG, 1):
            self.eeprom.config_written()
        if hit(R.SII_CONTROL, 2):
            self.eeprom.control_written(lo, old)
        if hit(R.AL_CONTROL, 2):
            self.al.control_written()
        if hit(R.FMMU_BASE, R.SM_BASE - R.FMMU_BASE):
            host.invalidate(Dirty.FMMU)
        if hit(R.SM_BASE, 16 * R.SM_SIZE):
            self._sm_registers_written(lo, hi, old)
        if hit(R.DC_RECEIVE_TIME_PORT0, R.DC_SYSTEM_TIME + 8 - R.DC_RECEIVE_TIME_PORT0) or hit(
                R.DC_SPEED_COUNTER_START, 6) or hit(
                R.DC_CYCLIC_UNIT_CONTROL, R.DC_LATCH1_CONTROL + 1 - R.DC_CYCLIC_UNIT_CONTROL):
            host.dc_written(self.index, lo, new.tobytes())

    def _reset_byte(self, value: int) -> None:
        """ESC reset: 'R', 'E', 'S' written in three consecutive writes (ET1100 datasheet, 0x0040)."""
        expected = R.ESC_RESET_SEQUENCE[self.reset_sequence]
        if value == expected:
            self.reset_sequence += 1
            if self.reset_sequence == 3:
                self.reset_sequence = 0
                self.host.reset_requested(self.index)
        else:
            self.reset_sequence = 1 if value == R.ESC_RESET_SEQUENCE[0] else 0

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
                self.set_sm_status(n, status)
                if not s.ecat_writes and s.mode == _SM_MODE_BUFFERED and n == self.input_sm and self.inputs:
                    self.row[s.start: s.start + min(len(self.inputs), s.length)] = np.frombuffer(
                        self.inputs[: s.length], np.uint8)
            elif not now_enabled and was_enabled:
                self.set_sm_status(n, 0)
            # Repeat request toggled on the send mailbox (SOES esc.c ESC_mbxprocess).
            if (now_enabled and s.mode == _SM_MODE_MAILBOX and not s.ecat_writes
                    and (before[R.SM_ACTIVATE] ^ after[R.SM_ACTIVATE]) & R.SM_ACTIVATE_REPEAT):
                self.mailbox.repeat(n)
            self.set_al_event(int(R.AlEvent.SM_ACTIVATION))
        if changed_any:
            self.host.invalidate(Dirty.SM)
            self.al.recheck_running_state()

    # --- PDI side --------------------------------------------------------------------------

    def pdi_sii_write(self, word: int, data: bytes) -> None:
        """The firmware rewrites EEPROM words (see :meth:`SiiInterface.firmware_write`)."""
        self.eeprom.firmware_write(word, data)

    def pdi_read(self, address: int, length: int) -> bytes:
        lo, hi = address, address + length
        if lo < 0 or hi > R.ADDRESS_SPACE:
            raise ValueError(f"PDI read 0x{address:04X}+{length} outside the 64 KiB space")
        top = len(self.row)
        if hi > top:  # memory the chip lacks reads 0
            head = self.pdi_read(address, top - lo) if lo < top else b""
            return head + bytes(length - len(head))
        self.refresh(lo, hi, pdi=True)
        data = self.row[lo:hi].tobytes()
        if lo < R.AL_CONTROL + 2 and hi > R.AL_CONTROL:
            self.clear_al_event(int(R.AlEvent.AL_CONTROL))
        if hi > SM_LOWEST:  # (registers are never an SM's: the firmware's reads of them skip the look)
            for s in self.sms_overlapping(lo, hi):
                if s.ecat_writes and hi >= s.end and s.mode == _SM_MODE_MAILBOX:
                    self.mailbox.pdi_consumed(s.n)
        return data

    def pdi_write(self, address: int, data: bytes) -> None:
        lo, hi = address, address + len(data)
        if lo < 0 or hi > max(self.profile.ram_end, R.RAM_START):
            raise ValueError(f"PDI write 0x{address:04X}+{len(data)} outside the chip's memory "
                             f"(0x0000-0x{self.profile.ram_end - 1:04X})")
        sms = self.sms_overlapping(lo, hi)
        # A process-data input buffer (3-buffer mode, PDI writes) is published
        # only when its last byte is written: until then EtherCAT reads the
        # newest complete buffer. The buffer being written is staged in the
        # slave's shadow row (unused for input SMs), seeded from the published one.
        staged = [(s, self.row[s.start: s.end].copy()) for s in sms
                  if not s.ecat_writes and s.mode == _SM_MODE_BUFFERED]
        shadow = self.shadow
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
                    self.mailbox.posted(s)
                else:
                    self.row[s.start: s.end] = shadow[s.start: s.end]
                    self._pdi_staging.discard(s.n)
                    self.set_sm_status(s.n, buffer_written(s.status))

    def pdi_outputs(self) -> bytes:
        if self.output_sm >= self.profile.sm_count:
            return b""
        s = self.sm(self.output_sm)
        if not s.enabled or not self.host.has_outputs(self.index):
            return b""
        return self.shadow[s.start: s.end].tobytes()

    def pdi_set_inputs(self, data: bytes) -> None:
        self.inputs = bytes(data)
        if self.input_sm >= self.profile.sm_count:
            return
        s = self.sm(self.input_sm)
        if s.enabled and s.mode == _SM_MODE_BUFFERED and not s.ecat_writes:
            n = min(len(data), s.length)
            self.row[s.start: s.start + n] = np.frombuffer(bytes(data[:n]), np.uint8)
            self.set_sm_status(s.n, buffer_written(s.status))

    def pdi_latch_input(self, unit: int, rising: bool, t_ns: int | None = None) -> None:
        """An edge on latch input ``unit`` (the LATCH0/1 pin), stamped by the DC unit."""
        if not self.profile.dc_supported:
            raise ValueError(f"{self.name}: the ESC has no distributed clocks: no latch inputs")
        self.host.dc_latch_input(self.index, unit, rising, t_ns)

    def pdi_post_mailbox(self, data: bytes) -> bool:
        return self.mailbox.post(data)
