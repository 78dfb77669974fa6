"""A CoE slave on an in-process segment, driven by real mailbox frames (FPWR SM0 / FPRD SM1).

The master side uses the sans-IO clients of ``wire.mailbox.coe``, so every
test exchanges the bytes a real master would.
"""

from __future__ import annotations

import struct

from pyethercat.clock import VirtualClock
from pyethercat.errors import SdoAbort
from pyethercat.sim.devices import DEVICES, behaviour
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.segment import Segment, SimSlaveSpec
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import decode_frame, encode_frame
from pyethercat.wire.mailbox import decode_message
from pyethercat.wire.mailbox.coe import (
    CoeMessage,
    SdoDownloadClient,
    SdoInfoReassembler,
    SdoTransferDone,
    SdoUploadClient,
    decode_coe,
)
from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType, encode_mailbox, next_counter
from pyethercat.wire.sii import parse_sii

STATION = 0x1001
MBX_OUT, MBX_IN, MBX_SIZE = 0x1000, 0x1080, 128
SM2, SM3 = 0x1100, 0x1180


def sm_bytes(start: int, length: int, control: int, enable: int = 1) -> bytes:
    return struct.pack("<HHBBBB", start, length, control, 0, enable, 0)


class CoeSlave:
    """One built-in CoE slave in PREOP on its own segment."""

    def __init__(self, builtin: str = "coe-io", serial: int = 7) -> None:
        dev = DEVICES[builtin]
        sii = dev.sii_image(serial=serial)
        run = behaviour(dev, parse_sii(sii))
        self.app = run.app
        self.clock = VirtualClock(1_000_000)
        self.seg = Segment(self.clock)
        self.seg.add_slave(SimSlaveSpec(builtin, sii, PROFILES[dev.profile], run.app, model=run.model,
                                     instance=run.instance))
        assert self.dg(Datagram.positional(Command.APWR, 0, R.STATION_ADDRESS,
                                           struct.pack("<H", STATION))).wkc == 1
        self.fpwr(R.sm_address(0), sm_bytes(MBX_OUT, MBX_SIZE, R.SM_CONTROL_MAILBOX_OUT))
        self.fpwr(R.sm_address(1), sm_bytes(MBX_IN, MBX_SIZE, R.SM_CONTROL_MAILBOX_IN))
        assert self.request_state(AlState.PREOP) == (int(AlState.PREOP), 0)
        self.counter = 0

    # --- registers --------------------------------------------------------------------

    def dg(self, d: Datagram) -> Datagram:
        reply = self.seg.process(encode_frame([d]))
        assert reply is not None
        return decode_frame(reply).datagrams[0]

    def fpwr(self, ado: int, data: bytes) -> int:
        return self.dg(Datagram.device(Command.FPWR, STATION, ado, data)).wkc

    def fprd(self, ado: int, n: int) -> Datagram:
        return self.dg(Datagram.device(Command.FPRD, STATION, ado, n))

    def request_state(self, state: AlState) -> tuple[int, int]:
        """Write AL control; (AL status, AL status code) afterwards."""
        self.fpwr(R.AL_CONTROL, struct.pack("<H", int(state)))
        status = struct.unpack("<H", self.fprd(R.AL_STATUS, 2).data)[0]
        code = struct.unpack("<H", self.fprd(R.AL_STATUS_CODE, 2).data)[0]
        return status, code

    def ack(self, state: AlState) -> None:
        self.fpwr(R.AL_CONTROL, struct.pack("<H", int(state) | R.AL_ERROR_FLAG))

    def configure_process_data(self, out_len: int, in_len: int) -> None:
        """SM2/SM3 with these lengths (0: disabled)."""
        self.fpwr(R.sm_address(2), sm_bytes(SM2, out_len, R.SM_CONTROL_OUTPUTS, int(out_len > 0)))
        self.fpwr(R.sm_address(3), sm_bytes(SM3, in_len, R.SM_CONTROL_INPUTS, int(in_len > 0)))

    # --- mailbox ----------------------------------------------------------------------

    def send_raw(self, frame: bytes) -> int:
        """FPWR the whole SM0 (frame padded to the SM length); the working counter."""
        return self.fpwr(MBX_OUT, frame.ljust(MBX_SIZE, b"\x00"))

    def send(self, payload: bytes, mtype: int = MailboxType.COE, counter: int | None = None,
             **kw: int) -> int:
        if counter is None:
            self.counter = next_counter(self.counter)
            counter = self.counter
        return self.send_raw(encode_mailbox(mtype, payload, counter=counter, **kw))

    def fetch(self) -> bytes | None:
        """FPRD the whole SM1; None when it was empty (working counter 0)."""
        d = self.fprd(MBX_IN, MBX_SIZE)
        return bytes(d.data) if d.wkc else None

    def fetch_message(self) -> tuple[MailboxHeader, object]:
        raw = self.fetch()
        assert raw is not None, "no reply in SM1"
        return decode_message(raw)

    def exchange(self, msg: CoeMessage) -> CoeMessage:
        """Send one CoE request, return the decoded CoE reply."""
        assert self.send(msg.encode()) == 1
        header, reply = self.fetch_message()
        assert header.type == MailboxType.COE, reply
        return reply  # type: ignore[return-value]

    # --- SDO --------------------------------------------------------------------------

    def upload(self, index: int, sub: int, ca: bool = False) -> bytes:
        client = SdoUploadClient(index, sub, complete_access=ca)
        msg: object = client.start()
        while True:
            reply = self.exchange(msg)  # type: ignore[arg-type]
            msg = client.receive(reply)
            if isinstance(msg, SdoTransferDone):
                return msg.data

    def download(self, index: int, sub: int, data: bytes, ca: bool = False,
                 expedited: bool | None = None) -> None:
        client = SdoDownloadClient(index, sub, data, mailbox_size=MBX_SIZE, complete_access=ca,
                                   expedited=expedited)
        msg: object = client.start()
        while True:
            reply = self.exchange(msg)  # type: ignore[arg-type]
            msg = client.receive(reply)
            if isinstance(msg, SdoTransferDone):
                return

    def abort_code(self, fn: object, *args: object, **kw: object) -> int:
        try:
            fn(*args, **kw)  # type: ignore[operator]
        except SdoAbort as exc:
            return exc.code
        raise AssertionError("no abort")

    def info(self, msg: object) -> object:
        """One SDO information request; the reassembled response."""
        assert self.send(msg.encode()) == 1  # type: ignore[attr-defined]
        r = SdoInfoReassembler()
        while True:
            raw = self.fetch()
            assert raw is not None
            header = MailboxHeader.decode(raw)
            out = r.feed(raw[6: 6 + header.length])
            if out is not None:
                return out


def coe_of(raw: bytes) -> CoeMessage:
    header = MailboxHeader.decode(raw)
    return decode_coe(raw[6: 6 + header.length])
