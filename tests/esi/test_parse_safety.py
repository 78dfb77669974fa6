"""Hostile and broken ESI input is refused with a clear EsiError.

The hostile cases run in a child process with an address-space and CPU-time
limit (resource.setrlimit): if the parser ever expanded a billion-laughs
document or fetched an external entity, the child would die or hang instead of
printing the expected error. These are resource *bounds*, not timing asserts.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pyethercat.errors import EsiError
from pyethercat.esi import load_esi, parse_esi

MINIMAL = """<?xml version="1.0"?>
<EtherCATInfo>
  <Vendor><Id>#x2</Id><Name>V</Name></Vendor>
  <Descriptions><Groups/><Devices>
    <Device><Type ProductCode="#x1" RevisionNo="#x2">D</Type></Device>
  </Devices></Descriptions>
</EtherCATInfo>
"""

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE EtherCATInfo [
  <!ENTITY lol "lol">
  <!ENTITY lol1 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
  <!ENTITY lol2 "&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;">
  <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
  <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
  <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
  <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
  <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
  <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
  <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
<EtherCATInfo>
  <Vendor><Id>#x2</Id><Name>&lol9;</Name></Vendor>
  <Descriptions><Devices/></Descriptions>
</EtherCATInfo>
"""

SECRET = "pyecat-esi-secret-9f3b2c"


def _xxe(target: str) -> str:
    return f"""<?xml version="1.0"?>
<!DOCTYPE EtherCATInfo [ <!ENTITY xxe SYSTEM "{target}"> ]>
<EtherCATInfo>
  <Vendor><Id>#x2</Id><Name>&xxe;</Name></Vendor>
  <Descriptions><Devices/></Descriptions>
</EtherCATInfo>
"""


def _run_bounded(path: Path) -> subprocess.CompletedProcess[str]:
    """Parse ``path`` in a child limited to 1 GiB of address space and 20 s CPU."""
    code = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        resource.setrlimit(resource.RLIMIT_CPU, (20, 20))
        from pyethercat.errors import EsiError
        from pyethercat.esi import load_esi
        try:
            load_esi({str(path)!r})
        except EsiError as exc:
            print("ESIERROR", exc)
            sys.exit(3)
        print("PARSED")
        """
    )
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env
    )


def test_billion_laughs_rejected_within_bounds(tmp_path: Path) -> None:
    path = tmp_path / "laughs.xml"
    path.write_text(BILLION_LAUGHS)
    res = _run_bounded(path)
    assert res.returncode == 3, res.stdout + res.stderr
    assert "ESIERROR" in res.stdout
    assert "laughs.xml:2:" in res.stdout  # the DOCTYPE line
    assert "DTD" in res.stdout


def test_external_entity_rejected_and_not_read(tmp_path: Path) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET)
    path = tmp_path / "xxe.xml"
    path.write_text(_xxe(secret.as_uri()))
    res = _run_bounded(path)
    assert res.returncode == 3, res.stdout + res.stderr
    assert "xxe.xml:2:" in res.stdout
    assert SECRET not in res.stdout + res.stderr


def test_external_dtd_and_network_entity_rejected() -> None:
    doc = MINIMAL.replace(
        '<?xml version="1.0"?>',
        '<?xml version="1.0"?>\n<!DOCTYPE EtherCATInfo SYSTEM "http://192.0.2.1/esi.dtd">',
    )
    with pytest.raises(EsiError, match="DTD"):
        parse_esi(doc.encode(), "ext.xml")
    with pytest.raises(EsiError, match="DTD"):
        parse_esi(_xxe("http://192.0.2.1/x").encode(), "net.xml")
    # Parameter entities are in the internal subset too.
    pe = '<?xml version="1.0"?><!DOCTYPE x [<!ENTITY % p SYSTEM "file:///etc/passwd"> %p;]><x/>'
    with pytest.raises(EsiError, match="DTD"):
        parse_esi(pe.encode(), "pe.xml")


def test_undeclared_entity_reference_is_malformed() -> None:
    doc = MINIMAL.replace("<Name>V</Name>", "<Name>&xxe;</Name>")
    with pytest.raises(EsiError, match=r"^bad\.xml:3: malformed XML: .*xxe"):
        parse_esi(doc.encode(), "bad.xml")


def test_utf16_doctype_rejected() -> None:
    doc = _xxe("file:///etc/passwd").replace('version="1.0"', 'version="1.0" encoding="UTF-16"')
    # Refused by the up-front prolog check (its message), not only after libxml2.
    for enc in ("utf-16", "utf-32"):
        with pytest.raises(EsiError, match=r"u16\.xml:2: .*entities or an external reference"):
            parse_esi(doc.encode(enc), "u16.xml")


def test_bare_doctype_is_harmless() -> None:
    doc = MINIMAL.replace('<?xml version="1.0"?>', '<?xml version="1.0"?>\n<!DOCTYPE EtherCATInfo>')
    assert len(parse_esi(doc.encode())) == 1


def test_size_bound(tmp_path: Path) -> None:
    data = MINIMAL.encode()
    with pytest.raises(EsiError, match="more than the limit of 100"):
        parse_esi(data, "big.xml", max_bytes=100)
    path = tmp_path / "big.xml"
    path.write_bytes(data + b" " * 1000)
    with pytest.raises(EsiError, match=r"big\.xml: file is 1\d+ bytes, more than the limit"):
        load_esi(path, max_bytes=1000)
    assert len(load_esi(path)) == 1  # the default limit (64 MiB) is plenty


def test_deep_nesting_bounded() -> None:
    # libxml2 refuses very deep trees unless huge_tree is on; we keep it off.
    depth = 100_000
    doc = "<EtherCATInfo>" + "<a>" * depth + "</a>" * depth + "</EtherCATInfo>"
    with pytest.raises(EsiError, match="malformed XML"):
        parse_esi(doc.encode(), "deep.xml")


@pytest.mark.parametrize(
    ("doc", "pattern"),
    [
        (MINIMAL[:-40], r"^t\.xml:\d+: malformed XML"),  # truncated
        ("", r"^t\.xml: file is empty"),
        ("<notesi/>", r"^t\.xml:1: root element is <notesi>, expected <EtherCATInfo>"),
        (
            "<EtherCATInfo><Descriptions/></EtherCATInfo>",
            r"^t\.xml:1: EtherCATInfo: missing <Vendor>",
        ),
        (MINIMAL.replace("#x2</Id>", "two</Id>"), r"^t\.xml:3: Vendor/Id: 'two' is not a number"),
        (
            MINIMAL.replace('ProductCode="#x1"', 'ProductCode="#xZZ"'),
            r"^t\.xml:5: Type@ProductCode: '#xZZ' is not a number",
        ),
        (
            MINIMAL.replace("<Type", "<Typo").replace("</Type>", "</Typo>"),
            r"^t\.xml:5: Device: missing <Type>",
        ),
        ("<EtherCATInfo><Vendor><Id>1</Id></Vendor></EtherCATInfo>", "missing <Descriptions>"),
        ("\x00\x01garbage", r"^t\.xml:1: malformed XML"),
    ],
)
def test_broken_files_name_file_line_and_problem(doc: str, pattern: str) -> None:
    with pytest.raises(EsiError, match=pattern):
        parse_esi(doc.encode(), "t.xml")


def test_bad_values_deep_in_a_device() -> None:
    doc = MINIMAL.replace(
        "</Type>",
        "</Type>\n<RxPdo Sm='2'><Index>#x1600</Index>\n<Entry><Index>#x7000</Index>"
        "<SubIndex>1</SubIndex><BitLen>eight</BitLen></Entry></RxPdo>",
    )
    with pytest.raises(EsiError) as info:
        parse_esi(doc.encode(), "dev.xml")
    assert str(info.value) == "dev.xml:7: RxPdo/Entry/BitLen: 'eight' is not a number"
    assert info.value.path == "dev.xml" and info.value.line == 7
    for bad, what in [
        ("<Eeprom><ConfigData>0A0</ConfigData></Eeprom>", "odd number of digits"),
        ("<Eeprom><ConfigData>0G</ConfigData></Eeprom>", "non-hex"),
        ("<Sm Enable='maybe'>Inputs</Sm>", "Sm@Enable: 'maybe' is not a boolean"),
        ("<RxPdo><Name>x</Name></RxPdo>", "RxPdo: missing <Index>"),
        (
            "<TxPdo><Index>#x1a00</Index><Entry><Index>#x6000</Index></Entry></TxPdo>",
            "missing <BitLen>",
        ),
        (
            "<TxPdo><Index>#x1a00</Index><Entry><Index>#x16000</Index><BitLen>1</BitLen></Entry></TxPdo>",
            "out of range",
        ),
    ]:
        with pytest.raises(EsiError, match=what):
            parse_esi(MINIMAL.replace("</Type>", "</Type>" + bad).encode(), "dev.xml")


def test_missing_file() -> None:
    with pytest.raises(EsiError, match=r"nope\.xml: cannot read"):
        load_esi("/nonexistent/nope.xml")
