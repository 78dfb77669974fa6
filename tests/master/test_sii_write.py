"""Safe SII writes: busy bit and EEPROM write cycle, checksum, read-back, identity, backup.

Against the simulator's ESC profiles (four of them model a real EEPROM's
timing: a write keeps the interface busy ~300 us and the EEPROM refuses
every command for ~3.3 ms after it) and the corpus dumps of real devices.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from fake_esc_segment import FakeSegment, FakeSlave

from pyethercat.clock import VirtualClock, WallClock
from pyethercat.link.pair import PairLink
from pyethercat.master import Master
from pyethercat.master.sii_write import SiiWriteError, identity_difference, with_alias
from pyethercat.sim.profiles import PROFILES
from pyethercat.sim.topology import load_topology
from pyethercat.wire import registers as reg
from pyethercat.wire.sii import parse_sii, sii_crc

CORPUS = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "sii"
DUMPS = {"EK1100": "ethercrab_ek1100.bin", "EL2004": "ethercrab_el2004.bin",
         "EL2828": "ethercrab_el2828.bin", "EL2889": "ethercrab_el2889.bin"}


def _segment(tmp_path: Path, body: str, wall_clock: bool = False) -> tuple[Master, object]:
    topo = tmp_path / "seg.toml"
    topo.write_text(body)
    seg = load_topology(topo).build()
    if wall_clock:
        # EEPROM timing in real time: the in-process segment's virtual clock moves only
        # by the frames' wire time, which makes a long write take many thousand polls.
        seg.clock = WallClock()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    return m, seg


def _corpus(name: str) -> Path:
    path = CORPUS / DUMPS[name]
    if not path.exists():
        pytest.skip(f"corpus dump {path} not present")
    return path


def test_alias_on_every_esc_profile(tmp_path: Path) -> None:
    body = "".join(f'[[slave]]\nname = "s{n}"\ndevice = "builtin:di8"\nprofile = "{p}"\n'
                   for n, p in enumerate(PROFILES))
    m, seg = _segment(tmp_path, body, wall_clock=True)
    timed = [n for n, p in enumerate(PROFILES.values()) if p.sii_write_cycle_ns]
    assert timed, "no profile models the EEPROM write cycle"
    for n in range(len(PROFILES)):
        report = m.set_alias(n, 0x100 + n)
        assert report.written == [4, 7]
        assert m.slaves[n].alias == 0x100 + n  # register 0x0012 after the reload
        image = m.sii_read(n)
        assert struct.unpack_from("<H", image, 8)[0] == 0x100 + n
        assert image[14] == sii_crc(image) and parse_sii(image).checksum_ok
    # The EEPROM-timed profiles refused commands during the write cycle and the
    # write repeated them instead of failing half way.
    assert m.scan()[timed[0]].alias == 0x100 + timed[0]


@pytest.mark.parametrize("device, whole", [("EK1100", True), ("EL2004", True),
                                           ("EL2828", False), ("EL2889", False)])
def test_image_on_corpus_dumps(tmp_path: Path, device: str, whole: bool) -> None:
    path = _corpus(device)
    m, seg = _segment(tmp_path, f'[[slave]]\nname = "d"\nsii = "{path}"\n', wall_clock=True)
    old = m.sii_read(0)
    assert old == path.read_bytes()[:len(old)]
    new = bytearray(with_alias(old, 0x2A))
    new[0x30] ^= 0x5A  # a reserved header byte
    new[-3] ^= 0x01  # a byte of the last category
    new[14] ^= 0xFF  # a stale checksum: the writer computes its own
    backup = tmp_path / "backup.bin"
    # Every word (the bigger dumps: the changed ones) goes through the EEPROM write cycle.
    report = m.sii_write(0, bytes(new), only_changed=not whole, backup=backup)
    words = len(new) // 2
    assert report.written == (list(range(words)) if whole
                              else [4, 7, 0x18, (len(new) - 3) // 2])
    assert report.checksum_fixed and report.checksum == sii_crc(bytes(new))
    assert backup.read_bytes() == old
    now = m.sii_read(0)
    expect = bytearray(new)
    expect[14] = sii_crc(bytes(new))
    assert now == bytes(expect[:len(now)])
    assert bytes(seg.slaves[0].esc.sii[:len(expect)]) == bytes(expect)  # type: ignore[attr-defined]
    assert m.read_u16(0, reg.STATION_ALIAS) == 0x2A


def test_another_devices_image_is_refused_unless_forced(tmp_path: Path) -> None:
    ek, el = _corpus("EK1100"), _corpus("EL2004")
    m, _ = _segment(tmp_path, f'[[slave]]\nname = "ek"\nsii = "{ek}"\n', wall_clock=True)
    before = m.sii_read(0)
    foreign = el.read_bytes()
    assert identity_difference(before, foreign)
    with pytest.raises(SiiWriteError, match="another device.*product 0x044C2C52 -> 0x07D43052") as exc:
        m.sii_write(0, foreign, backup=tmp_path / "b.bin")
    assert exc.value.written == () and "EEPROM is unchanged" in str(exc.value)
    assert m.sii_read(0) == before and not (tmp_path / "b.bin").exists()
    report = m.sii_write(0, foreign, force=True)
    assert report.identity_changes and m.scan()[0].identity.product_code == 0x07D43052


def test_serial_number_alone_may_differ() -> None:
    a = bytearray(with_alias(bytes(64), 0))
    struct.pack_into("<4I", a, 16, 2, 0x1234, 5, 100)
    b = bytearray(a)
    struct.pack_into("<I", b, 28, 200)
    assert identity_difference(with_alias(bytes(a), 0), with_alias(bytes(b), 0)) == []
    struct.pack_into("<I", b, 24, 6)
    assert identity_difference(with_alias(bytes(a), 0), bytes(b)) == [
        "revision 0x00000005 -> 0x00000006"]


def test_failure_names_the_word_and_how_to_restore(tmp_path: Path) -> None:
    from test_scan_states import _image

    image = _image("A", 1)
    slave = FakeSlave(image)
    seg = FakeSegment([slave])
    # A real-time master: the write cycle is waited for by the clock, not by polls.
    m = Master(PairLink.responder_link(seg.process))
    m.scan()
    new = bytearray(image)
    new[0x60:0x64] = b"\x12\x34\x56\x78"  # words 0x30 and 0x31
    slave.refuse_sii_writes = {0x31}
    backup = tmp_path / "old.bin"
    with pytest.raises(SiiWriteError) as exc:
        m.sii_write(0, bytes(new), backup=backup)
    err = exc.value
    assert err.word == 0x31 and err.written == (0x30,)
    text = str(err)
    assert "word 0x0031" in text and "does not acknowledge" in text
    assert f"restore the old content with sii_write --force {backup}" in text
    assert backup.read_bytes()[:len(image)] == image
    assert bytes(slave.sii[0x60:0x62]) == b"\x12\x34" and bytes(slave.sii[0x62:0x64]) == image[0x62:0x64]
    slave.refuse_sii_writes = set()
    m.sii_write(0, backup.read_bytes(), force=True)
    assert bytes(slave.sii[:len(image)]) == image


def test_readback_mismatch_is_reported(tmp_path: Path) -> None:
    from test_scan_states import _image

    image = _image("A", 1)
    slave = FakeSlave(image)
    m = Master(PairLink.responder_link(FakeSegment([slave]).process), clock=VirtualClock())
    m.scan()
    slave.stuck_sii_bits = {0x30: 0x0001}  # a bit that does not take the written 0
    new = bytearray(image)
    new[0x60:0x62] = b"\xaa\x00"
    with pytest.raises(SiiWriteError, match=r"word 0x0030 reads back ab 00, wrote aa 00"):
        m.sii_write(0, bytes(new))


def test_firmware_owned_eeprom_needs_force() -> None:
    from test_scan_states import _image

    slave = FakeSlave(_image("A", 1))
    m = Master(PairLink.responder_link(FakeSegment([slave]).process), clock=VirtualClock())
    m.scan()
    slave.mem[reg.SII_PDI_ACCESS] = 1
    with pytest.raises(SiiWriteError, match="firmware .PDI. holds the EEPROM"):
        m.set_alias(0, 3)
    m.set_alias(0, 3, force=True)
    assert m.slaves[0].alias == 3
