"""Benchmark: parse the 4 MB Beckhoff EL1xxx ESI catalogue.

Prints the time for libxml2 alone (lxml, same safe settings) and for the whole
parse into the typed model, the device count, and the per-device PDO layout
time. The last line is one JSON object of the figures.

Usage: python benchmarks/esi_parse.py [ESI_FILE] [--repeat N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from lxml import etree

from pyethercat.esi import parse_esi
from pyethercat.esi.parse import _make_parser

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "corpus" / "esi" / "beckhoff_EL1xxx.xml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    data = args.path.read_bytes()

    lxml_s: list[float] = []
    full_s: list[float] = []
    esi = None
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        etree.fromstring(data, parser=_make_parser())
        t1 = time.perf_counter()
        esi = parse_esi(data, str(args.path))
        t2 = time.perf_counter()
        lxml_s.append(t1 - t0)
        full_s.append(t2 - t1)
    assert esi is not None

    t0 = time.perf_counter()
    for dev in esi.devices:
        dev.pdo_layout()
    layout_s = time.perf_counter() - t0

    entries = sum(len(p.entries) for d in esi.devices for p in d.pdos)
    figures = {
        "file": args.path.name,
        "bytes": len(data),
        "devices": len(esi.devices),
        "pdo_entries": entries,
        "repeat": args.repeat,
        "lxml_ms_median": round(statistics.median(lxml_s) * 1e3, 2),
        "parse_ms_median": round(statistics.median(full_s) * 1e3, 2),
        "parse_ms_min": round(min(full_s) * 1e3, 2),
        "parse_mb_per_s": round(len(data) / statistics.median(full_s) / 1e6, 2),
        "model_overhead_ratio": round(statistics.median(full_s) / statistics.median(lxml_s), 2),
        "pdo_layout_us_per_device": round(layout_s / len(esi.devices) * 1e6, 2),
    }
    print(
        f"{figures['file']}: {figures['bytes']} bytes, {figures['devices']} devices, "
        f"{entries} PDO entries"
    )
    print(f"lxml parse only:        {figures['lxml_ms_median']:8.1f} ms (median of {args.repeat})")
    print(
        f"full parse into model:  {figures['parse_ms_median']:8.1f} ms "
        f"(min {figures['parse_ms_min']:.1f} ms, {figures['parse_mb_per_s']} MB/s)"
    )
    print(f"pdo_layout per device:  {figures['pdo_layout_us_per_device']:8.1f} us")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
