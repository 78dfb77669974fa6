"""The SII EEPROM interface of a simulated ESC (registers 0x0500-0x050F).

:class:`SiiInterface` holds the EEPROM image and carries out the commands the
master writes into SII control 0x0502 (ESC datasheet section II, registers
0x0500-0x050F; SOEM ``src/ec_main.c`` ``ecx_readeepromFP``; KickCAT
``EmulatedESC.cc``): read (4 or 8 bytes, as the
chip's profile says), write (one word, write enable needed), reload (the
configuration words 0-7 are applied again, as at power-on).

Timing: with a board profile's EEPROM timing (``EscProfile.sii_read_ns`` etc.)
or ``Segment.sii_busy_ns`` a command keeps the busy bit (15) with its command
bits set for that long; the data are ready at once. After a write the EEPROM
runs its internal write cycle and does not acknowledge commands meanwhile
(bit 13, the command is not carried out). Writes to 0x0502 while busy are
ignored.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from pyethercat.errors import SiiError
from pyethercat.sim.access import EscRegisters
from pyethercat.sim.host import Dirty
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.sii import SM_NOT_ASSIGNED, SiiInfo, parse_sii, sii_crc

__all__ = ["SiiInterface"]

_BELOW_SAFEOP = (AlState.INIT, AlState.PREOP, AlState.BOOT)
_CLEARS_ERRORS = ~int(R.SiiControl.ACK_ERROR | R.SiiControl.WRITE_ENABLE_ERROR)
#: SII words whose change needs the image parsed again (fixed area, categories).
_CONFIG_BYTES = 16
_CATEGORIES = 2 * 0x40


def _parse(image: bytes) -> SiiInfo | None:
    try:
        return parse_sii(image) if len(image) >= 32 else None
    except SiiError:
        return None


class SiiInterface:
    """EEPROM image and SII command state of one ESC (see the module docstring)."""

    def __init__(self, regs: EscRegisters, image: bytes, alias: int | None = None,
                 info: SiiInfo | None = None) -> None:
        self.regs = regs
        self.image = bytearray(image)
        #: The parsed image (None when it does not parse); shared across slaves with the same image.
        self.info: SiiInfo | None = info if info is not None else _parse(bytes(image))
        self.alias_override = alias
        self.busy_until = 0
        self.write_cycle_until = 0
        self.output_sm, self.input_sm = self._pd_sms()

    def word(self, word: int) -> int:
        off = 2 * word
        if off + 2 > len(self.image):
            return 0xFFFF
        return int(self.image[off] | (self.image[off + 1] << 8))

    def _pd_sms(self) -> tuple[int, int]:
        """Sync manager numbers carrying outputs and inputs (from the SII)."""
        out_sm, in_sm = 2, 3
        info = self.info
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

    def power_on(self) -> None:
        self.busy_until = 0
        self.write_cycle_until = 0
        self.load()

    def load(self) -> None:
        """Apply the SII configuration words (power-up and reload)."""
        regs = self.regs
        prof = regs.profile
        control = int(R.SiiControl.READ_8_BYTES) if prof.sii_read_bytes == 8 else 0
        if prof.sii_emulated:
            control |= R.SiiControl.EMULATION
        if regs.al_state() in _BELOW_SAFEOP:
            control |= prof.sii_control_static
        # EEPROMs of 32 Kbit and more need two address bytes (1-16 Kbit: one).
        if self.info is not None and self.info.eeprom_size_kbit >= 32:
            control |= R.SiiControl.TWO_ADDRESS_BYTES
        image = self.image
        ok = len(image) >= 16 and sii_crc(bytes(image[:14])) == image[14]
        row = regs.row
        if not ok:
            control |= R.SiiControl.CHECKSUM_ERROR
        else:
            word0 = self.word(0) if prof.pdi_control is None else prof.pdi_control
            row[R.PDI_CONTROL] = word0 & 0xFF
            row[R.ESC_CONFIG] = word0 >> 8
            regs.set_u16(R.DC_SYNC_PULSE_LENGTH, self.word(2))
        old = regs.u16(R.SII_CONTROL)
        regs.set_u16(R.SII_CONTROL, int(control) | (old & R.SiiControl.WRITE_ENABLE))
        alias = self.alias_override
        if alias is None:
            alias = self.word(4) if ok else 0
        regs.set_u16(R.STATION_ALIAS, alias)
        # DL status bit 0: the PDI is operational once the EEPROM was loaded.
        dl = regs.u16(R.DL_STATUS)
        # Bit 1 (PDI watchdog reloaded) needs a PDI: the real EK1100 (PDI
        # control 0x00, none) reads 0, EL1004/EL2828/EL2889 (0x04, digital
        # I/O) read 1, in device emulation all of them.
        pdi_ok = int(R.DlStatus.PDI_WATCHDOG_OK) if row[R.PDI_CONTROL] else 0
        dl &= ~int(R.DlStatus.PDI_OPERATIONAL | R.DlStatus.PDI_WATCHDOG_OK)
        dl |= (int(R.DlStatus.PDI_OPERATIONAL) | pdi_ok) if ok else 0
        regs.set_u16(R.DL_STATUS, dl)
        regs.host.invalidate(Dirty.ADDRESSING)

    def busy(self) -> bool:
        """A command is running (its busy time has not run out)."""
        return bool(self.busy_until) and self.regs.host.now_ns() < self.busy_until

    def refresh(self) -> None:
        """Before a read of 0x0502: a command whose busy time ran out is done."""
        if self.busy_until and self.regs.host.now_ns() >= self.busy_until:
            self.busy_until = 0
            regs = self.regs
            regs.set_u16(R.SII_CONTROL, regs.u16(R.SII_CONTROL) & ~(int(R.SiiControl.BUSY) | R.SII_COMMAND_MASK))

    def config_written(self) -> None:
        """SII configuration 0x0500 written: forcing ECAT access takes the PDI's access away."""
        if self.regs.u8(R.SII_CONFIG) & R.SII_CONFIG_FORCE_ECAT:
            self.regs.row[R.SII_PDI_ACCESS] = 0

    def state_changed(self, old: AlState, new: AlState) -> None:
        extra = self.regs.profile.sii_control_static
        if extra and (old in _BELOW_SAFEOP) != (new in _BELOW_SAFEOP):
            # The chip's undocumented SII control bits show only below SAFEOP.
            ctrl = self.regs.u16(R.SII_CONTROL)
            self.regs.set_u16(R.SII_CONTROL, ctrl | extra if new in _BELOW_SAFEOP else ctrl & ~extra)

    def control_written(self, lo: int, old: npt.NDArray[np.uint8]) -> None:
        """SII control 0x0502/0x0503 written (``old``: the bytes before the write from ``lo``)."""
        regs = self.regs
        base = R.SII_CONTROL - lo
        if base >= 0:
            prev = int(old[base]) | ((int(old[base + 1]) << 8) if base + 1 < len(old) else (
                regs.u8(R.SII_CONTROL + 1) << 8))
        else:  # the write started at 0x0503
            prev = regs.u8(R.SII_CONTROL) | (int(old[0]) << 8)
        written = regs.u16(R.SII_CONTROL)
        now = regs.host.now_ns()
        if self.busy_until and now >= self.busy_until:
            # The previous command finished (no read of 0x0502 since to notice).
            self.busy_until = 0
            prev &= ~(int(R.SiiControl.BUSY) | R.SII_COMMAND_MASK)
        if prev & R.SiiControl.BUSY:
            # Writes while busy are ignored.
            regs.set_u16(R.SII_CONTROL, prev)
            return
        we = written & R.SiiControl.WRITE_ENABLE
        cmd = written & R.SII_COMMAND_MASK
        status = prev & ~(R.SII_COMMAND_MASK | int(R.SiiControl.WRITE_ENABLE))
        if cmd and now < self.write_cycle_until:
            # The EEPROM is still in its internal write cycle and does not
            # acknowledge: the command is not carried out, bit 13 tells (a real
            # EK1100 reads 0x2040 after such an attempt), write enable is spent.
            regs.set_u16(R.SII_CONTROL, status | R.SiiControl.ACK_ERROR)
            return
        cfg = regs.u8(R.SII_CONFIG)
        owner_pdi = bool(cfg & R.SII_CONFIG_PDI_OWNS) and not (cfg & R.SII_CONFIG_FORCE_ECAT)
        if cmd == 0:
            status &= _CLEARS_ERRORS
        elif owner_pdi:
            status |= R.SiiControl.ACK_ERROR
        elif cmd == R.SiiControl.CMD_READ:
            off = 2 * (regs.u32(R.SII_ADDRESS) & 0xFFFF)
            n = regs.profile.sii_read_bytes
            chunk = bytes(self.image[off: off + n])
            regs.set_bytes(R.SII_DATA, chunk + b"\xff" * (n - len(chunk)))
            status &= _CLEARS_ERRORS
        elif cmd == R.SiiControl.CMD_WRITE:
            if not we:
                status |= R.SiiControl.WRITE_ENABLE_ERROR
            else:
                self._write_word(regs.u32(R.SII_ADDRESS) & 0xFFFF, now)
                status &= _CLEARS_ERRORS
        elif cmd == R.SiiControl.CMD_RELOAD:
            status &= ~int(R.SiiControl.CHECKSUM_ERROR)
            regs.set_u16(R.SII_CONTROL, status)
            self.load()
            status = regs.u16(R.SII_CONTROL) & ~(R.SII_COMMAND_MASK | int(R.SiiControl.WRITE_ENABLE))
        else:
            status |= R.SiiControl.ACK_ERROR
        prof = regs.profile
        busy_ns = regs.host.sii_busy_ns or (
            prof.sii_write_ns if cmd == R.SiiControl.CMD_WRITE else prof.sii_read_ns)
        if cmd and busy_ns > 0 and not status & R.SiiControl.ACK_ERROR:
            # Real ESCs show busy together with the running command (e.g. 0x8140).
            status |= R.SiiControl.BUSY | cmd
            self.busy_until = now + busy_ns
        # A command spends the write enable bit (real chips read it 0 after
        # a 0x0201 write command); without a command it stays.
        regs.set_u16(R.SII_CONTROL, status | (0 if cmd else we))

    def firmware_write(self, word: int, data: bytes) -> None:
        """Words the slave's firmware writes through the PDI's EEPROM access (0x0500 bit 0).

        Not a master command: no busy time, no write-enable bit. The parsed
        image follows (this slave's own copy from then on).
        """
        off = 2 * word
        if word < 0 or len(data) % 2 or off + len(data) > max(len(self.image), _CATEGORIES):
            raise ValueError(f"SII write of {len(data)} bytes at word 0x{word:04X} outside "
                             f"the {len(self.image)}-byte EEPROM")
        self.image[off: off + len(data)] = data
        self.info = _parse(bytes(self.image))
        self.output_sm, self.input_sm = self._pd_sms()

    def _write_word(self, address: int, now: int) -> None:
        off = 2 * address
        image = self.image
        if off + 2 > len(image):
            image.extend(b"\xff" * (off + 2 - len(image)))
        image[off: off + 2] = self.regs.row[R.SII_DATA: R.SII_DATA + 2].tobytes()
        if self.regs.profile.sii_write_cycle_ns:
            self.write_cycle_until = now + self.regs.profile.sii_write_cycle_ns
        if off < _CONFIG_BYTES or off >= _CATEGORIES:
            self.info = _parse(bytes(image))
            self.output_sm, self.input_sm = self._pd_sms()
