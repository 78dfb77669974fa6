"""The SII codec against the real EEPROM dumps of ../shared/corpus/sii.

Identities and category lists come from the corpus MANIFEST.md (written by
whoever collected the files, not derived from this parser); process-data sizes,
E-bus current and SyncManager settings are checked against SOEM's slaveinfo
output in corpus/slaveinfo.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from pyethercat.errors import SiiError
from pyethercat.wire.sii import (
    CategoryType,
    FmmuUsage,
    build_sii,
    category_body,
    format_sii,
    parse_sii,
    sii_bytes_needed,
)

NEGATIVE = {"ethercrab_akd_null_strings.bin", "ethercrab_issue-286-empty-eeprom.bin"}


def _sii_files(corpus_dir: Path) -> list[Path]:
    files = sorted((corpus_dir / "sii").glob("*.bin"))
    assert len(files) >= 20
    return files


@dataclass
class ManifestRow:
    vendor: int
    product: int
    revision: int
    size_kbit: int
    mailbox: int
    categories: list[tuple[str, int, bool]]  # name, bytes, truncated
    serial: int | None = None


def _manifest(corpus_dir: Path) -> dict[str, ManifestRow]:
    """The 'SII identity' table of MANIFEST.md, plus serials from manifest.json."""
    text = (corpus_dir / "MANIFEST.md").read_text(encoding="utf-8")
    section = text.split("### SII identity", 1)[1].split("\n## ", 1)[0]
    rows: dict[str, ManifestRow] = {}
    for line in section.splitlines():
        m = re.match(
            r"\| `([^`]+\.bin)` \| (0x[0-9a-f]+) \| (0x[0-9a-f]+) \| (0x[0-9a-f]+) "
            r"\| (\d+) \| (0x[0-9a-f]+) \| ([^|]*) \|",
            line,
        )
        if not m:
            continue
        cats = [
            (c.group(1), int(c.group(2)), bool(c.group(3)))
            for c in re.finditer(r"(\w+)\((\d+)B( TRUNC)?\)", m.group(7))
        ]
        rows[m.group(1)] = ManifestRow(
            int(m.group(2), 16),
            int(m.group(3), 16),
            int(m.group(4), 16),
            int(m.group(5)),
            int(m.group(6), 16),
            cats,
        )
    for entry in json.loads((corpus_dir / "manifest.json").read_text(encoding="utf-8")):
        name = entry["local"].removeprefix("sii/")
        serial = re.search(r"serial (0x[0-9A-Fa-f]+|\d+)", entry.get("description") or "")
        if name in rows and serial:
            rows[name].serial = int(serial.group(1), 0)
    return rows


_MANIFEST_CATEGORY = {
    "STRINGS": CategoryType.STRINGS,
    "GENERAL": CategoryType.GENERAL,
    "FMMU": CategoryType.FMMU,
    "SM": CategoryType.SYNCM,
    "FMMUX": CategoryType.FMMU_EX,
    "SYNCUNIT": CategoryType.SYNC_UNIT,
    "TXPDO": CategoryType.TXPDO,
    "RXPDO": CategoryType.RXPDO,
    "DC": CategoryType.DC,
    "NOP": 1,  # the manifest calls EL2262's leading type-1 category NOP
}


def test_every_dump_parses_and_matches_manifest_identity(corpus_dir: Path) -> None:
    manifest = _manifest(corpus_dir)
    files = _sii_files(corpus_dir)
    assert {f.name for f in files} == set(manifest)
    for path in files:
        data = path.read_bytes()
        info = parse_sii(data)
        row = manifest[path.name]
        assert (info.vendor_id, info.product_code, info.revision) == (
            row.vendor,
            row.product,
            row.revision,
        ), path.name
        assert info.eeprom_size_kbit == row.size_kbit, path.name
        assert int(info.mailbox_protocols) == row.mailbox, path.name
        if row.serial is not None:
            assert info.serial == row.serial, path.name
        if path.name in NEGATIVE:
            continue
        assert info.warnings == [], (path.name, info.warnings)
        assert info.checksum_ok and info.end_marker
        # Category types and body sizes as listed by the manifest (END is not a category).
        want = [
            (int(_MANIFEST_CATEGORY.get(name, 0)) or int(name, 16), size)
            for name, size, _trunc in row.categories
            if name != "END"
        ]
        got = [(int(cat.type), len(category_body(cat))) for cat in info.categories]
        assert got == want, path.name
        assert format_sii(info)  # renders without error


def test_well_formed_dumps_rebuild_byte_identical(corpus_dir: Path) -> None:
    for path in _sii_files(corpus_dir):
        if path.name in NEGATIVE:
            continue
        data = path.read_bytes()
        info = parse_sii(data, strict=True)
        rebuilt = build_sii(info, pad=False, fix_checksum=False)
        assert data[: len(rebuilt)] == rebuilt, path.name
        # The rest is erased EEPROM (0xFF); one SOES image has 4 zero bytes at 0x7F8
        # (see MANIFEST.md), beyond its size word's 1920 bytes.
        tail = data[len(rebuilt) : info.eeprom_size_bytes]
        assert set(tail) <= {0xFF}, path.name
        # parse -> build (padded to the size word, CRC recomputed) -> parse
        again = parse_sii(build_sii(info), strict=True)
        assert again == info, path.name
        assert len(build_sii(info)) == info.eeprom_size_bytes


def test_read_plan_reads_exactly_the_category_chain(corpus_dir: Path) -> None:
    """Feeding a dump word-pair by word-pair, the plan stops right after the end marker."""
    for path in _sii_files(corpus_dir):
        data = path.read_bytes()
        have = b""
        reads = 0
        while (need := sii_bytes_needed(have)) is not None:
            assert need > len(have)
            # the master reads 8 bytes at a time (SII read size bit)
            more = data[: min(len(data), -(-need // 8) * 8)]
            if len(more) <= len(have):
                break  # the dump ends before the chain does
            have = more
            reads += 1
        assert reads < 2000
        info = parse_sii(have) if len(have) >= 32 else None
        if path.name in NEGATIVE:
            continue
        assert info is not None
        assert info == parse_sii(data), path.name
        assert info.end_marker and not info.warnings, path.name


def test_negative_akd_null_strings(corpus_dir: Path) -> None:
    data = (corpus_dir / "sii" / "ethercrab_akd_null_strings.bin").read_bytes()
    info = parse_sii(data)
    # The fixed area and the category chain up to STRINGS survive.
    assert info.checksum_ok
    assert [int(c.type) for c in info.categories] == [0x800, 0x801, 10, 0x100]
    assert info.strings[3] == b"AKD EtherCA"  # the hand-cut string 4
    assert info.strings[9].startswith(b"Statu\x00")
    assert not info.end_marker
    assert len(info.warnings) == 1
    assert "0x0100" in info.warnings[0] and "word 0x0145" in info.warnings[0]
    assert info.general is None and info.device_name is None
    with pytest.raises(SiiError, match=r"category 0x0100 at word 0x0145"):
        parse_sii(data, strict=True)


def test_negative_issue_286_empty_eeprom(corpus_dir: Path) -> None:
    data = (corpus_dir / "sii" / "ethercrab_issue-286-empty-eeprom.bin").read_bytes()
    info = parse_sii(data)
    assert not info.checksum_ok
    assert info.categories == []
    assert not info.end_marker
    assert any("checksum" in w for w in info.warnings)
    assert any("blank" in w for w in info.warnings)
    assert sii_bytes_needed(data) is None  # the master stops at the zero header
    with pytest.raises(SiiError, match="checksum"):
        parse_sii(data, strict=True)


# --- SOEM slaveinfo cross-check ---------------------------------------------------------


@dataclass
class SoemSlave:
    name: str
    man: int
    ident: int
    rev: int
    out_bits: int
    in_bits: int
    ebus_ma: int
    mbx_protocols: int
    coe_details: int
    sms: list[tuple[int, int]] = field(default_factory=list)  # (address, type)
    fmmu_func: list[int] = field(default_factory=list)


def _slaveinfo(path: Path) -> list[SoemSlave]:
    raw = path.read_bytes()
    text = raw.decode("utf-16") if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else raw.decode()
    slaves = []
    for block in re.split(r"\nSlave:\d+\n", text)[1:]:

        def num(pattern: str, base: int = 10, b: str = block) -> int:
            m = re.search(pattern, b)
            assert m, pattern
            return int(m.group(1), base)

        s = SoemSlave(
            name=re.search(r"Name:(.*)", block).group(1).strip(),  # type: ignore[union-attr]
            man=num(r"Man: ([0-9a-f]+)", 16),
            ident=num(r"ID: ([0-9a-f]+)", 16),
            rev=num(r"Rev: ([0-9a-f]+)", 16),
            out_bits=num(r"Output size: (\d+)bits"),
            in_bits=num(r"Input size: (\d+)bits"),
            ebus_ma=num(r"Ebus current: (-?\d+)\[mA\]"),
            mbx_protocols=num(r"MBX protocols : ([0-9a-f]+)", 16),
            coe_details=num(r"CoE details: ([0-9a-f]+)", 16),
        )
        s.sms = [
            (int(a, 16), int(t)) for a, t in re.findall(r"SM\d A:([0-9a-f]+) .*Type:(\d+)", block)
        ]
        m = re.search(r"FMMUfunc (.*)", block)
        assert m
        s.fmmu_func = [int(x.split(":")[1]) for x in m.group(1).split()]
        slaves.append(s)
    return slaves


def test_pdo_sizes_and_settings_match_soem_slaveinfo(corpus_dir: Path) -> None:
    dumps = {}
    for path in _sii_files(corpus_dir):
        if path.name in NEGATIVE:
            continue
        info = parse_sii(path.read_bytes())
        dumps[(info.vendor_id, info.product_code, info.revision)] = info
    checked = set()
    for txt in sorted((corpus_dir / "slaveinfo").glob("*.txt")):
        for soem in _slaveinfo(txt):
            info = dumps.get((soem.man, soem.ident, soem.rev))
            if info is None:
                continue
            checked.add(soem.name)
            assert info.order_number == soem.name  # SOEM's name is string 1 here
            assert info.output_bits == soem.out_bits, soem.name
            assert info.input_bits == soem.in_bits, soem.name
            assert info.general is not None
            assert info.general.ebus_current_ma == soem.ebus_ma
            assert int(info.mailbox_protocols) == soem.mbx_protocols
            assert int(info.general.coe_details) == soem.coe_details
            # SOEM lists the SMs it configured: start address and type from the SII.
            for n, (addr, sm_type) in enumerate(soem.sms):
                assert info.sync_managers[n].start == addr
                assert info.sync_managers[n].sm_type == sm_type
            # SOEM's FMMU functions (0 = unused) are the SII FMMU usages in order.
            usages = [0 if u == FmmuUsage.NOT_USED else int(u) for u in info.fmmus]
            assert (usages + [0] * 4)[:4] == soem.fmmu_func[:4]
    assert checked == {"EK1100", "EL2004"}


def test_ethercrab_terminal_pdo_entry_counts(corpus_dir: Path) -> None:
    """Channel counts of the Beckhoff terminals (from their names) versus the RxPDOs."""
    sii = corpus_dir / "sii"
    for name, channels in (("el2004", 4), ("el2828", 8), ("el2889", 16)):
        info = parse_sii((sii / f"ethercrab_{name}.bin").read_bytes())
        assert len(info.rx_pdos) == channels
        assert all(len(p.entries) == 1 and p.bit_length == 1 for p in info.rx_pdos)
        assert info.output_bits == channels and info.input_bits == 0
        assert info.tx_pdos == []
        # One output SyncManager at 0x0F00, one output FMMU.
        assert info.sync_managers[0].start == 0x0F00
        assert info.fmmus[0] == FmmuUsage.OUTPUTS
    akd = parse_sii((sii / "ethercrab_akd.bin").read_bytes())
    assert akd.device_name == "AKD EtherCAT Drive (CoE)"
    assert (len(akd.tx_pdos), len(akd.rx_pdos)) == (12, 12)
    # TXPDO 520 B / RXPDO 368 B (manifest) = 12 headers of 8 B + entries of 8 B.
    assert sum(len(p.entries) for p in akd.tx_pdos) == (520 - 96) // 8
    assert sum(len(p.entries) for p in akd.rx_pdos) == (368 - 96) // 8
    assert len(akd.dc_modes) == 2
    el2262 = parse_sii((sii / "ethercrab_el2262.bin").read_bytes())
    assert len(el2262.dc_modes) == 4
    assert el2262.dc_modes[0].assign_activate == 0x0730
    assert [int(c.type) for c in el2262.raw_categories] == [1, 42, 43]
    # The description string holds a latin-1 micro sign.
    assert el2262.device_name is not None and "1\u00b5s" in el2262.device_name


def test_hbm_clipx_binary_string(corpus_dir: Path) -> None:
    info = parse_sii((corpus_dir / "sii" / "ethercrab_hbm_clipx.bin").read_bytes())
    assert info.device_name == "ClipX"
    icon = info.strings[0]
    assert len(icon) > 100 and not icon.isascii()
    assert isinstance(info.string(1), str)
