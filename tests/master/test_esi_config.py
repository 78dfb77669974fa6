"""Master configuration from ESI files and ENI files, against ESI-made simulated slaves."""

from __future__ import annotations

from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import ConfigError, TopologyMismatchError
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.eni import build_eni, parse_eni
from pyethercat.link.pair import PairLink
from pyethercat.master.esi_config import (
    apply_esi_config,
    eni_from_master,
    esi_specs,
    expected_from_topology,
    start_from_eni,
)
from pyethercat.master.master import Master
from pyethercat.wire.al import AlState


def _topology(tmp_path: Path, corpus_dir: Path) -> Path:
    path = tmp_path / "net.toml"
    path.write_text(
        f'[[slave]]\nname = "drive"\nesi = "{bundled_esi()}"\n\n'
        f'[[slave]]\nname = "foot"\nesi = "{corpus_dir / "esi" / "kickcat_wdc_foot.xml"}"\n\n'
        f'[[slave]]\nname = "el1004"\nesi = "{corpus_dir / "esi" / "beckhoff_EL1xxx.xml"}"\n'
        "product = 0x03EC3052\nrevision = 0x00130000\n"
    )
    return path


def _master(path: Path) -> Master:
    from pyethercat.sim.topology import load_topology  # tests join master and simulator

    seg = load_topology(path).build()
    return Master(PairLink.responder_link(seg.process), clock=VirtualClock())


def test_expected_network_mismatch_names_position_expected_found(
    tmp_path: Path, corpus_dir: Path
) -> None:
    path = _topology(tmp_path, corpus_dir)
    specs = expected_from_topology(path)
    assert [s.identity.product_code for s in specs] == [0x264860D2, 0x00B0CAD0, 0x03EC3052]
    m = _master(path)
    m.scan()
    apply_esi_config(m, specs)  # matches
    swapped = [specs[1], specs[0], specs[2]]
    with pytest.raises(TopologyMismatchError, match=r"position 0: expected .*0x00B0CAD0.*found"):
        apply_esi_config(m, swapped)
    with pytest.raises(TopologyMismatchError, match="position 2: expected no slave"):
        apply_esi_config(m, specs[:2])


def test_builtin_entries_cannot_be_expected(tmp_path: Path) -> None:
    p = tmp_path / "t.toml"
    p.write_text('[[slave]]\nname = "a"\ndevice = "builtin:di8"\n')
    with pytest.raises(ConfigError, match="only esi = ... and sii = ..."):
        expected_from_topology(p)


def test_pdo_choice_init_cmds_and_dc_mode_from_esi(tmp_path: Path, corpus_dir: Path) -> None:
    path = _topology(tmp_path, corpus_dir)
    m = _master(path)
    m.scan()
    specs = expected_from_topology(path)
    specs[0].assignment = {3: (0x1A00, 0x1A01)}  # a selectable TxPDO chosen
    specs[0].op_mode = "DC"
    apply_esi_config(m, specs)
    cfg = m.configure()
    sm3 = next(s for s in cfg.slaves[0].sync_managers if s.index == 3)
    assert (sm3.length, [p.index for p in sm3.pdos]) == (11, [0x1A00, 0x1A01])
    drive = m.slaves[0]
    assert drive.dc_op_mode.assign_activate == 0x300  # type: ignore[attr-defined]
    cmds = [(c.transition, c.index, c.subindex, c.data) for c in m.startup_commands
            if c.position == 0]  # fmt: skip
    assert ("PS", 0x6060, 0, b"\x03") in cmds
    assert ("PS", 0x1C13, 0, b"\x02") in cmds
    m.pd.bring_up(m.slaves, 2.0)  # to SAFE-OP: the PS commands ran, no outputs yet
    assert drive.sdo_read(0x6060, 0) == b"\x03"  # type: ignore[attr-defined]
    assert drive.sdo_read(0x1C13, 0) == b"\x02"  # type: ignore[attr-defined]
    with m.start(cycle=0.002):  # (its orderly stop takes them back to PREOP)
        assert all(s.al_state == AlState.OP for s in m.slaves)
    assert "Velocity_Actual_Value" in dict(drive.inputs.items())  # type: ignore[attr-defined]


def test_eni_round_trip_and_start_without_sii(tmp_path: Path, corpus_dir: Path) -> None:
    path = _topology(tmp_path, corpus_dir)
    m = _master(path)
    m.scan()
    specs = expected_from_topology(path)
    specs[0].assignment = {3: (0x1A00, 0x1A01)}
    apply_esi_config(m, specs)
    m.configure()
    eni = eni_from_master(m, cycle_time_us=2000)
    xml = build_eni(eni)
    assert parse_eni(xml) == eni

    # A fresh segment, configured from the ENI alone.
    m2 = _master(path)
    start_from_eni(m2, parse_eni(xml))
    assert all(s.sii_image and len(s.sii_image) >= 128 for s in m2.slaves)
    m2.configure()
    again = eni_from_master(m2, cycle_time_us=2000)
    assert again == eni
    m2.pd.bring_up(m2.slaves, 2.0)
    assert m2.slaves[0].sdo_read(0x6060, 0) == b"\x03"  # type: ignore[attr-defined]
    with m2.start(cycle=0.002):  # (its orderly stop takes them back to PREOP)
        assert all(s.al_state == AlState.OP for s in m2.slaves)


def test_eni_import_checks_identity(tmp_path: Path, corpus_dir: Path) -> None:
    path = _topology(tmp_path, corpus_dir)
    m = _master(path)
    m.scan()
    m.configure()
    eni = eni_from_master(m)
    import dataclasses

    wrong = dataclasses.replace(eni.slaves[1], product_code=0x1234)
    bad = dataclasses.replace(eni, slaves=(eni.slaves[0], wrong, eni.slaves[2]))
    with pytest.raises(TopologyMismatchError, match="position 1: expected .*0x00001234"):
        start_from_eni(_master(path), bad)
    short = dataclasses.replace(eni, slaves=eni.slaves[:2])
    with pytest.raises(TopologyMismatchError, match="describes 2 slaves, the segment has 3"):
        start_from_eni(_master(path), short)


def test_esi_specs_from_files(corpus_dir: Path) -> None:
    specs = esi_specs([(bundled_esi(), None, None),
                       (corpus_dir / "esi" / "beckhoff_EL1xxx.xml", 0x03EC3052, None)])  # fmt: skip
    assert specs[1].identity.revision == 0x00130000 and specs[1].device is not None


def test_scan_does_not_wait_out_the_ack_echo_of_device_emulation_slaves(
    tmp_path: Path, corpus_dir: Path
) -> None:
    """An EL1004 (no firmware) reads back the reset's INIT+ack as 0x0011 until INIT is
    written alone; the scan writes it, so all slaves read plain INIT and the scan does
    not poll until its INIT timeout (it used to: 2 s, hundreds of frames)."""
    from pyethercat.sim.topology import load_topology
    from pyethercat.wire.registers import AL_STATUS

    seg = load_topology(_topology(tmp_path, corpus_dir)).build()
    frames = 0

    def counting(frame: bytes) -> bytes | None:
        nonlocal frames
        frames += 1
        return seg.process(frame)

    m = Master(PairLink.responder_link(counting), clock=VirtualClock())
    m.scan(read_sii=False)
    assert [m.read_u16(s.position, AL_STATUS) for s in m.slaves] == [int(AlState.INIT)] * 3
    assert frames < 40, frames


def test_expected_network_parses_a_shared_esi_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pyethercat.master.esi_config as esi_config

    calls: list[object] = []
    real = esi_config.load_esi

    def counting(path: object) -> object:
        calls.append(path)
        return real(path)  # type: ignore[arg-type]

    monkeypatch.setattr(esi_config, "load_esi", counting)
    path = tmp_path / "net.toml"
    path.write_text("".join(f'[[slave]]\nname = "d{i}"\nesi = "{bundled_esi()}"\n\n'
                            for i in range(5)))  # fmt: skip
    specs = expected_from_topology(path)
    assert [s.name for s in specs] == [f"d{i}" for i in range(5)]
    assert {s.identity.product_code for s in specs} == {0x264860D2}
    assert len(calls) == 1
    calls.clear()
    esi_specs([(bundled_esi(), None, None)] * 3)
    assert len(calls) == 1
