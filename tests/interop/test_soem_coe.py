"""SOEM (through pysoem) speaks CoE with the simulator over a veth pair.

``pyethercat sim`` serves builtin:coe-io and the seed 002 drive in a child
process; pysoem reads and writes SDOs (expedited, segmented, complete
access), reads the object dictionary and its descriptions, maps the process
data from 0x1C12/0x1C13 (SOEM does that for every slave with CoE), reaches
OP, and after a dynamic remap in PREOP sees the new process image. The
capture of the run must dissect in tshark with the CoE fields filled and
nothing malformed.
"""

from __future__ import annotations

import struct
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from pyethercat.sim.server import SimProcess, start_sim_process

pysoem = pytest.importorskip("pysoem")

#: SCHED_FIFO priority of the simulator process (the tests run as root).
SIM_PRIORITY = 10

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"

[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""


@pytest.fixture
def served(veth_pair: tuple[str, str], tmp_path: Path) -> Iterator[tuple[SimProcess, str, Path]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "coe.toml"
    topo.write_text(TOPOLOGY)
    pcap = tmp_path / "soem-coe.pcapng"
    # Real-time priority: SOEM gives an SM1 read up after 2 ms and an SM0 write
    # after 6 ms; a simulator the scheduler leaves waiting longer than that on a
    # loaded machine makes SOEM repeat, retry, or report errors.
    handle = start_sim_process(topo, link=f"iface:{sim_end}", pcap=pcap, realtime=SIM_PRIORITY)
    try:
        yield handle, master_end, pcap
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def cycle(master: Any, n: int = 1) -> int:
    wkc = 0
    for _ in range(n):
        master.send_processdata()
        wkc = master.receive_processdata(2000)
        time.sleep(0.001)
    return int(wkc)


def to_op(master: Any) -> None:
    master.config_dc()
    assert master.state_check(pysoem.SAFEOP_STATE, 50_000) == pysoem.SAFEOP_STATE, [
        hex(s.al_status) for s in master.slaves]
    cycle(master, 3)
    master.state = pysoem.OP_STATE
    master.write_state()
    for _ in range(300):
        cycle(master)
        if master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
            return
    raise AssertionError(f"no OP: {[hex(s.al_status) for s in master.slaves]}")


def back_to_preop(master: Any) -> None:
    master.state = pysoem.PREOP_STATE
    master.write_state()
    assert master.state_check(pysoem.PREOP_STATE, 50_000) == pysoem.PREOP_STATE


def u8(v: int) -> bytes:
    return bytes([v])


def u16(v: int) -> bytes:
    return struct.pack("<H", v)


def u32(v: int) -> bytes:
    return struct.pack("<I", v)


@pytest.mark.root
def test_soem_coe_against_the_simulator(served: tuple[SimProcess, str, Path], tshark: str) -> None:
    handle, iface, pcap = served
    master = pysoem.Master()
    master.always_release_gil = True
    master.open(iface)
    try:
        assert master.config_init() == 2
        io, drive = master.slaves
        assert (io.man, io.id) == (0x00504543, 0x00050001)
        assert (drive.man, drive.id, drive.rev) == (0xE4, 0x264860D2, 0x00020000)

        # --- expedited and normal SDO reads and writes
        assert io.sdo_read(0x1018, 1) == u32(0x00504543)
        assert io.sdo_read(0x1008, 0) == b"PEC-COEIO CoE test IO"
        io.sdo_write(0x8000, 1, u16(1234))
        assert io.sdo_read(0x8000, 1) == u16(1234)
        io.sdo_write(0x8000, 6, b"spindle")
        assert io.sdo_read(0x8000, 6) == b"spindle"
        assert drive.sdo_read(0x1100, 0) == u16(0x1002)  # SOEM gave it station 0x1002

        # --- segmented transfers of the 4 KiB octet string, both ways
        assert io.sdo_read(0x2000, 0, 4096) == bytes(i & 0xFF for i in range(4096))
        blob = bytes((i * 13 + 1) & 0xFF for i in range(4096))
        io.sdo_write(0x2000, 0, blob)
        assert io.sdo_read(0x2000, 0, 4096) == blob

        # --- complete access
        assert io.sdo_read(0x1018, 0, ca=True)[:6] == b"\x04\x00" + u32(0x00504543)
        io.sdo_write(0x8001, 0, struct.pack("<Bxhh", 2, -7, 7), ca=True)
        assert io.sdo_read(0x8001, 1) == struct.pack("<h", -7)
        assert io.sdo_read(0x8001, 2) == struct.pack("<h", 7)

        # --- aborts arrive as SOEM's SdoError with the code
        with pytest.raises(pysoem.SdoError) as err:
            io.sdo_read(0x5555, 0)
        assert err.value.abort_code == 0x06020000
        with pytest.raises(pysoem.SdoError) as err:
            io.sdo_write(0x1018, 1, u32(1))
        assert err.value.abort_code == 0x06010002
        with pytest.raises(pysoem.SdoError) as err:
            io.sdo_write(0x8000, 4, u8(7))
        assert err.value.abort_code == 0x06090030

        # --- object dictionary through the SDO information service
        od = {obj.index: obj for obj in io.od}
        assert {0x1000, 0x1018, 0x1600, 0x1A00, 0x1C12, 0x1C13, 0x2000, 0x6000, 0x7000,
                0x8000} <= set(od)
        assert od[0x1018].name == b"Identity"
        assert od[0x1018].object_code == 9
        assert od[0x2000].data_type == 0x000A and od[0x2000].object_code == 7
        assert od[0x2000].bit_length == 4096 * 8
        names = [e.name for e in od[0x7000].entries]
        assert names[1:] == [b"Digital outputs", b"Value 16", b"Value 32", b"Bit output"]
        assert [e.bit_length for e in od[0x7000].entries][1:] == [8, 16, 32, 1]
        assert od[0x7000].entries[2].obj_access & 0x0040  # RxPDO mappable
        assert [e.data_type for e in od[0x1018].entries][1:] == [7, 7, 7, 7]

        # --- the drive: the seed's objects, PDOs assigned by the master (subindex 0 = 0)
        assert drive.sdo_read(0x1C12, 0) == u8(0)
        drive.sdo_write(0x1C12, 0, u8(1))
        drive.sdo_write(0x1C13, 0, u8(1))

        # --- process data mapped from 0x1C12/0x1C13, OP, echo through the mapping
        assert master.config_map() == 7 + 7 + 3 + 3
        assert (len(io.output), len(io.input)) == (7, 7)
        assert (len(drive.output), len(drive.input)) == (3, 3)
        to_op(master)
        io.output = struct.pack("<BHI", 0x5A, 0xBEEF, 0x01020304)
        drive.output = struct.pack("<Hb", 0x0006, 3)
        for _ in range(50):
            cycle(master)
            sw, mode = struct.unpack("<Hb", drive.input)
            if io.input == io.output and sw & 0x6F == 0x21 and mode == 3:
                break
        assert io.input == struct.pack("<BHI", 0x5A, 0xBEEF, 0x01020304)
        # shutdown (0x06) in OP: Ready to switch on (CiA 402), the mode shown in 0x6061
        assert (sw & 0x6F, mode) == (0x21, 3)
        # mapping objects are PREOP-only
        with pytest.raises(pysoem.SdoError) as err:
            io.sdo_write(0x1C12, 0, u8(0))
        assert err.value.abort_code == 0x08000022

        # --- emergency: queued in SM1, SOEM files it while waiting for an SDO reply
        got: list[Any] = []
        io.add_emergency_callback(got.append)
        assert handle.control("emergency", slave="io", code=0x8210, register=0x10,
                              data="0102030405")["sent"]
        assert io.sdo_read(0x1000, 0) == u32(0x00000191)
        assert got and got[0].error_code == 0x8210 and got[0].error_reg == 0x10

        # --- dynamic remap in PREOP: outputs = value 32 only, inputs = value 32 + counter
        back_to_preop(master)
        io.sdo_write(0x1C12, 0, u8(0))
        io.sdo_write(0x1602, 0, u8(0))
        io.sdo_write(0x1602, 1, u32(0x70000320))
        io.sdo_write(0x1602, 0, u8(1))
        io.sdo_write(0x1C12, 1, u16(0x1602))
        io.sdo_write(0x1C12, 0, u8(1))
        io.sdo_write(0x1C13, 0, u8(0))
        io.sdo_write(0x1C13, 1, u16(0x1A01))
        io.sdo_write(0x1C13, 2, u16(0x1A02))
        io.sdo_write(0x1C13, 0, u8(2))
        # SOEM maps a group once: scan again (the slaves keep their mapping through
        # INIT, as real devices keep theirs until power-off), then map anew
        assert master.config_init() == 2
        io, drive = master.slaves
        assert io.sdo_read(0x1C12, 0, ca=True) == b"\x01\x00" + u16(0x1602)
        assert master.config_map() == 4 + 8 + 3 + 3
        assert (len(io.output), len(io.input)) == (4, 8)
        to_op(master)
        io.output = u32(0xCAFEF00D)
        for _ in range(50):
            cycle(master)
            if io.input[2:6] == u32(0xCAFEF00D):
                break
        assert io.input[2:6] == u32(0xCAFEF00D)
        first = struct.unpack_from("<H", io.input, 6)[0]
        cycle(master, 5)
        assert struct.unpack_from("<H", io.input, 6)[0] != first  # the counter runs

        back_to_preop(master)
        master.state = pysoem.INIT_STATE
        master.write_state()
    finally:
        master.close()
    handle.stop()

    # --- tshark dissects the CoE traffic of the capture, nothing malformed
    out = subprocess.run(
        [tshark, "-r", str(pcap), "-Y", "ecat_mailbox.coe", "-T", "fields", "-E", "occurrence=a",
         "-E", "aggregator=,", "-e", "ecat_mailbox.coe.sdoidx", "-e", "ecat_mailbox.coe.abortcode",
         "-e", "ecat_mailbox.coe.sdoinfoopcode"],
        capture_output=True, text=True, check=True, timeout=120)
    rows = [line.split("\t") for line in out.stdout.splitlines()]
    assert len(rows) > 100

    def values(col: int) -> set[int]:
        return {int(v, 0) for r in rows if len(r) > col for v in r[col].split(",") if v}

    assert {0x1018, 0x2000, 0x1C12, 0x1C13, 0x1602, 0x8001} <= values(0)
    assert {0x06020000, 0x06010002, 0x06090030, 0x08000022} <= values(1)
    assert {1, 2, 3, 4, 5, 6} <= values(2)  # SDO information requests and responses
    bad = subprocess.run(
        [tshark, "-r", str(pcap), "-Y", "_ws.malformed || _ws.expert.severity >= error"],
        capture_output=True, text=True, check=True, timeout=120)
    assert bad.stdout.strip() == ""
