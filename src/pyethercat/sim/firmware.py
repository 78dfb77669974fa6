"""Firmware images of simulated slaves, and the slot a bootloader writes them into.

Real bootloaders check what they are given before they flash it: that the
image is meant for this device and that it arrived intact. The simulator's
image format carries what such a check needs (all little-endian)::

    0   4  magic "PEFW"
    4   u16 header version (1)
    6   u16 length of the version text
    8   u32 vendor id        } the device the image is built for
    12  u32 product code     }
    16  u32 revision number  (becomes SII words 0x0C-0x0D and 0x1018:03)
    20  u32 payload length
    24  u32 CRC-32 of everything after this field (version text and payload)
    28  version text (UTF-8; becomes 0x100A, manufacturer software version)
    ..  payload

A bad image is refused with the FoE error a bootloader gives (SOES
``soes/esc.h`` codes, as ETG.1020's FoE error table lists them): a file that is
not an image or is for another device 0x8004 "illegal", a damaged one
0x800C "checksum error", one larger than the flash 0x8003 "disk full".
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from pyethercat.errors import FoeAbort
from pyethercat.wire.mailbox.foe import FoeErrorCode
from pyethercat.wire.mailbox.foe_transfer import abort

__all__ = [
    "FIRMWARE_MAGIC",
    "FirmwareImage",
    "FirmwareSlot",
    "build_firmware_image",
    "parse_firmware_image",
]

FIRMWARE_MAGIC = b"PEFW"
_HEADER = struct.Struct("<4sHHIIIII")
#: Flash size of a simulated device unless the topology says otherwise.
DEFAULT_FLASH_SIZE = 16 << 20


@dataclass(frozen=True, slots=True)
class FirmwareImage:
    """A parsed firmware image."""

    vendor_id: int
    product_code: int
    revision: int
    version: str
    payload: bytes


def build_firmware_image(vendor_id: int, product_code: int, revision: int, version: str,
                         payload: bytes) -> bytes:
    """The bytes of a firmware image for the given device (see the module text)."""
    text = version.encode("utf-8")
    body = text + bytes(payload)
    return _HEADER.pack(FIRMWARE_MAGIC, 1, len(text), vendor_id, product_code, revision,
                        len(payload), zlib.crc32(body)) + body


def parse_firmware_image(data: bytes) -> FirmwareImage:
    """Parse and check an image; :class:`FoeAbort` with the bootloader's code if bad."""
    if len(data) < _HEADER.size or data[:4] != FIRMWARE_MAGIC:
        raise abort(FoeErrorCode.ILLEGAL, "not a firmware image")
    _magic, hver, tlen, vendor, product, revision, plen, crc = _HEADER.unpack_from(data, 0)
    if hver != 1:
        raise abort(FoeErrorCode.ILLEGAL, f"firmware header version {hver} not supported")
    body = data[_HEADER.size:]
    if len(body) != tlen + plen:
        raise abort(FoeErrorCode.CHECKSUM_ERROR,
                    f"image has {len(body)} bytes after the header, it says {tlen + plen}")
    if zlib.crc32(body) != crc:
        raise abort(FoeErrorCode.CHECKSUM_ERROR, "image CRC mismatch")
    try:
        version = body[:tlen].decode("utf-8")
    except UnicodeDecodeError:
        raise abort(FoeErrorCode.ILLEGAL, "version text is not UTF-8") from None
    return FirmwareImage(vendor, product, revision, version, bytes(body[tlen:]))


class FirmwareSlot:
    """What a slave's bootloader does with FoE in BOOT: take one image, check it, keep it.

    Used as the :class:`~pyethercat.wire.mailbox.foe_transfer.FoeFileStore` of the
    FoE server while the slave is in BOOT. ``pending`` holds the accepted
    image until the slave "restarts" (BOOT -> INIT), when the device applies
    it (:meth:`take`). ``current`` is the image running now (None: the one
    the device was built with).
    """

    def __init__(self, vendor_id: int, product_code: int, *, password: int = 0,
                 flash_size: int = DEFAULT_FLASH_SIZE) -> None:
        self.vendor_id = vendor_id
        self.product_code = product_code
        self.password = password
        self.flash_size = flash_size
        self.pending: FirmwareImage | None = None
        self.current: FirmwareImage | None = None
        #: Images refused, with the error each got (newest last).
        self.refused: list[FoeAbort] = []

    def open_read(self, name: str, password: int) -> bytes:
        # A bootloader has no file system to read from.
        raise abort(FoeErrorCode.NOT_FOUND, f"{name}: no files in BOOT")

    def open_write(self, name: str, password: int) -> int | None:
        if password != self.password:
            raise abort(FoeErrorCode.NO_RIGHTS, "wrong password")
        return self.flash_size

    def close_write(self, name: str, data: bytes) -> None:
        try:
            image = parse_firmware_image(data)
            if (image.vendor_id, image.product_code) != (self.vendor_id, self.product_code):
                raise abort(FoeErrorCode.ILLEGAL,
                            f"image is for vendor 0x{image.vendor_id:08X} product "
                            f"0x{image.product_code:08X}, this is vendor 0x{self.vendor_id:08X}"
                            f" product 0x{self.product_code:08X}")
        except FoeAbort as exc:
            self.refused.append(exc)
            raise
        self.pending = image

    def take(self) -> FirmwareImage | None:
        """The image to start with after the restart (and forget it as pending)."""
        image, self.pending = self.pending, None
        if image is not None:
            self.current = image
        return image
