"""FoE server of a simulated slave: files in memory or in a directory, firmware in BOOT.

:class:`FoeProtocol` is a mailbox protocol server (type 4) on a
:class:`~pyethercat.sim.mailbox.MailboxDevice`. It runs the slave side of
:mod:`pyethercat.wire.mailbox.foe_transfer` against

- a :class:`FoeStore` in PRE-OP, SAFE-OP and OP: files kept in memory, or in a
  directory the topology names (names are plain file names there, nothing
  that climbs out of it), with an optional password;
- a :class:`~pyethercat.sim.firmware.FirmwareSlot` in BOOT: the bootloader,
  which takes one firmware image, checks it and applies it when the slave
  goes back to INIT.

Test controls: ``busy_every`` answers every n-th DATA packet with BUSY first
(the master must send it again), ``fail_at(packet, code)`` answers one packet
with an FoE error, ``wrap`` numbers the DATA packets it sends modulo 256 like
some devices in the field.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pyethercat.errors import FoeAbort, MailboxError
from pyethercat.sim.firmware import FirmwareImage, FirmwareSlot
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.foe import (
    FoeBusy,
    FoeData,
    FoeError,
    FoeErrorCode,
    FoeReadRequest,
    FoeWriteRequest,
    decode_foe,
)
from pyethercat.wire.mailbox.foe_transfer import FoeFileStore, FoeServer, abort
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType

__all__ = ["DEFAULT_MAX_FILE", "FoeOptions", "FoeProtocol", "FoeStore"]

#: Largest file the store takes unless told otherwise.
DEFAULT_MAX_FILE = 64 << 20


@dataclass
class FoeOptions:
    """FoE settings of one simulated slave (the topology file's ``foe_*`` keys)."""

    enabled: bool = True
    directory: Path | None = None
    password: int = 0
    max_size: int = DEFAULT_MAX_FILE
    busy_every: int = 0
    wrap: int = 1 << 32
    firmware_password: int = 0


class FoeStore:
    """Files of a slave outside BOOT, in memory or in a directory (see the module text)."""

    def __init__(self, directory: Path | None = None, *, password: int = 0,
                 max_size: int = DEFAULT_MAX_FILE) -> None:
        self.directory = directory
        self.password = password
        self.max_size = max_size
        self.files: dict[str, bytes] = {}

    def _path(self, name: str) -> Path:
        assert self.directory is not None
        if not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name:
            raise abort(FoeErrorCode.ACCESS_DENIED, f"{name!r} is not a plain file name")
        return self.directory / name

    def _check(self, password: int) -> None:
        if password != self.password:
            raise abort(FoeErrorCode.NO_RIGHTS, "wrong password")

    def open_read(self, name: str, password: int) -> bytes:
        self._check(password)
        if self.directory is None:
            if name not in self.files:
                raise abort(FoeErrorCode.NOT_FOUND, name)
            return self.files[name]
        try:
            return self._path(name).read_bytes()
        except FileNotFoundError:
            raise abort(FoeErrorCode.NOT_FOUND, name) from None
        except OSError as exc:
            raise abort(FoeErrorCode.ACCESS_DENIED, f"{name}: {exc.strerror}") from None

    def open_write(self, name: str, password: int) -> int | None:
        self._check(password)
        if self.directory is not None:
            self._path(name)
        return self.max_size

    def close_write(self, name: str, data: bytes) -> None:
        if self.directory is None:
            self.files[name] = data
            return
        target = self._path(name)
        # Whole file or nothing: written beside the target (with the usual permissions,
        # unlike a mkstemp file), then renamed over it.
        tmp = target.with_name(f".foe-{name}.{os.getpid()}.tmp")
        try:
            tmp.write_bytes(data)
            os.replace(tmp, target)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise abort(FoeErrorCode.DISK_FULL, f"{name}: {exc.strerror}") from None


class _ByState:
    """The files the FoE server sees: the firmware slot in BOOT, the store otherwise."""

    def __init__(self, state: Callable[[], AlState], store: FoeStore,
                 firmware: FirmwareSlot | None) -> None:
        self.state = state
        self.store = store
        self.firmware = firmware

    def _files(self) -> FoeFileStore:
        if self.state() == AlState.BOOT:
            if self.firmware is None:
                raise abort(FoeErrorCode.NOT_DEFINED, "no bootloader")
            return self.firmware
        return self.store

    def open_read(self, name: str, password: int) -> bytes:
        return self._files().open_read(name, password)

    def open_write(self, name: str, password: int) -> int | None:
        return self._files().open_write(name, password)

    def close_write(self, name: str, data: bytes) -> None:
        self._files().close_write(name, data)


class FoeProtocol:
    """Mailbox protocol server for FoE (type 4) of one simulated slave.

    ``send(payload)`` queues an FoE reply, ``state()`` reads the AL state,
    ``sizes()`` gives the receive (SM0) and send (SM1) mailbox lengths now
    configured. ``on_firmware(image)`` is called when the slave leaves BOOT
    for INIT with a new image (the device shows its revision and version).
    """

    type = MailboxType.FOE

    def __init__(self, send: Callable[[bytes], None], state: Callable[[], AlState],
                 sizes: Callable[[], tuple[int, int]], *, options: FoeOptions | None = None,
                 firmware: FirmwareSlot | None = None,
                 on_firmware: Callable[[FirmwareImage], None] | None = None) -> None:
        opts = options if options is not None else FoeOptions()
        self.options = opts
        self.store = FoeStore(opts.directory, password=opts.password, max_size=opts.max_size)
        self.firmware = firmware
        self.on_firmware = on_firmware
        self._send = send
        self._sizes = sizes
        self._state = state
        self.server = FoeServer(_ByState(state, self.store, firmware), wrap=opts.wrap)
        self.busy_every = opts.busy_every
        #: BUSY answers sent, DATA packets seen.
        self.busy_sent = 0
        self.data_packets = 0
        self._busy_pending: int | None = None
        self._failures: dict[int, int] = {}
        self._mailbox: tuple[int, int] | None = None

    def fail_at(self, packet: int, code: int = FoeErrorCode.PROGRAM_ERROR) -> None:
        """Answer DATA packet ``packet`` of the next write with FoE error ``code`` (once)."""
        self._failures[packet] = code

    def reset(self) -> None:
        """The mailbox stopped: forget the transfer in progress."""
        self.server.reset()
        self._busy_pending = None
        self._mailbox = None

    def on_state_change(self, old: AlState, new: AlState) -> None:
        """Apply a firmware image accepted in BOOT when the slave restarts in INIT."""
        if old == AlState.BOOT and new == AlState.INIT and self.firmware is not None:
            image = self.firmware.take()
            if image is not None and self.on_firmware is not None:
                self.on_firmware(image)

    def handle(self, header: MailboxHeader, payload: bytes) -> None:
        """Serve one FoE request (the mailbox engine calls this)."""
        msg = decode_foe(payload)  # MailboxError: the engine answers "service not supported"
        if isinstance(msg, FoeReadRequest | FoeWriteRequest) or self._mailbox is None:
            # The SM lengths change only in INIT: read them once per transfer.
            self._mailbox = self._sizes()
        rx, tx = self._mailbox
        if isinstance(msg, FoeData) and self.server.busy_transfer:
            self.data_packets += 1
            code = self._failures.pop(msg.packet, None)
            if code is not None:
                self.server.reset()
                self._send(FoeError(code, "injected error").encode())
                return
            if self._answer_busy(msg):
                return
        try:
            reply = self.server.receive(msg, rx, tx)
        except FoeAbort as exc:  # a store refusing in a way the server did not map
            self.server.reset()
            reply = FoeError(exc.code, exc.text)
        except MailboxError:
            raise
        if reply is not None:
            self._send(reply.encode())

    def _answer_busy(self, msg: FoeData) -> bool:
        """BUSY on schedule: every ``busy_every``-th packet is refused once first."""
        if not self.busy_every:
            return False
        if self._busy_pending == msg.packet:
            self._busy_pending = None
            return False
        if self.data_packets % self.busy_every:
            return False
        self._busy_pending = msg.packet
        self.busy_sent += 1
        done = min(0xFFFF, self.server.received // 1024)
        self._send(FoeBusy(done, 0xFFFF, "busy").encode())
        return True
