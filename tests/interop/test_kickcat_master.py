"""KickCAT's master (the ``kickcat`` package on PyPI) runs our simulated segment (veth, root).

``pyethercat sim`` serves a coupler, builtin:coe-io, an EL2004 built from the
corpus EEPROM dump and a di8 on one end of a ``pyecat-`` veth pair; the
EL2004's four outputs are wired to the di8's first four inputs. KickCAT
(``kickcat.create_link`` + ``kickcat.Bus``) scans it, maps the process data,
brings every slave to OP, exchanges process data (what it writes reaches the
slaves' output sync managers, the di8's inputs come back through the wire)
and reads 0x1018:01 of the CoE slave with an SDO upload.

KickCAT requests every state with the acknowledge bit set (``Bus::requestState``
in ``lib/master/src/Bus.cc``); the EL2004's ESC runs in device emulation
(SII word 0), which copies AL control into AL status as the ET1100 datasheet
describes, so that slave reports OP with bit 4 set, as the real terminal does.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from pyethercat.sim.server import start_sim_process
from pyethercat.wire.al import AlState
from pyethercat.wire.registers import AL_STATE_MASK

kickcat = pytest.importorskip("kickcat")

pytestmark = pytest.mark.root

VENDOR = 0x00504543  # builtin:coe-io


def topology(corpus: Path) -> str:
    return f"""
[[slave]]
name = "coupler"
device = "builtin:coupler"

[[slave]]
name = "io"
device = "builtin:coe-io"

[[slave]]
name = "el2004"
sii = "{corpus / 'sii' / 'ethercrab_el2004.bin'}"

[[slave]]
name = "di8"
device = "builtin:di8"

[[wire]]
from = "el2004:0"
to = "di8:0"
bits = 4
"""


def test_kickcat_brings_the_segment_to_op_and_exchanges_data(
        veth_pair: tuple[str, str], tmp_path: Path, corpus_dir: Path) -> None:
    master_end, sim_end = veth_pair
    topo = tmp_path / "kickcat.toml"
    topo.write_text(topology(corpus_dir))
    with start_sim_process(topo, link=f"iface:{sim_end}", realtime=10) as sim:
        link = kickcat.create_link(master_end, "")
        # KickCAT gives a frame 2 ms (Link.h); a loaded CI host can hold the simulator's
        # reply longer than that.
        link.set_timeout(0.02)
        bus = kickcat.Bus(link)
        bus.init(0.1)
        coupler, io, el2004, di8 = bus.slaves()
        bus.create_mapping()
        # sizes in bytes from the slaves' PDO descriptions (SII, CoE for the io)
        assert [(s.input_size, s.output_size) for s in (coupler, el2004, di8)] == [
            (0, 0), (0, 1), (1, 0)]
        assert io.input_size > 0 and io.output_size > 0
        bus.request_state(kickcat.State.SAFE_OP)
        bus.wait_for_state(kickcat.State.SAFE_OP, 1.0)
        io_out = bytes(range(0x41, 0x41 + io.output_size))
        io.set_output_bytes(io_out)
        el2004.set_output_bytes(b"\x0a")
        bus.process_data()
        bus.request_state(kickcat.State.OPERATIONAL)
        bus.wait_for_state(kickcat.State.OPERATIONAL, 1.0, bus.process_data)
        states = [s["al_status"] for s in sim.control("slaves")["slaves"]]
        assert [st & AL_STATE_MASK for st in states] == [AlState.OP] * 4, states

        # process data both ways: outputs reach the slaves, the wire brings them back
        for pattern in (0x0A, 0x05, 0x0F, 0x00):
            el2004.set_output_bytes(bytes([pattern]))
            got = None
            end = time.monotonic() + 5
            while time.monotonic() < end:
                bus.process_data()
                got = di8.input_data[0] & 0x0F
                if got == pattern:
                    break
                time.sleep(0.002)
            assert got == pattern, f"0x{pattern:X} did not come back: 0x{got:X}"
            assert sim.control("outputs", slave="el2004")["data"] == f"{pattern:02x}"
        assert bytes.fromhex(sim.control("outputs", slave="io")["data"]) == io_out
        sim.control("set_inputs", slave="di8", data="f0")
        end = time.monotonic() + 5
        while time.monotonic() < end and di8.input_data[0] & 0xF0 != 0xF0:
            bus.process_data()
            time.sleep(0.002)
        assert di8.input_data[0] & 0xF0 == 0xF0

        # CoE: an SDO upload of the identity's vendor id
        raw = bus.read_sdo(io, 0x1018, 1, kickcat.Access.PARTIAL, 4, 1.0)
        assert int.from_bytes(raw[:4], "little") == VENDOR
        stats = sim.control("stats")
    assert stats["errors"] == 0
