"""One ESC driven alone through the host protocol (sim.host.EscHost), without a segment."""

from __future__ import annotations

import struct

from simhelp import make_sii

from pyethercat.sim.esc import Esc
from pyethercat.sim.host import Dirty
from pyethercat.sim.memory import EscMemory
from pyethercat.sim.profiles import PROFILES
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState, AlStatusCode


class RecordingHost:
    """A host that only records what the ESC tells it."""

    sii_busy_ns = 0

    def __init__(self) -> None:
        self.calls: list[tuple[object, ...]] = []
        self.dirty = Dirty(0)
        self.t = 0

    def now_ns(self) -> int:
        return self.t

    def invalidate(self, what: Dirty) -> None:
        self.dirty |= what

    def ecat_event_raised(self, bits: int) -> None:
        self.calls.append(("event", bits))

    def al_state_changed(self, index: int, old: AlState, new: AlState) -> None:
        self.calls.append(("state", index, old, new))

    def has_outputs(self, index: int) -> bool:
        return False

    def wait_for_outputs(self, index: int, waiting: bool) -> None:
        self.calls.append(("wait", index, waiting))

    def output_buffer_completed(self, index: int) -> None:
        self.calls.append(("outputs", index))

    def reset_requested(self, index: int) -> None:
        self.calls.append(("reset", index))

    def loop_control_written(self, index: int, old: int, new: int) -> None:
        self.calls.append(("loop", index, old, new))

    def dc_written(self, index: int, lo: int, data: bytes) -> None:
        self.calls.append(("dc", index, lo, data))

    def dc_refresh(self, index: int) -> None:
        self.calls.append(("dc_refresh", index))


def _esc(host: RecordingHost, **sii: object) -> Esc:
    memory = EscMemory()
    memory.add()
    esc = Esc(host, memory, 0, "dev", make_sii(**sii), PROFILES["ET1100"], None)  # type: ignore[arg-type]
    esc.power_on()
    return esc


def test_an_esc_reports_to_its_host_and_needs_nothing_else() -> None:
    host = RecordingHost()
    esc = _esc(host, out_bits=8, in_bits=8)
    assert host.dirty & Dirty.ADDRESSING  # the alias from the SII was loaded
    host.dirty = Dirty(0)
    assert esc.ecat_write(R.STATION_ADDRESS, struct.pack("<H", 0x1001))
    assert host.dirty == Dirty.ADDRESSING
    assert esc.ecat_write(R.AL_CONTROL, struct.pack("<H", AlState.PREOP))
    assert ("state", 0, AlState.INIT, AlState.PREOP) in host.calls
    assert ("event", int(R.EcatEvent.AL_STATUS)) in host.calls
    # SAFEOP without process-data SMs fails with the code a real slave gives.
    assert esc.ecat_write(R.AL_CONTROL, struct.pack("<H", AlState.SAFEOP))
    assert esc.u16(R.AL_STATUS) == AlState.PREOP | R.AL_ERROR_FLAG
    assert esc.u16(R.AL_STATUS_CODE) == AlStatusCode.INVALID_OUTPUT_CONFIG
    assert esc.ecat_write(R.DL_CONTROL_LOOP, bytes([0x04]))
    assert ("loop", 0, 0, 0x04) in host.calls
    assert esc.ecat_write(R.DC_RECEIVE_TIME_PORT0, bytes(4))
    assert ("dc", 0, R.DC_RECEIVE_TIME_PORT0, bytes(4)) in host.calls
    for b in b"RES":
        esc.ecat_write(R.ESC_RESET_ECAT, bytes([b]))
    assert ("reset", 0) in host.calls


def test_safeop_to_op_waits_for_outputs_through_the_host() -> None:
    host = RecordingHost()
    esc = _esc(host, out_bits=8)
    sm2 = R.sm_address(2)
    esc.ecat_write(R.AL_CONTROL, struct.pack("<H", AlState.PREOP))
    esc.ecat_write(sm2, struct.pack("<HHBBBB", 0x1100, 1, R.SM_CONTROL_OUTPUTS, 0, 1, 0))
    esc.ecat_write(R.AL_CONTROL, struct.pack("<H", AlState.SAFEOP))
    assert esc.al_state() == AlState.SAFEOP
    esc.ecat_write(R.AL_CONTROL, struct.pack("<H", AlState.OP))
    assert esc.al_state() == AlState.SAFEOP and ("wait", 0, True) in host.calls
    assert esc.ecat_write(0x1100, b"\x01")
    assert ("outputs", 0) in host.calls  # the host publishes the buffer and completes OP
    esc.al.outputs_arrived()
    assert esc.al_state() == AlState.OP and ("wait", 0, False) in host.calls
