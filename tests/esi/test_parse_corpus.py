"""Every ESI file of the shared corpus parses, and agrees with xmllint.

The expected values (device count, identities, PDO and entry counts, vendor
id) are read with ``xmllint --shell`` XPath queries, not with the parser under
test, and the number spellings are decoded here by a separate small function.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from pyethercat.esi import EsiFile, load_esi

DEVICES = "/EtherCATInfo/Descriptions/Devices/Device"


def _corpus_files() -> list[str]:
    here = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "esi"
    return sorted(p.name for p in here.glob("*.xml")) or ["<no corpus>"]


@pytest.fixture(scope="module")
def xmllint() -> str:
    path = shutil.which("xmllint")
    if path is None:
        # Same policy as the conftest fixtures: skip on a dev machine, fail in CI.
        reason = "xmllint is not installed (make test installs libxml2-utils as root)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(f"required under CI=true: {reason}")
        pytest.skip(reason)
    assert path is not None
    return path


def _xpath_many(xmllint: str, path: Path, queries: list[str]) -> list[str]:
    """Run XPath queries in one xmllint process; one result string per query."""
    script = "".join(f"xpath {q}\n" for q in queries)
    out = subprocess.run(
        [xmllint, "--shell", "--nonet", str(path)],
        input=script.encode(),
        capture_output=True,
        check=True,
        timeout=120,
    ).stdout.decode("utf-8", "replace")
    results = re.findall(r"Object is an? (?:number|string) : ?(.*)", out)
    assert len(results) == len(queries), out[-2000:]
    return [r.strip() for r in results]


def _num(text: str) -> int:
    """Decode ESI number spellings independently of the parser under test."""
    t = text.strip().lower()
    for prefix in ("#x0x", "#x", "0x"):
        if t.startswith(prefix):
            return int(t[len(prefix) :], 16)
    return int(t)


@pytest.mark.parametrize("name", _corpus_files())
def test_corpus_file_matches_xmllint(corpus_dir: Path, xmllint: str, name: str) -> None:
    path = corpus_dir / "esi" / name
    esi: EsiFile = load_esi(path)

    (count,) = _xpath_many(xmllint, path, [f"count({DEVICES})"])
    n = int(float(count))
    queries = ["string(/EtherCATInfo/Vendor/Id)"]
    for i in range(1, n + 1):
        d = f"{DEVICES}[{i}]"
        queries += [
            f"string({d}/Type/@ProductCode)",
            f"string({d}/Type/@RevisionNo)",
            f"count({d}/RxPdo)",
            f"count({d}/TxPdo)",
            f"count({d}/RxPdo/Entry)",
            f"count({d}/TxPdo/Entry)",
            f"count({d}/Sm)",
            f"sum({d}/RxPdo/Entry/BitLen) + sum({d}/TxPdo/Entry/BitLen)",
        ]
    res = _xpath_many(xmllint, path, queries)

    print(f"{name}: {n} devices")
    assert len(esi.devices) == n
    assert esi.vendor.id == _num(res[0])
    for i, dev in enumerate(esi.devices):
        pc, rev, nrx, ntx, erx, etx, nsm, bits = res[1 + 8 * i : 9 + 8 * i]
        assert dev.product_code == _num(pc), dev
        assert dev.revision == (_num(rev) if rev else 0), dev
        assert len(dev.rx_pdos) == int(float(nrx)), dev
        assert len(dev.tx_pdos) == int(float(ntx)), dev
        assert sum(len(p.entries) for p in dev.rx_pdos) == int(float(erx)), dev
        assert sum(len(p.entries) for p in dev.tx_pdos) == int(float(etx)), dev
        assert len(dev.sms) == int(float(nsm)), dev
        assert sum(p.bit_size for p in dev.pdos) == int(float(bits)), dev


def test_beckhoff_catalogue(corpus_dir: Path) -> None:
    esi = load_esi(corpus_dir / "esi" / "beckhoff_EL1xxx.xml")
    assert esi.vendor.id == 2
    assert esi.vendor.file_version == 14
    assert len(esi.devices) == 155
    # Several revisions per product code; the EL1004 on the ethercrab bench.
    el1004 = esi.find_device(0x03EC3052, 0x00130000)
    assert el1004.type_name == "EL1004"
    assert len(esi.devices_for(0x03EC3052)) > 1
    assert esi.find_device(0x03EC3052).revision == max(
        d.revision for d in esi.devices_for(0x03EC3052)
    )
    # German and English names, chosen by LcId.
    assert set(el1004.name.languages) == {1033, 1031}
    assert "Input" in el1004.name.pick(1033)
    assert "Eingang" in el1004.name.pick(1031)
    # 4 one-bit inputs in SM0, no mailbox.
    layout = el1004.pdo_layout()
    sm0 = layout.for_sm(0)
    assert sm0 is not None and sm0.sm.kind == "Inputs" and sm0.sm.start_address == 0x1000
    assert sm0.bit_size == 4 and sm0.byte_size == 1
    assert layout.input_bits == 4 and layout.output_bits == 0
    assert el1004.mailbox is None and el1004.mailbox_sizes is None
    assert el1004.eeprom is not None and el1004.eeprom.byte_size == 2048
    assert el1004.eeprom.config_data is not None and len(el1004.eeprom.config_data) > 0


def test_beckhoff_exclude_and_dc(corpus_dir: Path) -> None:
    esi = load_esi(corpus_dir / "esi" / "beckhoff_EL1xxx.xml")
    # EL1202-0100: TxPDO 0x1A10 (optional) and 0x1A11 (Sm=1, virtual) exclude each other.
    dev = next(d for d in esi.devices if d.type_name == "EL1202-0100")
    a10, a11 = dev.pdo(0x1A10), dev.pdo(0x1A11)
    assert a10 is not None and a11 is not None
    assert a10.excludes == (0x1A11,) and a11.excludes == (0x1A10,)
    assert a10.sm is None and a11.sm == 1 and a11.virtual
    chosen = [p.index for p in dev.default_pdos("tx")]
    assert 0x1A11 in chosen and 0x1A10 not in chosen
    sm1 = dev.sms[1]
    assert sm1.virtual and sm1.start_address == 0x0990
    assert dev.dc is not None
    mode = dev.dc.op_modes[0]
    assert mode.name == "DcLatch" and mode.assign_activate == 0x0300
    assert mode.shift_time_sync0_input
    # The one InitCmd of the catalogue: Index 61569 (decimal) = 0xF081.
    cmds = [c for d in esi.devices if d.mailbox and d.mailbox.coe for c in d.mailbox.coe.init_cmds]
    assert len(cmds) == 1
    assert cmds[0].transitions == ("IP",) and cmds[0].index == 0xF081
    assert cmds[0].subindex == 1 and cmds[0].data == bytes.fromhex("00001000")


def test_odd_vendor_spellings(corpus_dir: Path) -> None:
    esi_dir = corpus_dir / "esi"
    assert load_esi(esi_dir / "soes_rtl_slavedemo_RTL_ATO.xml").vendor.id == 0x1337  # "4919"
    orbita = load_esi(esi_dir / "poulpe_Orbita2d.xml")
    assert orbita.vendor.id == 0xF3F  # "0xF3F"
    dev = orbita.find_device(1, 1)
    # Entry indices written "#x0x6041" in this file.
    assert dev.rx_pdos[0].entries[0].index == 0x6041
    # SMs named OrbitaIn/OrbitaOut: the role comes from the control byte.
    assert [s.kind for s in dev.sms] == ["MBoxOut", "MBoxIn", "Outputs", "Inputs"]
    assert dev.mailbox_sizes == (128, 128)
    # No Version attribute on EtherCATInfo in this SOES file.
    assert load_esi(esi_dir / "soes_linux_lan9252demo.xml").version is None


def test_ingenia_dictionary(corpus_dir: Path) -> None:
    esi = load_esi(corpus_dir / "esi" / "kickcat_ingenia_esi.xml")
    dev = esi.find_device(0x03B11002, 0x00050005)
    assert dev.mailbox is not None and dev.mailbox.supports("EoE") and dev.mailbox.supports("foe")
    coe = dev.mailbox.coe
    assert coe is not None and coe.sdo_info
    d = dev.dictionary
    assert d is not None and len(d.objects) > 100
    ident = d.object(0x1018)
    assert ident is not None
    entries = d.entries(ident)
    assert [e.subindex for e in entries][:2] == [0, 1]
    assert entries[1].code == 0x0007 and entries[1].bit_size == 32  # vendor id, UDINT
    assert entries[1].default == (0x29C).to_bytes(4, "little")
    # Every PDO entry maps an object that the dictionary declares mappable.
    for pdo in dev.pdos:
        for e in pdo.entries:
            if e.is_padding:
                continue
            obj = d.object(e.index)
            assert obj is not None, hex(e.index)
            flat = {x.subindex: x for x in d.entries(obj)}
            assert e.subindex in flat, (hex(e.index), e.subindex)
            assert flat[e.subindex].bit_size == e.bit_len


def test_ecat402_default_device_type(corpus_dir: Path) -> None:
    esi = load_esi(corpus_dir / "esi" / "kickcat_ecat402-drive.xml")
    d = esi.devices[0].dictionary
    assert d is not None
    obj = d.object(0x1000)
    assert obj is not None and obj.info.default_data == (0x00020192).to_bytes(4, "little")
    assert d.object(0x603F) is not None
