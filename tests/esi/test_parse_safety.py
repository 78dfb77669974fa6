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


def _run_bounded(path: Path, cpu_s: int = 20) -> subprocess.CompletedProcess[str]:
    """Parse ``path`` in a child limited to 1 GiB of address space and ``cpu_s`` s CPU."""
    code = textwrap.dedent(
        f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        resource.setrlimit(resource.RLIMIT_CPU, ({cpu_s}, {cpu_s}))
        from pyethercat.errors import EsiError
        from pyethercat.esi import load_esi
        try:
            esi = load_esi({str(path)!r})
        except EsiError as exc:
            print("ESIERROR", exc)
            sys.exit(3)
        print("PARSED", len(esi.devices))
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


def test_dtd_behind_a_comment_or_pi_rejected_within_bounds(tmp_path: Path) -> None:
    # A comment or processing instruction holding "<x" before the DOCTYPE must not
    # make the prolog check take it for the root element.
    for n, lead in enumerate(["<!-- <x> -->", "<?pi <x> ?>", "<!-- a --><?p ?>\n<!-- <!DOCTYPE -->"]):
        path = tmp_path / f"lead{n}.xml"
        path.write_text(BILLION_LAUGHS.replace("\n<!DOCTYPE", f"\n{lead}\n<!DOCTYPE", 1))
        line = 3 + lead.count("\n")
        res = _run_bounded(path)
        assert res.returncode == 3, res.stdout + res.stderr
        # The up-front check's message (not libxml2's), on the DOCTYPE's own line.
        assert f"lead{n}.xml:{line}: document type declaration with a DTD (entities" in res.stdout


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


def test_deep_nesting_inside_a_dictionary() -> None:
    # Object/Info/SubItem/Info/... is read recursively: 120 levels parse, and libxml2's
    # depth limit (256, huge_tree off) stops anything deep enough to hurt the stack.
    def doc(levels: int) -> bytes:
        inner = "<SubItem><Name>a</Name><Info>" * levels + "</Info></SubItem>" * levels
        obj = f"<Object><Index>#x2000</Index><Info>{inner}</Info></Object>"
        dictionary = f"<Profile><Dictionary><Objects>{obj}</Objects></Dictionary></Profile>"
        return MINIMAL.replace("</Type>", "</Type>" + dictionary).encode()

    dev = parse_esi(doc(120)).devices[0]
    assert dev.dictionary is not None and len(dev.dictionary.objects) == 1
    with pytest.raises(EsiError, match=r"^deep\.xml:5: malformed XML: Excessive depth"):
        parse_esi(doc(600), "deep.xml")


def test_huge_values_are_bounded_and_named(tmp_path: Path) -> None:
    # A 20 MB attribute: libxml2's size limit (huge_tree off), not a 20 MB string.
    big = MINIMAL.replace('ProductCode="#x1"', 'ProductCode="#x' + "1" * (20 << 20) + '"')
    with pytest.raises(EsiError, match=r"^a\.xml:5: malformed XML: .*limit"):
        parse_esi(big.encode(), "a.xml")
    # 5 million digits: refused by length, and the message quotes only the start.
    digits = MINIMAL.replace('ProductCode="#x1"', 'ProductCode="' + "9" * 5_000_000 + '"')
    with pytest.raises(EsiError) as info:
        parse_esi(digits.encode(), "d.xml")
    msg = str(info.value)
    assert msg.startswith("d.xml:5: Type@ProductCode: '99999") and "5000000 digits" in msg
    assert len(msg) < 200


def test_many_devices_within_bounds(tmp_path: Path) -> None:
    # 100 000 devices (7 MB): all parsed in a child held to 1 GiB and 60 s of CPU.
    head, tail = MINIMAL.split("<Device>", 1)[0], "</Devices></Descriptions>\n</EtherCATInfo>\n"
    dev = '<Device><Type ProductCode="#x{:X}" RevisionNo="#x1">D</Type></Device>\n'
    path = tmp_path / "many.xml"
    path.write_text(head + "".join(dev.format(i) for i in range(100_000)) + tail)
    res = _run_bounded(path, cpu_s=60)
    assert res.returncode == 0 and res.stdout.split() == ["PARSED", "100000"], res.stdout + res.stderr


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
        # NUL bytes and invalid UTF-8 inside the document, named by line, one line long.
        (MINIMAL.replace(">D<", ">D\x00<"), r"^t\.xml:5: malformed XML: [^\n]*Char 0x0[^\n]*$"),
        (MINIMAL.replace('"#x1"', '"#x1\x00"'), r"^t\.xml:5: malformed XML: [^\n]*attribute"),
        (MINIMAL.replace(">D<", ">D\udcff<"), r"^t\.xml:5: malformed XML: [^\n]*encoding"),
        # Out-of-range numbers are refused where they stand, not when an SII is built.
        (
            MINIMAL.replace('"#x1"', '"#x100000000"'),
            r"^t\.xml:5: Type@ProductCode: 4294967296 is out of range \(0 to 0xFFFFFFFF\)",
        ),
        (MINIMAL.replace('RevisionNo="#x2"', 'RevisionNo="-1"'), r"^t\.xml:5: Type@RevisionNo: -1 is out"),
        (MINIMAL.replace("#x2</Id>", "#x1FFFFFFFF</Id>"), r"^t\.xml:3: Vendor/Id: 8589934591 is out"),
        (
            MINIMAL.replace("</Type>", "</Type><Sm StartAddress='#x10000'>Inputs</Sm>"),
            r"^t\.xml:5: Sm@StartAddress: 65536 is out of range \(0 to 0xFFFF\)",
        ),
        (
            MINIMAL.replace("</Type>", "</Type><Sm ControlByte='#x164'>Inputs</Sm>"),
            r"^t\.xml:5: Sm@ControlByte: 356 is out of range \(0 to 0xFF\)",
        ),
        (
            MINIMAL.replace("</Type>", "</Type><TxPdo><Index>#x1A000</Index></TxPdo>"),
            r"^t\.xml:5: TxPdo/Index: 106496 is out of range",
        ),
        (
            MINIMAL.replace("</Type>", "</Type><Mailbox><CoE><InitCmd><Transition>PS</Transition>"
                            "<Index>#x6060</Index><SubIndex>256</SubIndex></InitCmd></CoE></Mailbox>"),
            r"^t\.xml:5: CoE/InitCmd/SubIndex: 256 is out of range \(0 to 0xFF\)",
        ),
    ],
)
def test_broken_files_name_file_line_and_problem(doc: str, pattern: str) -> None:
    with pytest.raises(EsiError, match=pattern):
        # surrogateescape: "\udcff" in a case stands for the invalid UTF-8 byte 0xFF.
        parse_esi(doc.encode("utf-8", "surrogateescape"), "t.xml")


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
