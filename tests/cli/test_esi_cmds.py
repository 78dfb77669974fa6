"""pyethercat esi show / esi sii / xml / eni export / eni import (click runner, simulated segment)."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from pyethercat.cli.main import cli
from pyethercat.esi import load_esi, parse_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.eni import load_eni
from pyethercat.esi.from_sii import esi_from_sii
from pyethercat.esi.sii_from_esi import esi_to_sii, sii_differences
from pyethercat.wire.sii import parse_sii


def _run(*args: str) -> str:
    res = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res.output


def _topology(tmp_path: Path, corpus_dir: Path) -> str:
    p = tmp_path / "t.toml"
    p.write_text(
        f'[[slave]]\nname = "drive"\nesi = "{bundled_esi()}"\n\n'
        f'[[slave]]\nname = "foot"\nesi = "{corpus_dir / "esi" / "kickcat_wdc_foot.xml"}"\n'
    )
    return str(p)


def test_esi_show_list_and_detail(corpus_dir: Path) -> None:
    out = _run("esi", "show", str(corpus_dir / "esi" / "beckhoff_EL1xxx.xml"))
    assert out.splitlines()[0].startswith("vendor 0x00000002") and "155 device(s)" in out
    assert "0x03EC3052 rev 0x00130000  EL1004" in out
    out = _run("esi", "show", "builtin:seed002_drive.xml", "--product", "0x264860d2")
    assert "RxPDO 0x1600 'Outputs' sm 2 24 bit [fixed default]" in out
    assert "InitCmd PS 0x6060:00 = 03  velocity mode" in out
    assert "CoE: PdoAssign SegmentedSdo DS402Channels=1" in out
    assert "DC op mode 'DC': AssignActivate 0x0300" in out


def test_esi_sii_writes_image_and_compares(tmp_path: Path, corpus_dir: Path) -> None:
    out_file = tmp_path / "e.bin"
    vendor = corpus_dir / "sii" / "soes_rtl_lwip_eoe_slave30.bin"
    out = _run("esi", "sii", str(corpus_dir / "esi" / "soes_rtl_lwip_eoe_slave30.xml"),
               "-o", str(out_file), "--compare", str(vendor))  # fmt: skip
    assert "256 bytes written" in out and "PDO categories left out" in out
    assert "3 difference(s)" in out and "general.physical_ports" in out
    info = parse_sii(out_file.read_bytes(), strict=True)
    assert (info.vendor_id, info.product_code) == (0x1337, 0x3030)


def test_esi_errors_are_one_line(tmp_path: Path) -> None:
    res = CliRunner().invoke(cli, ["esi", "sii", "builtin:seed002_drive.xml", "--product", "1",
                                   "-o", str(tmp_path / "x")])  # fmt: skip
    assert res.exit_code == 1 and "no device with product code 0x00000001" in res.output


def test_xml_of_a_live_slave_round_trips(tmp_path: Path, corpus_dir: Path) -> None:
    topo = _topology(tmp_path, corpus_dir)
    out = _run("--sim", topo, "xml", "-p", "1", "-o", str(tmp_path / "foot.xml"))
    assert "objects)" in out
    esi = load_esi(tmp_path / "foot.xml")
    dev = esi.devices[0]
    assert dev.dictionary is not None and dev.dictionary.object(0x1018) is not None
    # The generated ESI gives back the live slave's SII content.
    original = esi_to_sii(load_esi(corpus_dir / "esi" / "kickcat_wdc_foot.xml").devices[0],
                          vendor_id=0x6A5).info  # fmt: skip
    again = esi_to_sii(dev, vendor_id=esi.vendor.id, serial=original.serial).info
    assert [d.field for d in sii_differences(again, original)] == []


def test_esi_from_sii_of_every_corpus_pair_image(corpus_dir: Path) -> None:
    # Vendor images -> ESI -> SII: identity, mailbox, SMs, FMMUs and PDOs survive.
    for f in sorted((corpus_dir / "sii").glob("*.bin")):
        info = parse_sii(f.read_bytes())
        if info.general is None or info.warnings:
            continue
        esi = parse_esi(esi_from_sii(info), f.name)
        back = esi_to_sii(esi.devices[0], vendor_id=esi.vendor.id, serial=info.serial,
                          include_pdos=bool(info.tx_pdos or info.rx_pdos)).info  # fmt: skip
        content = [d.field for d in sii_differences(back, info)
                   if d.field == "general.ds402_channels" or d.field.split(".")[0].split("[")[0] in
                   ("vendor_id", "product_code", "revision", "rx_mailbox_size", "sm", "fmmu",
                    "txpdo", "rxpdo", "mailbox_protocols")
                   # PDO flags beyond Mandatory/Fixed (Default, Oversample...) have no
                   # ESI attribute of their own.
                   and not d.field.endswith("].flags")
                   # SM type 0 ("unused") for an SM in use (Orbita): we derive the type
                   # from the control byte, as the ESI has no SM type attribute.
                   and not (d.field.endswith(".sm_type") and d.b == 0)]  # fmt: skip
        assert content == [], (f.name, content)


def test_eni_export_then_import(tmp_path: Path, corpus_dir: Path) -> None:
    topo = _topology(tmp_path, corpus_dir)
    eni_file = tmp_path / "net.xml"
    out = _run("--sim", topo, "eni", "export", "-o", str(eni_file), "--expect", topo)
    assert "2 slaves" in out
    eni = load_eni(eni_file)
    assert [s.product_code for s in eni.slaves] == [0x264860D2, 0x00B0CAD0]
    out = _run("--sim", topo, "eni", "import", str(eni_file), "--op")
    assert out.count("identity ok") == 2 and "states: OP OP" in out


def test_run_from_eni(tmp_path: Path, corpus_dir: Path) -> None:
    topo = _topology(tmp_path, corpus_dir)
    eni_file = tmp_path / "net.xml"
    _run("--sim", topo, "eni", "export", "-o", str(eni_file), "--cycle", "2000", "--expect", topo)
    out = _run("--sim", topo, "run", "--eni", str(eni_file), "--seconds", "0.3")
    # The ENI's cycle time is the default; the live view shows both slaves in OP.
    assert "cycles:" in out and "at 2000 us" in out
    rows = [line for line in out.splitlines() if "Metronix ECAT" in line or "Foot" in line]
    assert len(rows) == 2 and all(" OP " in row for row in rows), out
    # A different segment than the ENI describes is refused before cyclic operation.
    other = tmp_path / "other.toml"
    other.write_text(f'[[slave]]\nname = "drive"\nesi = "{bundled_esi()}"\n')
    res = CliRunner().invoke(cli, ["--sim", str(other), "run", "--eni", str(eni_file),
                                   "--seconds", "0.1"])  # fmt: skip
    assert res.exit_code != 0
    assert "the ENI describes 2 slaves, the segment has 1" in res.output
