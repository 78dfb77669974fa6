"""Writing a slave's SII EEPROM so that a failure cannot leave it unusable.

A slave whose SII header checksum is wrong does not load its configuration
words (alias, PDI setup) and a master cannot identify it any more: a write
that stops half way or writes a stale checksum bricks the device until
someone rewrites it. So every write here

1. takes the EEPROM for EtherCAT (0x0500), refusing when the slave's
   firmware holds it (0x0501) unless forced;
2. reads the current content and keeps it (the backup, written to a file
   before the first word is changed when a path is given);
3. checks the new image's identity (vendor, product, revision) against the
   current one unless forced;
4. computes the header checksum (word 7, CRC-8 over words 0-6, ETG.1000.6
   5.4; the same CRC as IgH's ``sii_crc.cpp``) itself;
5. writes word by word, each time waiting out the busy bit (0x0502 bit 15)
   *and* the EEPROM's internal write cycle: after a write an I2C EEPROM does
   not acknowledge anything for up to ~5 ms (24Cxx tWR; a real EK1100 reads
   0x2040 for about 3.3 ms), which the ESC reports as the acknowledge error
   bit 13 on the next command. A command refused that way is repeated; the
   write-enable error (bit 14) is final;
6. reads every written word back and compares it;
7. reloads the configuration words (alias...) into the ESC registers.

A failure raises :class:`SiiWriteError` naming the word, what the EEPROM
holds now and where the backup is. ESC command and status bits: ESC
datasheet section II, registers 0x0500-0x050F (SII EEPROM interface).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pyethercat.errors import SiiError, WorkingCounterError
from pyethercat.master.scan import SiiAccess, read_sii_batch
from pyethercat.master.scheduler import Scheduler
from pyethercat.wire.datagram import Datagram
from pyethercat.wire.registers import (
    SII_CONFIG,
    SII_CONFIG_FORCE_ECAT,
    SII_CONTROL,
    SII_DATA,
    SII_ERROR_MASK,
    SiiControl,
)
from pyethercat.wire.sii import sii_crc
from pyethercat.wire.sii.model import (
    WORD_ALIAS,
    WORD_CHECKSUM,
    WORD_PRODUCT_CODE,
    WORD_REVISION,
    WORD_SERIAL,
    WORD_VENDOR_ID,
)

__all__ = [
    "SiiWriteError",
    "SiiWriteReport",
    "SiiIdentity",
    "WriteTiming",
    "image_identity",
    "with_checksum",
    "with_alias",
    "identity_difference",
    "write_sii_image",
    "reload_sii",
]

#: Bytes the header checksum covers (words 0-6), and the words that hold it.
_HEADER_BYTES = 2 * WORD_CHECKSUM
_HEADER_WORDS = WORD_CHECKSUM + 1
# 0x0502-0x0509: control/status (2), address (4), first two data bytes.
_WINDOW = 8
_BUSY = int(SiiControl.BUSY)
_ACK_ERROR = int(SiiControl.ACK_ERROR)
_WE_ERROR = int(SiiControl.WRITE_ENABLE_ERROR)
_CMD_WRITE = int(SiiControl.CMD_WRITE | SiiControl.WRITE_ENABLE)
_CMD_READ = int(SiiControl.CMD_READ)
_CMD_RELOAD = int(SiiControl.CMD_RELOAD)
_CHECKSUM_ERROR = int(SiiControl.CHECKSUM_ERROR)
#: 0x0501 bit 0: the PDI (the slave's firmware) has the EEPROM.
_PDI_ACCESS = 0x01


class SiiWriteError(SiiError):
    """An SII write stopped; says which word and what the EEPROM holds now.

    ``word`` is the word that failed (None: before the first write),
    ``written`` the words already changed, ``backup`` the file with the old
    content (None when none was written).
    """

    def __init__(self, message: str, *, word: int | None = None,
                 written: tuple[int, ...] = (), backup: Path | None = None) -> None:
        self.word = word
        self.written = written
        self.backup = backup
        self.reason = message
        super().__init__(message + self.state_text())

    def state_text(self) -> str:
        """What the EEPROM holds now and how to get the old content back."""
        if not self.written:
            text = "; nothing was written, the EEPROM is unchanged"
        else:
            text = (f"; {len(self.written)} word{'s' if len(self.written) != 1 else ''} "
                    f"(0x{self.written[0]:04X}-0x{self.written[-1]:04X}) hold the new image")
        if self.backup is not None and self.written:
            text += f"; restore the old content with sii_write --force {self.backup}"
        elif self.backup is not None:
            text += f" (backup: {self.backup})"
        return text


@dataclass(frozen=True, slots=True)
class SiiIdentity:
    """Vendor, product, revision and serial from SII words 8-15."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def __str__(self) -> str:
        return (f"vendor 0x{self.vendor_id:08X} product 0x{self.product_code:08X} "
                f"revision 0x{self.revision:08X}")


@dataclass(frozen=True, slots=True)
class WriteTiming:
    """How long one command may keep the interface busy or unacknowledged.

    ``word_timeout`` bounds the busy bit plus the EEPROM write cycle of one
    word (real EEPROMs: at most ~5 ms; IgH allows 20 ms per command);
    ``min_polls`` status reads are always allowed, so a link that answers
    without real time passing (the in-process simulator, whose clock moves
    with the frames) still sees the write cycle end. ``pause`` is slept
    between polls of a refused command (0 on such links).
    """

    word_timeout: float = 0.05
    min_polls: int = 8
    pause: float = 0.0005

    @classmethod
    def for_virtual_time(cls) -> WriteTiming:
        """Timing for links whose peer's clock moves only with the frames."""
        return cls(word_timeout=0.0, min_polls=20000, pause=0.0)


@dataclass
class SiiWriteReport:
    """What :func:`write_sii_image` did."""

    #: Words in the written image (after padding to an even length).
    words: int
    #: Word addresses written (in order); empty when the EEPROM already held the image.
    written: list[int] = field(default_factory=list)
    #: The checksum byte written to word 7, and whether the given image had another one.
    checksum: int = 0
    checksum_fixed: bool = False
    #: The content before the write (as long as the image or the old chain, whichever is longer).
    old: bytes = field(default=b"", repr=False)
    #: Where ``old`` was saved (None: not saved).
    backup: Path | None = None
    #: Identity fields that differ between old and new (forced writes only).
    identity_changes: list[str] = field(default_factory=list)
    #: Commands the EEPROM refused while busy with its write cycle and that were repeated.
    retries: int = 0


# --- images (pure) --------------------------------------------------------------------


def with_checksum(image: bytes) -> bytes:
    """``image`` padded to whole words with the header checksum byte set (word 7 low byte).

    The high byte of word 7 is kept (reserved; Beckhoff images carry 0).
    """
    data = bytearray(image)
    if len(data) % 2:
        data.append(0xFF)
    if len(data) < 2 * _HEADER_WORDS:
        raise SiiError(f"SII image of {len(image)} bytes is shorter than its 16-byte header")
    data[_HEADER_BYTES] = sii_crc(bytes(data[:_HEADER_BYTES]))
    return bytes(data)


def with_alias(image: bytes, alias: int) -> bytes:
    """``image`` with the station alias (word 4) set and the checksum recomputed."""
    if not 0 <= alias <= 0xFFFF:
        raise SiiError(f"alias {alias} out of range 0..65535")
    data = bytearray(image)
    if len(data) < 2 * _HEADER_WORDS:
        raise SiiError(f"SII of {len(image)} bytes is too short to hold an alias (16 bytes needed)")
    struct.pack_into("<H", data, 2 * WORD_ALIAS, alias)
    return with_checksum(bytes(data))


def image_identity(image: bytes) -> SiiIdentity | None:
    """Identity words 8-15 of an image (None if the image is shorter)."""
    if len(image) < 2 * WORD_SERIAL + 4:
        return None
    return SiiIdentity(*struct.unpack_from("<4I", image, 2 * WORD_VENDOR_ID))


def identity_difference(old: bytes, new: bytes) -> list[str]:
    """``["product 0x... -> 0x..."]`` for every identity field that differs (serial excluded).

    A serial number differs between two units of the same device; copying
    an image between them is what ``sii_write`` is for, so it does not count.
    An old image without a valid checksum or identity (blank, corrupt) gives
    no difference: there is nothing to protect.
    """
    a, b = image_identity(old), image_identity(new)
    if a is None or b is None or sii_crc(old) != old[_HEADER_BYTES]:
        return []
    if a.vendor_id in (0, 0xFFFFFFFF):
        return []
    out = []
    for name, word in (("vendor", WORD_VENDOR_ID), ("product", WORD_PRODUCT_CODE),
                       ("revision", WORD_REVISION)):
        x = struct.unpack_from("<I", old, 2 * word)[0]
        y = struct.unpack_from("<I", new, 2 * word)[0]
        if x != y:
            out.append(f"{name} 0x{x:08X} -> 0x{y:08X}")
    return out


# --- the interface --------------------------------------------------------------------


class _Interface:
    """The SII registers of one slave, with a per-command poll budget."""

    def __init__(self, scheduler: Scheduler, access: SiiAccess, timing: WriteTiming,
                 sleep: Callable[[float], None], now: Callable[[], float]) -> None:
        self.scheduler = scheduler
        self.access = access
        self.timing = timing
        self.sleep = sleep
        self.now = now
        self.retries = 0

    def _transact(self, datagrams: list[Datagram], what: str) -> list[Datagram]:
        replies = self.scheduler.transact(datagrams)
        for r in replies:
            if r.wkc != 1:
                raise WorkingCounterError(f"{self.access.label}: {what}", 1, r.wkc)
        return replies

    def status(self) -> tuple[int, bytes]:
        """Control/status word and the first two data bytes."""
        reply = self._transact([self.access.rd(SII_CONTROL, _WINDOW)], "SII status read")[0]
        return struct.unpack_from("<H", reply.data)[0], bytes(reply.data[6:8])

    def clear_errors(self) -> None:
        self._transact([self.access.wr(SII_CONTROL, b"\0\0")], "clearing the SII error bits")

    def run(self, command: list[Datagram], what: str) -> tuple[int, bytes]:
        """Send a command (its datagrams), poll until done; repeat while unacknowledged.

        Returns the final status and data bytes. Raises :class:`SiiError` on
        a write-enable error or when the budget runs out.
        """
        deadline = self.now() + self.timing.word_timeout
        polls = 0

        def spent() -> bool:
            return polls >= self.timing.min_polls and self.now() >= deadline

        def idle(ctrl: int, data: bytes) -> tuple[int, bytes]:
            nonlocal polls
            while ctrl & _BUSY:
                polls += 1
                if spent():
                    raise SiiError(f"SII interface stays busy ({what}, status 0x{ctrl:04X})")
                ctrl, data = self.status()
            return ctrl, data

        ctrl, data = idle(*self.status())
        while True:
            if ctrl & SII_ERROR_MASK:
                self.clear_errors()
            replies = self._transact([*command, self.access.rd(SII_CONTROL, _WINDOW)], what)
            ctrl, data = idle(struct.unpack_from("<H", replies[-1].data)[0],
                              bytes(replies[-1].data[6:8]))
            if ctrl & _WE_ERROR:
                raise SiiError(f"{what}: write enable not taken (status 0x{ctrl:04X})")
            if not ctrl & _ACK_ERROR:
                return ctrl, data
            # The EEPROM did not acknowledge: it is still in the write cycle of the
            # previous word (or absent). The ESC did not carry the command out.
            polls += 1
            self.retries += 1
            if spent():
                raise SiiError(f"{what}: the EEPROM does not acknowledge (status 0x{ctrl:04X})")
            if self.timing.pause:
                self.sleep(self.timing.pause)

    def write_word(self, word: int, value: bytes) -> None:
        self.run([self.access.wr(SII_DATA, value),
                  self.access.wr(SII_CONTROL, struct.pack("<HI", _CMD_WRITE, word))],
                 f"SII write of word 0x{word:04X}")

    def read_word(self, word: int) -> bytes:
        _, data = self.run([self.access.wr(SII_CONTROL, struct.pack("<HI", _CMD_READ, word))],
                           f"SII read-back of word 0x{word:04X}")
        return data

    def reload(self) -> None:
        ctrl, _ = self.run([self.access.wr(SII_CONTROL, struct.pack("<HI", _CMD_RELOAD, 0))],
                           "SII reload")
        if ctrl & _CHECKSUM_ERROR:
            raise SiiError(f"the ESC reports a header checksum error after the reload "
                           f"(status 0x{ctrl:04X})")


def take_eeprom(scheduler: Scheduler, access: SiiAccess, *, force: bool = False) -> None:
    """Give the EEPROM to EtherCAT (0x0500 = 0); with ``force`` take it from the PDI.

    Without ``force`` a slave whose firmware holds the EEPROM (0x0501 bit 0)
    is left alone: forcing could break the firmware's own EEPROM access.
    """
    reply = scheduler.transact_one(access.rd(SII_CONFIG, 2))
    if reply.wkc != 1:
        raise WorkingCounterError(f"{access.label}: SII configuration read", 1, reply.wkc)
    if reply.data[1] & _PDI_ACCESS and not force:
        raise SiiWriteError(f"{access.label}: the slave's firmware (PDI) holds the EEPROM "
                       "(0x0501 = 0x01); force the write to take it over")
    values = (SII_CONFIG_FORCE_ECAT, 0) if force else (0,)
    for v in values:
        r = scheduler.transact_one(access.wr(SII_CONFIG, bytes([v])))
        if r.wkc != 1:
            raise WorkingCounterError(f"{access.label}: SII configuration write", 1, r.wkc)


def reload_sii(scheduler: Scheduler, access: SiiAccess, *,
               timing: WriteTiming | None = None,
               sleep: Callable[[float], None] = time.sleep,
               now: Callable[[], float] = time.monotonic) -> None:
    """Make the ESC load its configuration words (alias, PDI setup) from the EEPROM."""
    _Interface(scheduler, access, timing or WriteTiming(), sleep, now).reload()


def _read_old(scheduler: Scheduler, access: SiiAccess, length: int) -> bytes:
    """The current content: up to the end marker, and at least ``length`` bytes."""
    chain = read_sii_batch(scheduler, [access])[0]
    if isinstance(chain, Exception):
        chain = b""
    if len(chain) >= length:
        return chain
    more = read_sii_batch(scheduler, [access], length=length)[0]
    if isinstance(more, Exception):
        raise SiiWriteError(f"{access.label}: cannot read the current SII before writing: {more}")
    return more


def _save(path: Path, data: bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        tmp.write_bytes(data)
        tmp.replace(path)
    except OSError as exc:
        raise SiiWriteError(f"cannot save the backup to {path}: {exc.strerror or exc}") from None


def write_sii_image(scheduler: Scheduler, access: SiiAccess, image: bytes, *,
                    force: bool = False, only_changed: bool = True, reload: bool = True,
                    backup: Path | Callable[[bytes], Path] | None = None,
                    timing: WriteTiming | None = None,
                    sleep: Callable[[float], None] = time.sleep,
                    now: Callable[[], float] = time.monotonic,
                    progress: Callable[[str, int, int], None] | None = None) -> SiiWriteReport:
    """Write ``image`` into one slave's EEPROM safely (see the module text).

    ``force`` writes an image of another identity and takes the EEPROM from
    the slave's firmware. ``now``/``sleep`` are the master's clock (seconds). ``only_changed`` skips words that already hold the
    new value. ``backup`` is the file for the old content, or a function that
    names it from the old content (called once, before anything is written).
    """
    new = with_checksum(image)
    report = SiiWriteReport(words=len(new) // 2, checksum=new[_HEADER_BYTES])
    report.checksum_fixed = len(image) > _HEADER_BYTES and image[_HEADER_BYTES] != new[_HEADER_BYTES]
    timing = timing or WriteTiming()
    take_eeprom(scheduler, access, force=force)
    old = _read_old(scheduler, access, len(new))
    report.old = old
    changes = identity_difference(old, new)
    if changes and not force:
        raise SiiWriteError(f"{access.label}: the image is for another device ({', '.join(changes)}); "
                            "force the write if that is intended")
    report.identity_changes = changes
    todo = [w for w in range(len(new) // 2)
            if not only_changed or new[2 * w:2 * w + 2] != old[2 * w:2 * w + 2]]
    if todo and backup is not None:
        path = backup(old) if callable(backup) else Path(backup)
        _save(path, old)
        report.backup = path
    iface = _Interface(scheduler, access, timing, sleep, now)
    for n, w in enumerate(todo):
        if progress is not None:
            progress("sii_write", n, len(todo))
        want = new[2 * w:2 * w + 2]
        try:
            iface.write_word(w, want)
            got = iface.read_word(w)
        except (SiiError, WorkingCounterError) as exc:
            raise SiiWriteError(f"{access.label}: writing word 0x{w:04X} failed: {exc}", word=w,
                                written=tuple(report.written), backup=report.backup) from None
        report.written.append(w)
        if got != want:
            raise SiiWriteError(
                f"{access.label}: word 0x{w:04X} reads back {got.hex(' ')}, wrote {want.hex(' ')}",
                word=w, written=tuple(report.written), backup=report.backup)
    report.retries = iface.retries
    if progress is not None:
        progress("sii_write", len(todo), len(todo))
    if reload:
        try:
            iface.reload()
        except (SiiError, WorkingCounterError) as exc:
            raise SiiWriteError(f"{access.label}: every word was written and verified, but the "
                                f"reload failed: {exc}", written=tuple(report.written),
                                backup=report.backup) from None
    return report
