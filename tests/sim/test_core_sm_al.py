"""Sync managers (mailbox, three-buffer, watchdog) and the AL state machine."""

from __future__ import annotations

import struct

from simhelp import (
    IN_SM,
    MBX_IN,
    MBX_OUT,
    OUT_SM,
    address_all,
    fmmu_bytes,
    fprd,
    fpwr,
    one,
    sm_bytes,
    spec,
    u16,
)

from pyethercat.clock import VirtualClock
from pyethercat.sim.device import DeviceApp
from pyethercat.sim.segment import Segment
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.datagram import Command, Datagram

ST = 0x1000


class Recorder(DeviceApp):
    mailbox_auto_read = False

    def __init__(self) -> None:
        super().__init__()
        self.mailboxes: list[bytes] = []
        self.states: list[tuple[AlState, AlState]] = []
        self.extra_code = 0

    def on_mailbox(self, data: bytes) -> None:
        self.mailboxes.append(data)

    def on_state_change(self, old: AlState, new: AlState) -> None:
        self.states.append((old, new))

    def check_transition(self, current: AlState, requested: AlState) -> int:
        return self.extra_code


def mbx_segment(app: DeviceApp | None = None, **kw: object) -> Segment:
    seg = Segment(VirtualClock(0))
    seg.add_slave(spec("m", app=app, mailbox=True, **kw))
    address_all(seg)
    return seg


def setup_mailbox(seg: Segment) -> None:
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 128, R.SM_CONTROL_MAILBOX_OUT))
    fpwr(seg, ST, R.sm_address(1), sm_bytes(MBX_IN, 128, R.SM_CONTROL_MAILBOX_IN))


def request(seg: Segment, state: int) -> tuple[int, int]:
    fpwr(seg, ST, R.AL_CONTROL, struct.pack("<H", state))
    return u16(fprd(seg, ST, R.AL_STATUS, 2)), u16(fprd(seg, ST, R.AL_STATUS_CODE, 2))


# --- mailbox ---------------------------------------------------------------------------------


def test_mailbox_write_full_refused_then_read_by_pdi() -> None:
    app = Recorder()
    seg = mbx_segment(app)
    setup_mailbox(seg)
    msg = bytes(range(128))
    assert fpwr(seg, ST, MBX_OUT, msg).wkc == 1
    assert app.mailboxes == [msg]
    assert fprd(seg, ST, R.sm_address(0) + R.SM_STATUS, 1).data[0] & R.SM_STATUS_MAILBOX_FULL
    assert fpwr(seg, ST, MBX_OUT, msg).wkc == 0  # full: refused
    app.pdi.read(MBX_OUT, 128)  # firmware reads it, including the last byte
    assert not fprd(seg, ST, R.sm_address(0) + R.SM_STATUS, 1).data[0] & R.SM_STATUS_MAILBOX_FULL
    assert fpwr(seg, ST, MBX_OUT, msg).wkc == 1


def test_partial_mailbox_write_is_not_complete() -> None:
    app = Recorder()
    seg = mbx_segment(app)
    setup_mailbox(seg)
    assert fpwr(seg, ST, MBX_OUT, bytes(64)).wkc == 1
    assert app.mailboxes == []
    assert fpwr(seg, ST, MBX_OUT + 127, b"\x01").wkc == 1  # the last byte completes it
    assert len(app.mailboxes) == 1


def test_send_mailbox_empty_read_refused_and_last_byte_empties() -> None:
    app = Recorder()
    seg = mbx_segment(app)
    setup_mailbox(seg)
    assert fprd(seg, ST, MBX_IN, 128).wkc == 0
    assert app.pdi.post_mailbox(b"\x0a\x00hello")
    assert not app.pdi.post_mailbox(b"again")  # still full
    d = fprd(seg, ST, MBX_IN, 128)
    assert d.wkc == 1 and d.data.startswith(b"\x0a\x00hello")
    assert fprd(seg, ST, MBX_IN, 128).wkc == 0
    # status byte through 0x080D shows full/empty
    app.pdi.post_mailbox(b"x")
    assert fprd(seg, ST, R.sm_address(1) + R.SM_STATUS, 1).data[0] & R.SM_STATUS_MAILBOX_FULL


def test_mailbox_repeat_request() -> None:
    app = Recorder()
    seg = mbx_segment(app)
    setup_mailbox(seg)
    app.pdi.post_mailbox(b"reply-1")
    assert fprd(seg, ST, MBX_IN, 128).data.startswith(b"reply-1")
    # reply lost: master toggles the repeat request bit of SM1 activate
    act = fprd(seg, ST, R.sm_address(1) + R.SM_ACTIVATE, 1).data[0]
    fpwr(seg, ST, R.sm_address(1) + R.SM_ACTIVATE, bytes([act ^ R.SM_ACTIVATE_REPEAT]))
    pdi = fprd(seg, ST, R.sm_address(1) + R.SM_PDI_CONTROL, 1).data[0]
    assert pdi & R.SM_PDI_REPEAT_ACK
    d = fprd(seg, ST, MBX_IN, 128)
    assert d.wkc == 1 and d.data.startswith(b"reply-1")


def test_auto_read_mailbox_without_app() -> None:
    seg = mbx_segment(None)
    setup_mailbox(seg)
    assert fpwr(seg, ST, MBX_OUT, bytes(128)).wkc == 1
    assert fpwr(seg, ST, MBX_OUT, bytes(128)).wkc == 1


# --- three-buffer ----------------------------------------------------------------------------


def test_three_buffer_outputs_visible_only_when_complete_and_status() -> None:
    seg = Segment()
    seg.add_slave(spec("do", out_bits=32))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(OUT_SM, 4, R.SM_CONTROL_OUTPUTS))
    st = fprd(seg, ST, R.sm_address(2) + R.SM_STATUS, 1).data[0]
    assert (st & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT == 3
    pdi = seg.slaves[0].esc.pdi
    assert pdi.outputs() == b""
    fpwr(seg, ST, OUT_SM, b"\x01\x02")
    assert pdi.outputs() == b""
    fpwr(seg, ST, OUT_SM, b"\x01\x02\x03\x04")
    assert pdi.outputs() == b"\x01\x02\x03\x04"
    fpwr(seg, ST, OUT_SM, b"\xaa\xbb")  # a new buffer begun, not complete
    assert pdi.outputs() == b"\x01\x02\x03\x04"
    st = fprd(seg, ST, R.sm_address(2) + R.SM_STATUS, 1).data[0]
    assert st & R.SM_STATUS_WRITE_EVENT
    assert (st & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT == 0
    fpwr(seg, ST, OUT_SM + 2, b"\xcc\xdd")
    assert pdi.outputs() == b"\xaa\xbb\xcc\xdd"
    st = fprd(seg, ST, R.sm_address(2) + R.SM_STATUS, 1).data[0]
    assert (st & R.SM_STATUS_BUFFER_MASK) >> R.SM_STATUS_BUFFER_SHIFT == 1
    # the write raised the SM2 AL event for the PDI
    assert seg.slaves[0].esc.u32(R.AL_EVENT_REQUEST) & R.al_event_sm(2)


def test_master_cannot_write_input_buffer() -> None:
    seg = Segment()
    seg.add_slave(spec("di", in_bits=8))
    address_all(seg)
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    seg.slaves[0].esc.pdi.set_inputs(b"\x42")
    assert fpwr(seg, ST, IN_SM, b"\x00").wkc == 0
    assert fprd(seg, ST, IN_SM, 1).data == b"\x42"


# --- AL state machine -----------------------------------------------------------------------


def test_init_to_preop_checks_mailbox_sms() -> None:
    seg = mbx_segment(None)
    status, code = request(seg, AlState.PREOP)
    assert status == AlState.INIT | R.AL_ERROR_FLAG and code == AlStatusCode.INVALID_MAILBOX_CONFIG
    # a request without acknowledge is ignored while the error is set
    setup_mailbox(seg)
    status, _ = request(seg, AlState.PREOP)
    assert status == AlState.INIT | R.AL_ERROR_FLAG
    status, code = request(seg, AlState.PREOP | R.AL_ERROR_FLAG)
    assert status == AlState.PREOP and code == 0


def test_invalid_and_unknown_transitions() -> None:
    seg = mbx_segment(None)
    status, code = request(seg, AlState.OP)
    assert status == AlState.INIT | R.AL_ERROR_FLAG and code == AlStatusCode.INVALID_STATE_CHANGE
    status, code = request(seg, AlState.INIT | R.AL_ERROR_FLAG)
    assert status == AlState.INIT and code == 0
    status, code = request(seg, 0x05)
    assert status == AlState.INIT | R.AL_ERROR_FLAG and code == AlStatusCode.UNKNOWN_STATE
    status, code = request(seg, AlState.BOOT | R.AL_ERROR_FLAG)
    assert code == AlStatusCode.BOOTSTRAP_NOT_SUPPORTED
    # an INIT request acknowledges implicitly
    status, code = request(seg, AlState.INIT)
    assert status == AlState.INIT and code == 0


def _to_preop(seg: Segment) -> None:
    setup_mailbox(seg)
    assert request(seg, AlState.PREOP)[0] == AlState.PREOP


def test_preop_to_safeop_checks_process_data_sms() -> None:
    seg = mbx_segment(None, out_bits=16, in_bits=8)
    _to_preop(seg)
    assert request(seg, AlState.OP) == (AlState.PREOP | R.AL_ERROR_FLAG, AlStatusCode.INVALID_STATE_CHANGE)
    request(seg, AlState.PREOP | R.AL_ERROR_FLAG)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(OUT_SM, 1, R.SM_CONTROL_OUTPUTS))  # wrong length
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    assert request(seg, AlState.SAFEOP) == (AlState.PREOP | R.AL_ERROR_FLAG, AlStatusCode.INVALID_OUTPUT_CONFIG)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(OUT_SM, 2, R.SM_CONTROL_OUTPUTS))
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 3, R.SM_CONTROL_INPUTS))
    assert request(seg, AlState.SAFEOP | R.AL_ERROR_FLAG) == (
        AlState.PREOP | R.AL_ERROR_FLAG, AlStatusCode.INVALID_INPUT_CONFIG)
    fpwr(seg, ST, R.sm_address(3), sm_bytes(IN_SM, 1, R.SM_CONTROL_INPUTS))
    assert request(seg, AlState.SAFEOP | R.AL_ERROR_FLAG) == (AlState.SAFEOP, 0)


def _to_safeop(seg: Segment) -> None:
    _to_preop(seg)
    fpwr(seg, ST, R.sm_address(2), sm_bytes(OUT_SM, 1, R.SM_CONTROL_OUTPUTS))
    fpwr(seg, ST, R.fmmu_address(0), fmmu_bytes(0, 1, 0, 7, OUT_SM, 0, int(R.FmmuType.WRITE)))
    assert request(seg, AlState.SAFEOP) == (AlState.SAFEOP, 0)


def test_safeop_to_op_waits_for_outputs_then_watchdog_falls_back() -> None:
    seg = mbx_segment(None, out_bits=8)
    _to_safeop(seg)
    assert request(seg, AlState.OP) == (AlState.SAFEOP, 0)  # pending: no outputs yet
    assert one(seg, Datagram.logical(Command.LWR, 0, b"\x01")).wkc == 1
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.OP
    clock = seg.clock
    assert isinstance(clock, VirtualClock)
    clock.advance(50_000_000)  # 50 ms < 100 ms default
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.OP
    one(seg, Datagram.logical(Command.LWR, 0, b"\x02"))
    clock.advance(150_000_000)
    status = u16(fprd(seg, ST, R.AL_STATUS, 2))
    assert status == AlState.SAFEOP | R.AL_ERROR_FLAG
    assert u16(fprd(seg, ST, R.AL_STATUS_CODE, 2)) == AlStatusCode.SM_WATCHDOG
    assert fprd(seg, ST, R.WATCHDOG_STATUS_PROCESS_DATA, 2).data[0] & 1 == 0
    assert fprd(seg, ST, R.WATCHDOG_COUNTER_PROCESS_DATA, 1).data == b"\x01"
    # acknowledge and go back to OP with fresh outputs
    assert request(seg, AlState.OP | R.AL_ERROR_FLAG) == (AlState.SAFEOP, 0)
    one(seg, Datagram.logical(Command.LWR, 0, b"\x03"))
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.OP


class _SteppedClock:
    """A clock that is not virtual (the segment does not move it per frame): it
    moves when told, also while a frame is being processed, as real time does."""

    def __init__(self) -> None:
        self.ns = 0

    def now_ns(self) -> int:
        return self.ns


class _SlowOutputs(DeviceApp):
    """Spends ``cost_ns`` of the clock on each completed output buffer (a slow simulator)."""

    wants_output_events = True

    def __init__(self, clock: _SteppedClock) -> None:
        super().__init__()
        self.clock = clock
        self.cost_ns = 0

    def on_outputs(self) -> None:
        self.clock.ns += self.cost_ns


def test_time_spent_processing_a_frame_does_not_run_out_watchdogs() -> None:
    """A real ESC answers within the frame's passage: a frame that kept the
    simulator busy for 150 ms on real time is no silence of the master, so the
    100 ms watchdog of outputs it delivered keeps running from the frame's time;
    silence on the wire still runs it out."""
    clock = _SteppedClock()
    app = _SlowOutputs(clock)
    seg = mbx_segment(app, out_bits=8)
    seg.clock = clock
    _to_safeop(seg)
    assert request(seg, AlState.OP) == (AlState.SAFEOP, 0)
    one(seg, Datagram.logical(Command.LWR, 0, b"\x01"))
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.OP
    app.cost_ns = 150_000_000
    one(seg, Datagram.logical(Command.LWR, 0, b"\x02"))  # returns 150 ms later
    app.cost_ns = 0
    clock.ns += 1_000_000
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.OP
    clock.ns += 150_000_000  # the master silent for 150 ms
    assert u16(fprd(seg, ST, R.AL_STATUS, 2)) == AlState.SAFEOP | R.AL_ERROR_FLAG
    assert u16(fprd(seg, ST, R.AL_STATUS_CODE, 2)) == AlStatusCode.SM_WATCHDOG


def test_app_check_and_state_callbacks() -> None:
    app = Recorder()
    seg = mbx_segment(app)
    setup_mailbox(seg)
    app.extra_code = AlStatusCode.NO_MEMORY
    assert request(seg, AlState.PREOP) == (AlState.INIT | R.AL_ERROR_FLAG, AlStatusCode.NO_MEMORY)
    app.extra_code = 0
    assert request(seg, AlState.PREOP | R.AL_ERROR_FLAG) == (AlState.PREOP, 0)
    assert (AlState.INIT, AlState.PREOP) in app.states
    app.pdi.set_al_error(AlStatusCode.SYNCHRONIZATION_ERROR, AlState.INIT)
    assert request(seg, AlState.PREOP)[0] == AlState.INIT | R.AL_ERROR_FLAG


def test_mailbox_sm_change_while_running_drops_to_init() -> None:
    seg = mbx_segment(None)
    _to_preop(seg)
    fpwr(seg, ST, R.sm_address(0), sm_bytes(MBX_OUT, 64, R.SM_CONTROL_MAILBOX_OUT))
    status = u16(fprd(seg, ST, R.AL_STATUS, 2))
    assert status == AlState.INIT | R.AL_ERROR_FLAG
    assert u16(fprd(seg, ST, R.AL_STATUS_CODE, 2)) == AlStatusCode.INVALID_MAILBOX_CONFIG


def test_device_emulation_follows_al_control() -> None:
    seg = Segment()
    seg.add_slave(spec("coupler", esc_config=int(R.EscConfig.DEVICE_EMULATION)))
    address_all(seg)
    assert request(seg, AlState.PREOP) == (AlState.PREOP, 0)
    assert request(seg, AlState.OP) == (AlState.OP, 0)


def test_id_request_loads_alias() -> None:
    seg = mbx_segment(None, alias_sii=0x0777)
    setup_mailbox(seg)
    status, code = request(seg, AlState.PREOP | R.AL_ID_FLAG)
    assert status == AlState.PREOP | R.AL_ID_FLAG and code == 0x0777
