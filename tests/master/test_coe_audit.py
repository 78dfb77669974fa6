"""Audit of the CoE client against the simulator: edge cases the other tests left open.

Zero-byte downloads (a normal transfer with complete size 0), start-up
command failures (named clearly, and the state request is not made).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import SdoAbort
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.wire import registers as R
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.mailbox.coe import SdoAbortCode, SdoDownloadClient

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"
[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""


@pytest.fixture
def m(tmp_path: Path) -> Master:
    from pyethercat.sim.topology import load_topology

    path = tmp_path / "coe.toml"
    path.write_text(TOPOLOGY)
    seg = load_topology(path).build()
    master = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    master.scan()
    master.set_state("PREOP")
    return master


def test_zero_byte_download_is_a_normal_transfer_of_size_zero() -> None:
    req = SdoDownloadClient(0x8000, 6, b"", mailbox_size=128).start()
    # CoE header (service 2), command 0x21 (initiate, size indicated, not expedited),
    # index, subindex, complete size 0, no data
    assert req.encode() == bytes.fromhex("0020" "21" "0080" "06" "00000000")


def test_zero_byte_download_empties_a_string(m: Master) -> None:
    io = m.slaves[0]
    io.sdo_write(0x8000, 6, b"")
    assert io.sdo_read(0x8000, 6) == b""
    assert io.sdo_read(0x8000, 6, "string") == ""
    with pytest.raises(SdoAbort) as err:  # a fixed-size entry refuses 0 bytes
        io.sdo_write(0x8000, 1, b"")
    assert err.value.code == SdoAbortCode.LENGTH_TOO_LOW


def _al_control(m: Master, station: int) -> int:
    reply = m.scheduler.transact_one(Datagram.device(Command.FPRD, station, R.AL_CONTROL, 2))
    return int.from_bytes(reply.data, "little") & 0x0F


def test_failing_ps_startup_command_names_slave_object_abort_and_stops(m: Master) -> None:
    io = m.slaves[0]
    # 0x8000:01 takes at most 10000: the slave aborts with 0x06090031
    m.add_startup_command(io, "PS", 0x8000, 1, 20000, dtype="uint16", comment="filter")
    with pytest.raises(SdoAbort) as err:
        m.set_state("SAFEOP", [io])
    text = str(err.value)
    assert "start-up command PS 0x8000:01 = 20 4e (filter)" in text
    assert io.describe() in text
    assert "0x06090031" in text and "too high" in text
    assert err.value.code == SdoAbortCode.VALUE_TOO_HIGH
    # the SAFE-OP request was never written: AL control still asks for PRE-OP
    assert _al_control(m, io.station_address) == int(AlState.PREOP)
    status = m.scheduler.transact_one(
        Datagram.device(Command.FPRD, io.station_address, R.AL_STATUS, 2))
    assert int.from_bytes(status.data, "little") & 0x0F == int(AlState.PREOP)


def test_startup_command_timeout_names_the_command(m: Master,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    drive = m.slaves[1]
    m.add_startup_command(drive, "PS", 0x6060, 0, 3, dtype="int8", comment="mode")
    assert drive.coe is not None

    def silent(*_a: object, **_k: object) -> None:
        raise EcTimeoutError(f"{drive.describe()}: no reply to SDO download 0x6060:00 within 2 s")

    monkeypatch.setattr(drive.coe, "download", silent)
    with pytest.raises(EcTimeoutError) as err:
        m.set_state("SAFEOP", [drive])
    assert str(err.value).startswith("start-up command PS 0x6060:00 = 03 (mode): ")
    assert drive.describe() in str(err.value)
    assert _al_control(m, drive.station_address) == int(AlState.PREOP)


# --- mailbox counters and error replies --------------------------------------------------


def test_sim_engine_counters_zero_wrap_and_duplicates() -> None:
    from pyethercat.sim.mailbox import MailboxEngine
    from pyethercat.wire.mailbox.header import MailboxHeader, MailboxType, encode_mailbox

    eng = MailboxEngine(None)
    got: list[int] = []
    eng.register(MailboxType.COE, lambda h, p: got.append(h.counter))
    for cnt in (0, 0, 6, 7, 1, 1, 2, 0, 0):
        eng.receive(encode_mailbox(MailboxType.COE, b"\x00\x20", counter=cnt, size=32))
    # 0 means "counter not used": never a repetition; 7 -> 1 is a new request;
    # only a repeated non-zero counter is dropped
    assert got == [0, 0, 6, 7, 1, 2, 0, 0]
    assert eng.duplicates == 1
    for _ in range(9):  # the slave's own counter runs 1..7 and wraps to 1
        eng.send(MailboxType.COE, b"x")
    assert [MailboxHeader.decode(r).counter for r in eng.queue] == [1, 2, 3, 4, 5, 6, 7, 1, 2]


@pytest.mark.parametrize("code,name", [
    (0x0001, "syntax"), (0x0002, "protocol not supported"), (0x0003, "channel"),
    (0x0004, "service"), (0x0005, "invalid mailbox protocol header"),
    (0x0006, "too short"), (0x0007, "memory"), (0x0008, "length inconsistent"),
])
def test_every_mailbox_error_code_is_typed_and_named(code: int, name: str) -> None:
    from pyethercat.errors import MailboxErrorReply
    from pyethercat.wire.mailbox.header import decode_mailbox_error, encode_mailbox_error

    reply = decode_mailbox_error(encode_mailbox_error(code))
    assert isinstance(reply, MailboxErrorReply)
    assert reply.code == code and name in reply.name
    assert f"0x{code:04X}" in str(reply)


def test_emergency_event_text_names_code_class_and_register_bits() -> None:
    from pyethercat.master.coe import EmergencyEvent
    from pyethercat.wire.mailbox.coe import Emergency

    ev = EmergencyEvent("slave 1", 1, Emergency(0x8130, 0x11, b"\x01\x02\x03\x04\x05"), 0.0)
    assert str(ev) == ("slave 1: emergency 0x8130 (life guard or heartbeat error), error "
                       "register 0x11 (generic, communication), data 01 02 03 04 05")
    assert ev.register_names == ("generic", "communication")
    clear = EmergencyEvent("slave 1", 1, Emergency(0x0000, 0x00), 0.0)
    assert "error register 0x00, " in str(clear)


def test_seed002_entry_names_follow_the_seed_tables(m: Master) -> None:
    drive = m.slaves[1]
    assert drive.coe is not None
    name = lambda i, s: drive.coe.entry_description(i, s, value_info=0).description  # noqa: E731
    assert name(0x1C00, 0) == "Number of used Sync Manager Channels"
    assert [name(0x1C00, s) for s in range(1, 5)] == [
        f"Communication Type Sync Channel {n}" for n in range(4)]
    assert name(0x1C10, 0) == name(0x1C12, 0) == "Number of assigned PDOs"
    assert name(0x1C12, 1) == "PDO Mapping object Number of assigned RxPDO"
    assert name(0x1C13, 4) == "PDO Mapping object number of assigned TxPDO"
