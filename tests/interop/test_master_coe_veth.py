"""Our master speaks CoE with ``pyethercat sim`` over a veth pair: the pysoem scenarios.

The same simulated segment as tests/interop/test_soem_coe.py (builtin:coe-io
and the seed 002 drive in a child process, wall clock, raw sockets): SDOs
expedited and segmented both ways, complete access, aborts, the object
dictionary through SDO information, OP with the process image laid out from
0x1C12/0x1C13, emergencies, and a dynamic remap in PRE-OP that changes the
image. While cyclic exchange runs, the mailbox status comes from the cyclic
frame: the capture of our side holds no status poll (FPRD 0x080D) then.
"""

from __future__ import annotations

import io as iolib
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SIM_FRAME_TIMEOUT, wait_for

from pyethercat.errors import SdoAbort
from pyethercat.link.capture import CaptureLink
from pyethercat.link.raw import RawLink
from pyethercat.master.master import Master
from pyethercat.sim.server import SimProcess, start_sim_process
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.coe import SdoAbortCode
from pyethercat.wire.pcap import read_capture

TOPOLOGY = """
[[slave]]
name = "io"
device = "builtin:coe-io"

[[slave]]
name = "drive"
device = "builtin:seed002-drive"
"""

STATUS = reg.sm_address(1) + reg.SM_STATUS


@pytest.fixture
def served(veth_pair: tuple[str, str], tmp_path: Path) -> Iterator[tuple[SimProcess, str]]:
    sim_end, master_end = veth_pair
    topo = tmp_path / "coe.toml"
    topo.write_text(TOPOLOGY)
    handle = start_sim_process(topo, link=f"iface:{sim_end}")
    try:
        yield handle, master_end
    finally:
        code = handle.stop()
        assert code == 0, f"pyethercat sim exited with {code}: {handle.stderr()}"


def _status_polls(capture: iolib.BytesIO, start: int) -> int:
    """FPRD 0x080D datagrams in the capture (sent and returned) from time ``start`` on."""
    data = capture.getvalue()
    count = 0
    for rec in read_capture(iolib.BytesIO(data)):
        if rec.timestamp_ns < start:
            continue
        for d in decode_frame(rec.data).datagrams:
            if d.command == Command.FPRD and d.ado == STATUS:
                count += 1
    return count


@pytest.mark.root
def test_our_master_coe_against_the_simulator(served: tuple[SimProcess, str]) -> None:
    handle, iface = served
    capture = iolib.BytesIO()
    link = CaptureLink(RawLink(iface), capture, flush=True)
    with Master(link, timeout=SIM_FRAME_TIMEOUT) as m:
        slaves = m.scan()
        assert len(slaves) == 2
        io, drive = slaves
        assert (io.identity.vendor_id, io.identity.product_code) == (0x00504543, 0x00050001)
        assert (drive.identity.vendor_id, drive.identity.product_code,
                drive.identity.revision) == (0xE4, 0x264860D2, 0x00020000)
        m.set_state("PREOP")

        # --- expedited and normal SDO reads and writes
        assert io.sdo_read(0x1018, 1, "uint32") == 0x00504543
        assert io.sdo_read(0x1008, 0, "string") == "PEC-COEIO CoE test IO"
        io.sdo_write(0x8000, 1, 1234, "uint16")
        assert io.sdo_read(0x8000, 1, "uint16") == 1234
        io.sdo_write(0x8000, 6, "spindle", "string")
        assert io.sdo_read(0x8000, 6, "string") == "spindle"
        assert drive.sdo_read(0x1100, 0, "uint16") == drive.station_address

        # --- segmented transfers of the 4 KiB octet string, both ways
        assert io.sdo_read(0x2000) == bytes(i & 0xFF for i in range(4096))
        blob = bytes((i * 13 + 1) & 0xFF for i in range(4096))
        io.sdo_write(0x2000, 0, blob)
        assert io.sdo_read(0x2000) == blob

        # --- complete access
        assert io.sdo_read(0x1018, 0, complete_access=True)[:6] == b"\x04\x00" + struct.pack(
            "<I", 0x00504543)
        io.sdo_write(0x8001, 0, struct.pack("<Bxhh", 2, -7, 7), complete_access=True)
        assert io.sdo_read(0x8001, 1, "int16") == -7
        assert io.sdo_read(0x8001, 2, "int16") == 7

        # --- aborts
        for op, code in (
                (lambda: io.sdo_read(0x5555), SdoAbortCode.NO_OBJECT),
                (lambda: io.sdo_write(0x1018, 1, 1, "uint32"), SdoAbortCode.READ_ONLY),
                (lambda: io.sdo_write(0x8000, 4, 7, "uint8"), 0x06090030)):
            with pytest.raises(SdoAbort) as err:
                op()
            assert err.value.code == code

        # --- object dictionary through the SDO information service
        od = io.od
        assert {0x1000, 0x1018, 0x1600, 0x1A00, 0x1C12, 0x1C13, 0x2000, 0x6000, 0x7000,
                0x8000} <= set(od)
        assert od[0x1018].name == "Identity" and od[0x1018].object_code_name == "RECORD"
        assert od[0x2000].object_code_name == "VAR"
        assert od[0x2000][0].type_name == "OCTET_STRING"
        assert od[0x2000][0].bit_length == 4096 * 8
        assert [e.name for e in od[0x7000].entries][1:] == [
            "Digital outputs", "Value 16", "Value 32", "Bit output"]
        assert [e.bit_length for e in od[0x7000].entries][1:] == [8, 16, 32, 1]
        assert od[0x7000][2].pdo_mappable
        assert [e.type_name for e in od[0x1018].entries][1:] == ["UNSIGNED32"] * 4
        assert od[0x1018][1].read() == 0x00504543

        # --- the drive: PDOs assigned by the master (subindex 0 = 0 at power-on)
        assert drive.sdo_read(0x1C12, 0, "uint8") == 0
        drive.sdo_write(0x1C12, 0, 1, "uint8")
        drive.sdo_write(0x1C13, 0, 1, "uint8")

        # --- process data laid out from 0x1C12/0x1C13, OP, echo through the mapping
        cfg = m.configure()
        assert io.pdo_mapping is not None and drive.pdo_mapping is not None
        assert [(cfg.slaves[p].output_bytes, cfg.slaves[p].input_bytes) for p in (0, 1)] == [
            (7, 7), (3, 3)]
        assert cfg.groups[0].status_bytes == 2
        runner = m.start(cycle=0.002)
        try:
            assert all(s.al_state == AlState.OP for s in m.slaves)
            io.outputs["Digital outputs"] = 0x5A
            io.outputs["Value 16"] = 0xBEEF
            io.outputs["Value 32"] = 0x01020304
            drive.outputs[(0x6040, 0)] = 0x0006
            drive.outputs[(0x6060, 0)] = 3
            assert wait_for(lambda: io.inputs["Value 32"] == 0x01020304)
            assert (io.inputs["Digital inputs"], io.inputs["Value 16"]) == (0x5A, 0xBEEF)
            assert wait_for(lambda: drive.inputs[(0x6061, 0)] == 3)
            # shutdown (0x06) in OP: the drive goes to Ready to switch on (CiA 402)
            assert wait_for(lambda: drive.inputs[(0x6041, 0)] & 0x6F == 0x21)

            # SDOs while cyclic exchange runs: the status comes from the cyclic frame
            start = time.time_ns()
            assert io.sdo_read(0x1018, 2, "uint32") == 0x00050001
            assert io.sdo_read(0x2000) == blob
            # mapping objects are PRE-OP only
            with pytest.raises(SdoAbort) as err:
                io.sdo_write(0x1C12, 0, 0, "uint8")
            assert err.value.code == 0x08000022
            # an emergency: posted by the slave, its status bit shows in the image
            assert handle.control("emergency", slave="io", code=0x8210, register=0x10,
                                  data="0102030405")["sent"]
            assert wait_for(lambda: m.poll_mailboxes() > 0 or not m.emergencies.empty())
            event = m.emergencies.get(timeout=1)
            assert (event.position, event.error_code, event.error_register) == (0, 0x8210, 0x10)
            assert io.mbx is not None and io.mbx.stats.cyclic_status > 0
            assert runner.stats.wkc_errors == 0
            assert _status_polls(capture, start) == 0
        finally:
            runner.stop()

        # --- dynamic remap in PRE-OP: outputs = value 32 only, inputs = 0x1A01 + 0x1A02
        m.set_state("PREOP")
        io.set_pdo_mapping({0x1C12: [(0x1602, [(0x7000, 3, 32)])], 0x1C13: [0x1A01, 0x1A02]})
        assert io.sdo_read(0x1C12, 0, complete_access=True) == b"\x01\x00" + struct.pack(
            "<H", 0x1602)
        runner = m.start(cycle=0.002)
        try:
            sc = m.process_data.slaves[0]  # type: ignore[union-attr]
            assert (sc.output_bytes, sc.input_bytes) == (4, 8)
            assert list(io.outputs) == ["Value 32"]
            io.outputs["Value 32"] = 0xCAFEF00D
            assert wait_for(lambda: io.inputs["Value 32"] == 0xCAFEF00D)
            first = io.inputs["Cycle counter"]
            assert wait_for(lambda: io.inputs["Cycle counter"] != first)
        finally:
            runner.stop()
        m.set_state("INIT")
