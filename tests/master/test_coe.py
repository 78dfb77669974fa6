"""Master CoE client: transfers of every kind and size, every abort path, SDO info, PDO mapping."""

from __future__ import annotations

import contextlib
import dataclasses
import struct

import pytest
from mini_coe import MiniCoe, coe_segment

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError, EtherCATError, MailboxError, SdoAbort
from pyethercat.errors import TimeoutError as EcTimeoutError
from pyethercat.master.coe import CoeClient, mapping_word, split_mapping_word
from pyethercat.master.config import PdoDirection
from pyethercat.master.master import Master
from pyethercat.master.slave import Slave
from pyethercat.wire.al import AlState, parse_transition
from pyethercat.wire.mailbox.coe import (
    SDO_ABORT_CODES,
    SdoAbortCode,
    SdoAbortTransfer,
    SdoInitiateUploadResponse,
    SdoUploadSegmentResponse,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.datatypes import DataType
from pyethercat.wire.mailbox.header import MailboxType, encode_mailbox, next_counter


def _master(count: int = 1, mailbox_size: int = 128) -> tuple[Master, list[MiniCoe]]:
    _seg, apps, _drop, link = coe_segment(count, mailbox_size=mailbox_size)
    m = Master(link, clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    return m, apps


@pytest.mark.parametrize("size", [1, 2, 3, 4, 5, 7, 8, 50, 112, 113, 118, 119, 500, 4096, 65536])
def test_download_then_upload_any_size(size: int) -> None:
    m, apps = _master()
    s = m.slaves[0]
    data = bytes((i * 7 + size) & 0xFF for i in range(size))
    s.sdo_write(0x2001, 0, data)
    assert apps[0].od[0x2001].entries[0][1] == data
    assert s.sdo_read(0x2001) == data


def test_upload_kinds_on_the_wire() -> None:
    m, apps = _master()
    s = m.slaves[0]
    s.sdo_read(0x1000)  # 4 bytes: expedited
    s.sdo_read(0x1008)  # 8 bytes: normal, fits the initiate frame
    s.sdo_read(0x2001)  # 4 KiB: segmented
    segs = [r for r in apps[0].requests if type(r).__name__ == "SdoUploadSegmentRequest"]
    # 4096 - 112 in the initiate, the rest in 119-byte segments
    assert len(segs) == -(-(4096 - 112) // 119)
    assert [sg.toggle for sg in segs[:4]] == [False, True, False, True]


@pytest.mark.parametrize("dtype,value", [
    ("uint32", 0xDEADBEEF), ("int32", -5), ("uint16", 513), ("uint8", 255), ("int8", -1),
    (DataType.REAL32, 2.5), ("float", -0.25), ("double", 1e300), ("bool", True),
    ("string", "hello world, longer than four"), ("uint64", 2**63 + 5), ("int24", -70000),
])
def test_typed_round_trip(dtype: object, value: object) -> None:
    m, _apps = _master()
    s = m.slaves[0]
    s.sdo_write(0x2000, 0, value, dtype)  # type: ignore[arg-type]
    assert s.sdo_read(0x2000, 0, dtype) == value  # type: ignore[arg-type]


def test_typed_errors() -> None:
    m, _apps = _master()
    s = m.slaves[0]
    with pytest.raises(ConfigError):
        s.sdo_write(0x2000, 0, 300, "uint8")
    with pytest.raises(ConfigError):
        s.sdo_write(0x2000, 0, 3)  # no dtype for an int
    with pytest.raises(ConfigError):
        s.sdo_read(0x2000, 0, "no-such-type")
    with pytest.raises(MailboxError):
        s.sdo_read(0x1018, 0, "uint32")  # one byte is not a u32
    assert s.sdo_read(0x2002, 0, "real32") == 1.5


def test_complete_access() -> None:
    m, apps = _master()
    s = m.slaves[0]
    raw = s.sdo_read(0x1018, 0, complete_access=True)
    assert raw == b"\x04\x00" + struct.pack("<IIII", 0x00504543, 0x00040002, 0x00010000, 42)
    s.sdo_write(0x1C13, 0, b"\x02\x00" + struct.pack("<HH", 0x1A00, 0x1A01),
                complete_access=True)
    assert apps[0].od[0x1C13].entries[2][1] == struct.pack("<H", 0x1A01)
    reqs = [r for r in apps[0].requests if getattr(r, "complete_access", False)]
    assert len(reqs) == 2


@pytest.mark.parametrize("code", sorted(SDO_ABORT_CODES))
def test_every_abort_code_from_the_slave(code: int) -> None:
    m, apps = _master()
    s = m.slaves[0]
    apps[0].aborts[(0x2000, 0)] = code
    for op in (lambda: s.sdo_read(0x2000), lambda: s.sdo_write(0x2000, 0, b"\x01\x02\x03\x04\x05")):
        with pytest.raises(SdoAbort) as err:
            op()
        assert err.value.code == code
        assert err.value.name == sdo_abort_name(code)
        assert (err.value.index, err.value.subindex) == (0x2000, 0)
        assert s.describe() in str(err.value)


def test_unknown_abort_code_still_named() -> None:
    m, apps = _master()
    apps[0].aborts[(0x2000, 0)] = 0x12345678
    with pytest.raises(SdoAbort) as err:
        m.slaves[0].sdo_read(0x2000)
    assert "unknown SDO abort code 0x12345678" in err.value.name


def _mangle_toggle(msg: object) -> object:
    if isinstance(msg, SdoUploadSegmentResponse):
        return dataclasses.replace(msg, toggle=not msg.toggle)
    return msg


def _mangle_index(msg: object) -> object:
    if isinstance(msg, SdoInitiateUploadResponse):
        return dataclasses.replace(msg, index=msg.index + 1)
    return msg


def _mangle_short(msg: object) -> object:
    if isinstance(msg, SdoUploadSegmentResponse) and msg.last:
        return dataclasses.replace(msg, data=msg.data[:-1])
    return msg


@pytest.mark.parametrize("mangle,code", [
    (_mangle_toggle, SdoAbortCode.TOGGLE_BIT),
    (_mangle_short, SdoAbortCode.LENGTH_MISMATCH),
])
def test_master_side_aborts_are_sent_and_raised(mangle: object, code: int) -> None:
    m, apps = _master()
    apps[0].mangle = mangle  # type: ignore[assignment]
    with pytest.raises(SdoAbort) as err:
        m.slaves[0].sdo_read(0x2001)
    assert err.value.code == code
    sent = [r for r in apps[0].requests if isinstance(r, SdoAbortTransfer)]
    assert sent and sent[-1].code == code


def test_an_answer_for_another_object_is_dropped_as_stale() -> None:
    # A response for another index (or another command) answers an earlier
    # request (a slow slave, another master's): dropped, so the transfer
    # times out and aborts, and the slave was asked once.
    m, apps = _master()
    m.slaves[0].sdo_read(0x2001)  # the mailbox counters are in sync
    apps[0].mangle = _mangle_index  # type: ignore[assignment]
    before = len(apps[0].requests)
    with pytest.raises(EcTimeoutError):
        m.slaves[0].sdo_read(0x2001)
    box = m.slaves[0].mbx
    assert box is not None and box.stats.stale == 1 and box.stats.resent == 0
    asked = apps[0].requests[before:]
    assert [type(r).__name__ for r in asked] == ["SdoInitiateUploadRequest",
                                                 "SdoAbortTransfer"]
    assert isinstance(asked[-1], SdoAbortTransfer)
    assert asked[-1].code == SdoAbortCode.TIMEOUT


def test_unexpected_download_answer_is_not_taken() -> None:
    m, apps = _master()

    def to_upload(msg: object) -> object:
        return SdoInitiateUploadResponse(0x2000, 0, b"\x01")
    apps[0].mangle = to_upload  # type: ignore[assignment]
    with pytest.raises(EcTimeoutError):
        m.slaves[0].sdo_write(0x2000, 0, b"\x01\x02")
    box = m.slaves[0].mbx
    assert box is not None and box.stats.stale >= 1


def test_timeout_mid_segmented_transfer() -> None:
    m, apps = _master()
    s = m.slaves[0]

    class Stop:
        n = 0

    # answer the initiate and two segments, then nothing
    orig = apps[0]._serve

    def serve(msg: object) -> list[object]:
        Stop.n += 1
        if Stop.n > 3:
            return []
        return orig(msg)  # type: ignore[arg-type]
    apps[0]._serve = serve  # type: ignore[method-assign]
    with pytest.raises(EcTimeoutError, match="0x2001:00"):
        s.sdo_read(0x2001, timeout=0.05)


def test_sdo_info_object_dictionary() -> None:
    m, apps = _master(mailbox_size=40)  # small mailbox: the OD list comes in fragments
    s = m.slaves[0]
    od = s.od
    assert list(od) == sorted(apps[0].od)
    assert 0x1018 in od and 0x3000 not in od
    ident = od[0x1018]
    assert ident.name == "Identity" and ident.object_code_name == "RECORD"
    assert ident.max_subindex == 4
    names = [e.name for e in ident.entries]
    assert names == ["Count", "Vendor ID", "Product code", "Revision", "Serial number"]
    assert ident[1].type_name == "UNSIGNED32" and ident[1].bit_length == 32
    assert ident[1].read() == 0x00504543
    assert ident[1].access_text == "r-r-r-"
    assert od[0x1008][0].read() == "mini-coe"
    with pytest.raises(KeyError):
        od[0x3000]
    with pytest.raises(KeyError):
        ident[9]
    assert len(od) == len(apps[0].od)


def test_sdo_info_error_is_an_abort() -> None:
    m, _apps = _master()
    client = m.slaves[0].coe
    assert client is not None
    with pytest.raises(SdoAbort) as err:
        client.entry_description(0x1018, 9)
    assert err.value.code == SdoAbortCode.NO_SUBINDEX


def test_read_pdo_mapping_lays_out_the_image() -> None:
    m, _apps = _master()
    cfg = m.configure()
    s = m.slaves[0]
    assert s.pdo_mapping is not None
    assert [p.index for p in s.pdo_mapping[3]] == [0x1A00]
    assert s.pdo_mapping[3][0].entries[0].index == 0x6000
    assert s.pdo_mapping[2][0].direction is PdoDirection.OUTPUTS
    sc = cfg.slaves[0]
    assert sc.output_bits == 16 and sc.input_bits == 16
    assert [v.index for v in sc.variables] == [0x7000, 0x6000]


def test_dynamic_pdo_mapping_takes_effect() -> None:
    m, apps = _master()
    m.configure()
    s = m.slaves[0]
    new = s.set_pdo_mapping({0x1C13: [(0x1A00, [(0x6000, 1, 16), (0x6010, 1, 16)]), 0x1A01]})
    assert [p.index for p in new[3]] == [0x1A00, 0x1A01]
    od = apps[0].od
    assert od[0x1A00].entries[0][1] == b"\x02"
    assert od[0x1A00].entries[2][1] == struct.pack("<I", 0x60100110)
    assert od[0x1C13].entries[0][1] == b"\x02"
    assert m.process_data is None  # invalidated: the next start configures anew
    cfg = m.configure()
    assert cfg.slaves[0].input_bits == 48
    # kept as PS start-up commands and done again on the way to SAFE-OP
    assert any(c.comment == "PDO mapping" and c.transition == "PS" for c in m.startup_commands)
    apps[0].downloads.clear()
    m.set_state("INIT")
    m.set_state("PREOP")
    assert not apps[0].downloads
    m.slaves[0].al_state = AlState.PREOP
    with pytest.raises(ConfigError):
        s.set_pdo_mapping({5: [0x1A00]})


def test_set_pdo_mapping_needs_preop() -> None:
    m, _apps = _master()
    m.set_state("INIT")
    with pytest.raises(ConfigError, match="PRE-OP"):
        m.slaves[0].set_pdo_mapping({3: [0x1A00]})


def test_startup_commands_run_at_their_transitions() -> None:
    m, apps = _master()
    m.set_state("INIT")
    m.add_startup_command(0, "IP", 0x2000, 0, 7, dtype="uint32", comment="ip")
    m.add_startup_command(0, "P->S", 0x2002, 0, 3.0, dtype="real32")
    m.add_startup_command(0, "SAFEOP_PREOP", 0x2000, 0, b"\x09\x00\x00\x00")
    apps[0].downloads.clear()
    m.set_state("PREOP")
    assert apps[0].downloads == [(0x2000, 0, b"\x07\x00\x00\x00")]
    # SAFE-OP is refused by the ESC model without process-data SMs; the PS command runs first
    with contextlib.suppress(EtherCATError):
        m.set_state("SAFEOP")
    assert (0x2002, 0, struct.pack("<f", 3.0)) in apps[0].downloads
    with pytest.raises(ConfigError):
        m.add_startup_command(0, "XY", 0x2000, 0, b"\x00")
    with pytest.raises(ConfigError):
        m.add_startup_command(0, "IP", 0x2000, 0, 5)
    assert m.remove_startup_commands(0) == 3


def test_startup_command_abort_names_the_command() -> None:
    m, apps = _master()
    m.set_state("INIT")
    m.add_startup_command(0, "IP", 0x2000, 0, b"\x01", comment="gain")
    apps[0].aborts[(0x2000, 0)] = SdoAbortCode.VALUE_TOO_HIGH
    with pytest.raises(SdoAbort, match="start-up command IP 0x2000:00 = 01 \\(gain\\)"):
        m.set_state("PREOP")


def test_helpers() -> None:
    assert mapping_word(0x6010, 7, 16) == 0x60100710
    assert split_mapping_word(0x60100710) == (0x6010, 7, 16)
    assert parse_transition("ps") == "PS" and parse_transition("OP_SAFEOP") == "OS"
    with pytest.raises(ConfigError):
        mapping_word(0x10000, 0, 8)


def test_no_mailbox_no_coe() -> None:
    m, _apps = _master()
    s = m.slaves[0]
    m.mailboxes.attach([])  # as for a slave without mailbox
    assert s.coe is None and s.mbx is None
    with pytest.raises(ConfigError, match="no mailbox"):
        s.sdo_read(0x1000)
    with pytest.raises(ConfigError, match="no mailbox: no CoeClient"):
        s.client(CoeClient)
    with pytest.raises(ConfigError, match="was not scanned by a master"):
        Slave(0, 0x1001).set_pdo_mapping({2: [0x1600]})


class _ShortErrorLength(MiniCoe):
    """Posts SDO information errors as KickCAT's ESC emulator does: the mailbox length word
    says 6 (CoE and SDO information headers) and the abort code follows outside it."""

    def _post(self, payload: bytes, mtype: int) -> None:
        if mtype == MailboxType.COE and len(payload) == 10 and payload[2] & 0x7F == 7:
            self._counter = next_counter(self._counter)
            raw = bytearray(encode_mailbox(mtype, payload, counter=self._counter))
            raw[0:2] = (6).to_bytes(2, "little")
            self._out.append(bytes(raw))
            self._flush()
            return
        super()._post(payload, mtype)


def test_sdo_info_error_whose_length_leaves_the_abort_code_out() -> None:
    _seg, _apps, _drop, link = coe_segment(apps=[_ShortErrorLength()])
    m = Master(link, clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    client = m.slaves[0].client(CoeClient)
    with pytest.raises(SdoAbort) as err:
        client.entry_description(0x1018, 0x13)
    assert err.value.code == SdoAbortCode.NO_SUBINDEX
    # The next request is answered normally (nothing was left in the mailbox).
    assert client.entry_description(0x1018, 1).description
