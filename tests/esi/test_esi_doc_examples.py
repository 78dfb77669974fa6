"""docs/esi.md and docs/simulator.md say what the code does (examples, ESI defaults, serials)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import SdoAbort
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.sim.topology import load_topology

REPO = Path(__file__).resolve().parents[2]


def _master(tmp_path: Path, body: str) -> Master:
    topo = tmp_path / "t.toml"
    topo.write_text(body)
    m = Master(PairLink.responder_link(load_topology(topo).build().process), clock=VirtualClock())
    m.scan()
    return m


def test_esi_md_pdo_layout_example_runs(corpus_dir: Path) -> None:
    text = (REPO / "docs" / "esi.md").read_text()
    block = next(b.split("```", 1)[0] for b in text.split("```python\n")[1:] if "pdo_layout" in b)
    code = block.replace('"Beckhoff EL1xxx.xml"', repr(str(corpus_dir / "esi" / "beckhoff_EL1xxx.xml")))
    ns: dict[str, object] = {}
    exec(compile(code, "esi.md", "exec"), ns)  # noqa: S102
    dev_layout = ns["dev"].pdo_layout(assignment={0: (0x1A00, 0x1A01)})  # type: ignore[attr-defined]
    assert [p.index for p in dev_layout.sms[0].pdos] == [0x1A00, 0x1A01]
    assert ns["layout"] is not None


def test_topology_takes_a_builtin_esi(tmp_path: Path) -> None:
    m = _master(tmp_path, '[[slave]]\nname = "drive"\nesi = "builtin:seed002_drive.xml"\n')
    assert m.slaves[0].identity.product_code == 0x264860D2


def test_esi_default_string_fills_the_simulated_dictionary(tmp_path: Path,
                                                           corpus_dir: Path) -> None:
    esi = corpus_dir / "esi" / "soes_linux_lan9252demo.xml"
    m = _master(tmp_path, f'[[slave]]\nname = "soes"\nesi = "{esi}"\n')
    m.set_state("PREOP")
    s = m.slaves[0]
    # <DefaultString>evb9252_dig</DefaultString> (STRING(11)), and "1.0" on a STRING(0).
    assert s.sdo_read(0x1008, 0, "string") == "evb9252_dig"
    assert s.sdo_read(0x1009, 0, "string") == "1.0"


def test_nan_is_outside_every_value_range(tmp_path: Path) -> None:
    m = _master(tmp_path, '[[slave]]\nname = "io"\ndevice = "builtin:coe-io"\n')
    m.set_state("PREOP")
    io = m.slaves[0]
    with pytest.raises(SdoAbort) as exc:
        io.sdo_write(0x8000, 5, math.nan, "real32")  # Gain, 0.0..100.0
    assert exc.value.code == 0x06090030
    io.sdo_write(0x8000, 5, 50.0, "real32")
    assert io.sdo_read(0x8000, 5, "real32") == 50.0


def test_serial_defaults_to_the_file_order_not_the_ring_position(tmp_path: Path) -> None:
    m = _master(tmp_path, '[[slave]]\nname = "coupler"\ndevice = "builtin:coupler"\n'
                          '[[slave]]\nname = "a"\ndevice = "builtin:di8"\n'
                          '[[slave]]\nname = "b"\ndevice = "builtin:do8"\n'
                          'parent = "coupler"\nport = 3\n')
    # Ring order: coupler, b (port 3 comes first), a; serials follow the file: 1, 2, 3.
    assert [s.name.split()[0] for s in m.slaves] == ["PEC-CU4", "PEC-DO8", "PEC-DI8"]
    assert [s.identity.serial for s in m.slaves] == [1, 3, 2]
    assert struct.unpack_from("<I", m.sii_read(1), 0x1C)[0] == 3
