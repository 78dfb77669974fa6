"""A small CoE slave application for master tests, on the simulator's ESC model.

The simulator's ESC gives the real SM0/SM1 behaviour (full/empty gating,
repeat request); this app answers CoE requests with the shared wire state
machines, keeps a tiny object dictionary, can be told to abort, misbehave
or stay silent, and posts emergencies. Tests use it to reach every branch of
the master's CoE client deterministically; the full simulator CoE server
(``builtin:coe-io``) is exercised by the interop tests.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from pyethercat.link.pair import PairLink
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.devices.builtin import AI2
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.segment import Segment, SimSlaveSpec
from pyethercat.wire.mailbox.coe import (
    CoeMessage,
    Emergency,
    ObjectAccess,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoDownloadServer,
    SdoInfoError,
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoGetObjectDescriptionRequest,
    SdoInfoGetObjectDescriptionResponse,
    SdoInfoGetOdListRequest,
    SdoInfoGetOdListResponse,
    SdoInitiateDownloadRequest,
    SdoInitiateUploadRequest,
    SdoUploadServer,
    decode_coe,
    encode_sdo_info_fragments,
)
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType, encode_mailbox, next_counter
from pyethercat.wire.sii import MailboxProtocol, build_sii


@dataclass
class Obj:
    """An object: name, object code, and its entries by subindex (dtype, value, name)."""

    name: str
    code: int  # 7 VAR, 8 ARRAY, 9 RECORD
    entries: dict[int, tuple[int, bytes, str]] = field(default_factory=dict)
    access: int = ObjectAccess.READ_WRITE


def default_od() -> dict[int, Obj]:
    u8, u16, u32 = DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32
    return {
        0x1000: Obj("Device type", 7, {0: (u32, struct.pack("<I", 0x00020192), "Device type")},
                    ObjectAccess.READ),
        0x1008: Obj("Device name", 7, {0: (DataType.VISIBLE_STRING, b"mini-coe", "Name")},
                    ObjectAccess.READ),
        0x1018: Obj("Identity", 9, {0: (u8, b"\x04", "Count"),
                                    1: (u32, struct.pack("<I", 0x00504543), "Vendor ID"),
                                    2: (u32, struct.pack("<I", 0x00040002), "Product code"),
                                    3: (u32, struct.pack("<I", 0x00010000), "Revision"),
                                    4: (u32, struct.pack("<I", 42), "Serial number")},
                    ObjectAccess.READ),
        0x1600: Obj("RxPDO 1", 9, {0: (u8, b"\x01", "Count"),
                                   1: (u32, struct.pack("<I", 0x70000110), "Entry 1")}),
        0x1A00: Obj("TxPDO 1", 9, {0: (u8, b"\x01", "Count"),
                                   1: (u32, struct.pack("<I", 0x60000110), "Entry 1"),
                                   2: (u32, bytes(4), "Entry 2")}),
        0x1A01: Obj("TxPDO 2", 9, {0: (u8, b"\x01", "Count"),
                                   1: (u32, struct.pack("<I", 0x60100110), "Entry 1")}),
        0x1C12: Obj("RxPDO assign", 8, {0: (u8, b"\x01", "Count"),
                                        1: (u16, struct.pack("<H", 0x1600), "PDO 1")}),
        0x1C13: Obj("TxPDO assign", 8, {0: (u8, b"\x01", "Count"),
                                        1: (u16, struct.pack("<H", 0x1A00), "PDO 1"),
                                        2: (u16, b"\x00\x00", "PDO 2")}),
        0x2000: Obj("Parameter", 7, {0: (u32, bytes(4), "Parameter")}),
        0x2001: Obj("Big", 7, {0: (DataType.OCTET_STRING, bytes(range(256)) * 16, "Big")}),
        0x2002: Obj("Gain", 7, {0: (DataType.REAL32, struct.pack("<f", 1.5), "Gain")}),
        0x6000: Obj("Input 1", 7, {0: (DataType.INTEGER16, b"\x00\x00", "Value")},
                    ObjectAccess.READ | ObjectAccess.TXPDO_MAPPABLE),
        0x6010: Obj("Input 2", 7, {0: (DataType.INTEGER16, b"\x00\x00", "Value")},
                    ObjectAccess.READ | ObjectAccess.TXPDO_MAPPABLE),
        0x7000: Obj("Output 1", 7, {0: (DataType.UNSIGNED16, b"\x00\x00", "Value")},
                    ObjectAccess.READ_WRITE | ObjectAccess.RXPDO_MAPPABLE),
    }


class MiniCoe(DeviceApp):
    """CoE server for tests (see the module text)."""

    def __init__(self, od: dict[int, Obj] | None = None, mailbox_size: int = 128) -> None:
        super().__init__()
        self.od = od if od is not None else default_od()
        self.mailbox_size = mailbox_size
        #: (index, subindex) -> abort code answered instead of serving.
        self.aborts: dict[tuple[int, int], int] = {}
        #: Requests to leave unanswered (counted down).
        self.silent = 0
        #: Mangles a reply payload before it is posted (protocol-violation tests).
        self.mangle: Callable[[CoeMessage], CoeMessage] | None = None
        self.requests: list[CoeMessage] = []
        #: Frames a reply waits before the slave posts it (a slow slave; needs ``tick()``).
        self.late = 0
        self._held: deque[tuple[int, bytes, int]] = deque()
        self._frames = 0
        self.downloads: list[tuple[int, int, bytes]] = []
        self._out: deque[bytes] = deque()
        self._counter = 0
        self._last_in = 0
        self._upload: SdoUploadServer | None = None
        self._download: SdoDownloadServer | None = None

    # -- outgoing ----------------------------------------------------------------------

    def post(self, payload: bytes, mtype: int = MailboxType.COE) -> None:
        if self.late:
            self._held.append((self._frames + self.late, payload, mtype))
            return
        self._post(payload, mtype)

    def tick(self) -> None:
        """One frame went by (the segment's responder calls this): post late replies due."""
        self._frames += 1
        while self._held and self._held[0][0] <= self._frames:
            _due, payload, mtype = self._held.popleft()
            self._post(payload, mtype)

    def _post(self, payload: bytes, mtype: int) -> None:
        self._counter = next_counter(self._counter)
        self._out.append(encode_mailbox(mtype, payload, counter=self._counter))
        self._flush()

    def _flush(self) -> None:
        while self._out and self.pdi is not None and self.pdi.post_mailbox(self._out[0]):
            self._out.popleft()

    def on_mailbox_read(self) -> None:
        self._flush()

    def emergency(self, code: int, register: int = 0, data: bytes = bytes(5)) -> None:
        self.post(Emergency(code, register, data).encode())

    # -- incoming ----------------------------------------------------------------------

    def on_mailbox(self, data: bytes) -> None:
        header = MailboxHeader.decode(data)
        if header.counter and header.counter == self._last_in:
            return  # a repeated request (the counter says so)
        self._last_in = header.counter
        payload = data[6:6 + header.length]
        if header.type != MailboxType.COE:
            self.post(struct.pack("<HH", 1, 2), MailboxType.ERR)
            return
        msg = decode_coe(payload)
        self.requests.append(msg)
        if self.silent:
            self.silent -= 1
            return
        for reply in self._serve(msg):
            if self.mangle is not None:
                reply = self.mangle(reply)
            self.post(reply.encode())  # type: ignore[union-attr]

    def _entry(self, index: int, sub: int) -> tuple[int, bytes, str] | int:
        obj = self.od.get(index)
        if obj is None:
            return SdoAbortCode.NO_OBJECT
        if sub not in obj.entries:
            return SdoAbortCode.NO_SUBINDEX
        return obj.entries[sub]

    def _value(self, index: int, sub: int, ca: bool) -> bytes | int:
        if ca:
            obj = self.od.get(index)
            if obj is None:
                return SdoAbortCode.NO_OBJECT
            subs = sorted(s for s in obj.entries if s >= sub)
            out = b""
            for s in subs:
                v = obj.entries[s][1]
                out += v + (b"\x00" if s == 0 else b"")  # sub 0 padded to 16 bits
            return out
        got = self._entry(index, sub)
        return got if isinstance(got, int) else got[1]

    def _serve(self, msg: CoeMessage) -> list[object]:
        size = self.mailbox_size
        if isinstance(msg, SdoInitiateUploadRequest):
            code = self.aborts.get((msg.index, msg.subindex))
            value = code if code is not None else self._value(msg.index, msg.subindex,
                                                               msg.complete_access)
            if isinstance(value, int):
                return [SdoAbortTransfer(msg.index, msg.subindex, value)]
            self._upload = SdoUploadServer(msg.index, msg.subindex, value, mailbox_size=size,
                                           complete_access=msg.complete_access)
            return [self._upload.start()]
        if isinstance(msg, SdoInitiateDownloadRequest):
            code = self.aborts.get((msg.index, msg.subindex))
            if code is None and not msg.complete_access:
                got = self._entry(msg.index, msg.subindex)
                code = got if isinstance(got, int) else None
            if code is not None:
                return [SdoAbortTransfer(msg.index, msg.subindex, code)]
            self._download = SdoDownloadServer(msg)
            ev = self._download.start()
            if ev.data is not None:
                self._store(msg.index, msg.subindex, ev.data, msg.complete_access)
            return [ev.reply]
        if isinstance(msg, SdoAbortTransfer):
            self._upload = self._download = None
            return []
        if self._download is not None and not self._download.done:
            ev = self._download.receive(msg)
            if ev.data is not None:
                self._store(self._download.index, self._download.subindex, ev.data,
                            self._download.complete_access)
            return [ev.reply]
        if self._upload is not None and not self._upload.done:
            return [self._upload.receive(msg)]
        if isinstance(msg, SdoInfoGetOdListRequest):
            return self._info(SdoInfoGetOdListResponse(msg.list_type, tuple(sorted(self.od))))
        if isinstance(msg, SdoInfoGetObjectDescriptionRequest):
            obj = self.od.get(msg.index)
            if obj is None:
                return self._info(SdoInfoError(SdoAbortCode.NO_OBJECT))
            dtype = obj.entries[max(obj.entries)][0] if obj.entries else 0
            return self._info(SdoInfoGetObjectDescriptionResponse(
                msg.index, dtype, max(obj.entries), obj.code, obj.name))
        if isinstance(msg, SdoInfoGetEntryDescriptionRequest):
            got = self._entry(msg.index, msg.subindex)
            if isinstance(got, int):
                return self._info(SdoInfoError(got))
            dtype, value, name = got
            access = self.od[msg.index].access
            return self._info(SdoInfoGetEntryDescriptionResponse(
                msg.index, msg.subindex, 0, dtype, 8 * len(value), access, name))
        return [SdoAbortTransfer(0, 0, SdoAbortCode.INVALID_COMMAND)]

    def _info(self, message: object) -> list[object]:
        frags = encode_sdo_info_fragments(message, self.mailbox_size)  # type: ignore[arg-type]
        return [_Raw(f) for f in frags]

    def _store(self, index: int, sub: int, data: bytes, ca: bool) -> None:
        self.downloads.append((index, sub, data))
        obj = self.od[index]
        if ca:
            pos = 0
            for s in sorted(x for x in obj.entries if x >= sub):
                dtype, old, name = obj.entries[s]
                n = len(old) + (1 if s == 0 else 0)
                obj.entries[s] = (dtype, data[pos:pos + len(old)], name)
                pos += n
            return
        dtype, old, name = obj.entries[sub]
        obj.entries[sub] = (dtype, data, name)


@dataclass(frozen=True)
class _Raw:
    payload: bytes

    def encode(self) -> bytes:
        return self.payload


def coe_sii(mailbox_size: int = 128) -> bytes:
    """SII of a CoE slave: the ai2 layout with CoE announced and the mailbox size chosen."""
    info = AI2.sii_info()
    info.mailbox_protocols = MailboxProtocol.COE
    info.rx_mailbox_size = info.tx_mailbox_size = mailbox_size
    info.tx_mailbox_offset = info.rx_mailbox_offset + mailbox_size
    return build_sii(info)


class DropFilter:
    """Responder wrapper: drops the reply of chosen frames (a lost frame on the wire)."""

    def __init__(self, process: Callable[[bytes], bytes | None]) -> None:
        self.process = process
        #: Drop the reply to the next frame whose datagrams this predicate likes.
        self.drop_when: Callable[[bytes], bool] | None = None
        self.dropped = 0
        self.frames: list[bytes] = []
        #: Called after every frame (MiniCoe.tick of every slave).
        self.ticks: list[Callable[[], None]] = []

    def __call__(self, frame: bytes) -> bytes | None:
        reply = self.process(frame)
        self.frames.append(frame)
        for tick in self.ticks:
            tick()
        if reply is not None and self.drop_when is not None and self.drop_when(reply):
            self.drop_when = None
            self.dropped += 1
            return None
        return reply


def coe_segment(count: int = 1, mailbox_size: int = 128,
                apps: list[MiniCoe] | None = None) -> tuple[Segment, list[MiniCoe], DropFilter,
                                                           PairLink]:
    """A segment of ``count`` MiniCoe slaves and the master's end of the link."""
    seg = Segment()
    made: list[MiniCoe] = []
    # The two mailboxes lie in the chip's process RAM: an ET1200's 1 KiB holds two of
    # 128 bytes but not two of 800 (a real one refuses PREOP with 0x0016), an ET1100's 8 KiB does.
    profile = PROFILES[AI2.profile]
    if AI2.sii_info().rx_mailbox_offset + 2 * mailbox_size > profile.ram_end:
        profile = PROFILES["ET1100"]
    for i in range(count):
        app = apps[i] if apps is not None else MiniCoe(mailbox_size=mailbox_size)
        made.append(app)
        seg.add_slave(SimSlaveSpec(f"coe{i}", coe_sii(mailbox_size), profile, app))
    drop = DropFilter(seg.process)
    drop.ticks = [a.tick for a in made]
    link = PairLink.responder_link(drop)
    return seg, made, drop, link
