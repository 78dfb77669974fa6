"""Benchmark: ESI parsing and start-up from an ENI file versus a full SII scan.

1. Parse time of the 4 MB Beckhoff EL1xxx catalogue (median of ``--repeat``),
   split into libxml2 alone (lxml, same safe settings) and the whole parse into
   the typed model, plus the default PDO layout per device.
2. Start-up of a simulated segment of ``--slaves`` slaves made from ESI files
   (EL1004 terminals, with every tenth slave the seed 002 CoE drive), over the
   in-process link: "SII" = scan reading every EEPROM + configure (CoE slaves'
   PDO mapping read over SDO); "ENI" = scan without SII + identity check +
   configure from an ENI exported before. Both end with the same process-data
   configuration (checked).

The last output line is one JSON object of the figures.

Usage: python benchmarks/esi.py [--slaves N] [--repeat N] [--catalogue ESI_FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from lxml import etree

from pyethercat.clock import VirtualClock
from pyethercat.esi import parse_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.eni import build_eni, parse_eni
from pyethercat.esi.xmlread import _make_parser
from pyethercat.link.pair import PairLink
from pyethercat.master.esi_config import eni_from_master, start_from_eni
from pyethercat.master.master import Master
from pyethercat.sim.topology import load_topology

CORPUS = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "esi"
CATALOGUE = CORPUS / "beckhoff_EL1xxx.xml"


def _topology(n: int, folder: Path) -> Path:
    parts = []
    for i in range(n):
        if i % 10 == 9:
            parts.append(f'[[slave]]\nname = "drive{i}"\nesi = "{bundled_esi()}"\n')
        else:
            parts.append(
                f'[[slave]]\nname = "in{i}"\nesi = "{CATALOGUE}"\n'
                "product = 0x03EC3052\nrevision = 0x00130000\n"
            )
    path = folder / "bench.toml"
    path.write_text("\n".join(parts))
    return path


def _master(topo: Path) -> Master:
    seg = load_topology(topo).build()
    return Master(PairLink.responder_link(seg.process), clock=VirtualClock())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slaves", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--catalogue", type=Path, default=CATALOGUE,
                    help="ESI file for the parse figures (the start-up uses the EL1004).")  # fmt: skip
    args = ap.parse_args()

    data = args.catalogue.read_bytes()
    lxml_s: list[float] = []
    parse_s: list[float] = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        etree.fromstring(data, parser=_make_parser())
        t1 = time.perf_counter()
        esi = parse_esi(data, args.catalogue.name)
        parse_s.append(time.perf_counter() - t1)
        lxml_s.append(t1 - t0)
    t0 = time.perf_counter()
    for dev in esi.devices:
        dev.pdo_layout()
    layout_us = (time.perf_counter() - t0) / max(len(esi), 1) * 1e6
    parse_ms = statistics.median(parse_s) * 1e3
    lxml_ms = statistics.median(lxml_s) * 1e3
    entries = sum(len(p.entries) for d in esi.devices for p in d.pdos)
    print(
        f"parse {args.catalogue.name}: {len(data)} bytes, {len(esi)} devices, {entries} PDO "
        f"entries: median {parse_ms:.1f} ms ({len(data) / parse_ms / 1e3:.1f} MB/s), of which "
        f"libxml2 {lxml_ms:.1f} ms; pdo_layout {layout_us:.1f} us per device"
    )

    with tempfile.TemporaryDirectory() as tmp:
        topo = _topology(args.slaves, Path(tmp))
        sii_s, eni_s, bare_s = [], [], []
        eni_xml = b""
        for _ in range(args.repeat):
            m = _master(topo)
            t0 = time.perf_counter()
            m.scan()
            cfg = m.configure()
            sii_s.append(time.perf_counter() - t0)
            eni = eni_from_master(m)
            eni_xml = build_eni(eni)
            m.close()

            m2 = _master(topo)
            t0 = time.perf_counter()
            start_from_eni(m2, parse_eni(eni_xml))
            cfg2 = m2.configure()
            eni_s.append(time.perf_counter() - t0)
            assert eni_from_master(m2) == eni, "ENI start gave another configuration"
            assert [g.size for g in cfg2.groups] == [g.size for g in cfg.groups]
            m2.close()

            m3 = _master(topo)
            t0 = time.perf_counter()
            m3.scan(read_sii=False)
            bare_s.append(time.perf_counter() - t0)
            m3.close()
    sii_ms = statistics.median(sii_s) * 1e3
    eni_ms = statistics.median(eni_s) * 1e3
    bare_ms = statistics.median(bare_s) * 1e3
    print(
        f"start-up of {args.slaves} slaves: SII scan + configure {sii_ms:.1f} ms, "
        f"ENI {eni_ms:.1f} ms (x{sii_ms / eni_ms:.2f}), ENI file {len(eni_xml)} bytes"
    )
    print(
        f"  of which the bare scan (count, reset to INIT, addresses; no SII) takes "
        f"{bare_ms:.1f} ms; beyond it: SII {sii_ms - bare_ms:.1f} ms, "
        f"ENI {eni_ms - bare_ms:.1f} ms"
    )
    figures = {
        "catalogue_bytes": len(data),
        "catalogue_devices": len(esi),
        "catalogue_pdo_entries": entries,
        "esi_parse_ms": round(parse_ms, 2),
        "esi_parse_min_ms": round(min(parse_s) * 1e3, 2),
        "esi_parse_mb_per_s": round(len(data) / parse_ms / 1e3, 2),
        "lxml_only_ms": round(lxml_ms, 2),
        "parse_vs_lxml_ratio": round(parse_ms / lxml_ms, 2),
        "pdo_layout_us_per_device": round(layout_us, 2),
        "slaves": args.slaves,
        "startup_sii_ms": round(sii_ms, 2),
        "startup_eni_ms": round(eni_ms, 2),
        "startup_speedup_eni_vs_sii": round(sii_ms / eni_ms, 3),
        "bare_scan_ms": round(bare_ms, 2),
        "beyond_scan_sii_ms": round(sii_ms - bare_ms, 2),
        "beyond_scan_eni_ms": round(eni_ms - bare_ms, 2),
        "beyond_scan_speedup_eni_vs_sii": round(
            (sii_ms - bare_ms) / max(eni_ms - bare_ms, 1e-3), 3
        ),
        "eni_bytes": len(eni_xml),
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
