"""The simulator's FoE server and bootloader, driven by our master's FoE client in process."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.errors import (
    BootMailboxConfigError,
    BootstrapNotSupportedError,
    ConfigError,
    FoeAccessDenied,
    FoeChecksumError,
    FoeIllegal,
    FoeNoRights,
    FoeNotFound,
    FoeProgramError,
    FoeTimeoutError,
    MailboxErrorReply,
)
from pyethercat.link.pair import PairLink
from pyethercat.master import states
from pyethercat.master.bootstrap import bootstrap_update
from pyethercat.master.foe import FoeClient
from pyethercat.master.master import Master
from pyethercat.sim.firmware import build_firmware_image
from pyethercat.sim.foe import FoeProtocol
from pyethercat.sim.segment import Segment
from pyethercat.sim.topology import parse_topology
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame
from pyethercat.wire.mailbox.header import MailboxType
from pyethercat.wire.sii import parse_sii

CORPUS_SII = Path(__file__).resolve().parents[3] / "shared" / "corpus" / "sii"
CORPUS_ESI = CORPUS_SII.parent / "esi"
DATA = bytes((i * 131 + 7) & 0xFF for i in range(50_000))


def _master(toml: str, base: Path | str = ".") -> tuple[Segment, Master]:
    seg = parse_topology(toml, base_dir=base).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    return seg, m


def _foe(seg: Segment, i: int) -> FoeProtocol:
    app = seg.slaves[i].spec.app
    return app.protocols[MailboxType.FOE]  # type: ignore[union-attr,no-any-return]


def _client(m: Master, i: int = 0) -> FoeClient:
    # the master made it with the slave's mailbox (the client registry)
    return m.slaves[i].client(FoeClient)


IO = """
[[slave]]
name = "io"
device = "builtin:coe-io"
foe = true
"""


def test_memory_files_round_trip_and_progress() -> None:
    seg, m = _master(IO)
    c = _client(m)
    seen = []
    c.write("data.bin", DATA, progress=seen.append)
    assert [p.done for p in seen] == sorted(p.done for p in seen) and seen[-1].done == len(DATA)
    assert seen[-1].fraction == 1.0 and seen[-1].total == len(DATA)
    assert _foe(seg, 0).store.files["data.bin"] == DATA
    got: list[int] = []
    assert c.read("data.bin", progress=lambda p: got.append(p.done)) == DATA
    assert got[-1] == len(DATA) and c.stats.bytes == len(DATA) and c.stats.packets > 400
    with pytest.raises(FoeNotFound, match="nope"):
        c.read("nope")


def test_directory_store_password_and_plain_names(tmp_path: Path) -> None:
    files = tmp_path / "files"
    files.mkdir()
    (files / "existing.txt").write_bytes(b"from disk")
    seg, m = _master(IO + 'foe_dir = "files"\nfoe_password = 0x1234\n', tmp_path)
    c = _client(m)
    with pytest.raises(FoeNoRights):
        c.read("existing.txt")
    assert c.read("existing.txt", password=0x1234) == b"from disk"
    c.write("new.bin", DATA, password=0x1234)
    assert (files / "new.bin").read_bytes() == DATA
    assert oct((files / "new.bin").stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    with pytest.raises(FoeAccessDenied):
        c.write("../escape", b"x", password=0x1234)
    assert not (tmp_path / "escape").exists()
    assert sorted(p.name for p in files.iterdir()) == ["existing.txt", "new.bin"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_busy_schedule_makes_the_master_resend() -> None:
    seg, m = _master(IO + "foe_busy_every = 5\n")
    c = _client(m)
    c.write("b.bin", DATA)
    server = _foe(seg, 0)
    assert server.busy_sent > 50 and c.stats.busy == server.busy_sent
    assert server.store.files["b.bin"] == DATA


def test_injected_error_reaches_the_master_typed() -> None:
    seg, m = _master(IO)
    _foe(seg, 0).fail_at(3)
    with pytest.raises(FoeProgramError, match="injected error"):
        _client(m).write("x", DATA)
    assert "x" not in _foe(seg, 0).store.files
    _client(m).write("x", DATA)  # the next transfer works
    assert _foe(seg, 0).store.files["x"] == DATA


def test_slave_that_wraps_its_packet_numbers_at_256() -> None:
    seg, m = _master(IO + "foe_wrap = 256\n")
    data = bytes(range(256)) * 150  # 38400 bytes: over 300 packets of 116 bytes
    _foe(seg, 0).store.files["w"] = data
    assert _client(m).read("w") == data
    _client(m).write("w2", data, wrap=256)
    assert _foe(seg, 0).store.files["w2"] == data


def test_silent_slave_times_out_typed() -> None:
    seg, m = _master(IO)
    app = seg.slaves[0].spec.app
    app.mailbox.register(MailboxType.FOE, lambda header, payload: None)  # type: ignore[union-attr]
    with pytest.raises(FoeTimeoutError, match="no answer to FoeWriteRequest within 0.05 s"):
        _client(m).write("x", b"abc", packet_timeout=0.05)


def test_foe_off_gives_the_mailbox_error_and_default_follows_the_sii() -> None:
    _seg, m = _master(IO.replace("foe = true", "foe = false"))
    with pytest.raises(MailboxErrorReply) as info:
        _client(m).read("x")
    assert info.value.code == 0x0002  # protocol not supported
    # an SII that announces FoE (HBM ClipX) gets a server without being asked
    _seg, m2 = _master(f'[[slave]]\nname = "clipx"\nsii = "{CORPUS_SII / "ethercrab_hbm_clipx.bin"}"\n')
    with pytest.raises(FoeNotFound):
        _client(m2).read("missing")


def test_esi_device_announcing_foe_serves_it() -> None:
    esi = CORPUS_ESI / "poulpe_Orbita2d.xml"
    seg, m = _master(f'[[slave]]\nname = "orbita"\nesi = "{esi}"\n')
    c = _client(m)
    c.write("cfg.json", b'{"a": 1}')
    assert c.read("cfg.json") == b'{"a": 1}'
    # and the ESI's CoE dictionary still answers next to it
    assert m.slaves[0].sdo_read(0x1018, 1, "uint32") == m.slaves[0].identity.vendor_id


def test_topology_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="foe_busy_every given with foe = false"):
        parse_topology(IO.replace("foe = true", "foe = false\nfoe_busy_every = 3"))
    with pytest.raises(ConfigError, match="foe_dir .* is not a folder"):
        parse_topology(IO + 'foe_dir = "/nonexistent/folder"\n')
    with pytest.raises(ConfigError, match="FoE/SoE need a mailbox"):
        parse_topology('[[slave]]\nname = "d"\ndevice = "builtin:di8"\nfoe = true\n').build()


# --- bootstrap -------------------------------------------------------------------------


def test_bootstrap_update_through_the_boot_mailbox() -> None:
    orbita = CORPUS_SII / "poulpe_Orbita2d.bin"
    info = parse_sii(orbita.read_bytes())
    # the image's bootstrap send mailbox differs from the standard one: 0x1080 vs 0x1180
    assert info.boot_tx_mailbox_offset != info.tx_mailbox_offset
    seg = parse_topology(f'[[slave]]\nname = "orbita"\nsii = "{orbita}"\n' + IO).build()
    frames: list[bytes] = []

    def record(frame: bytes) -> bytes | None:
        frames.append(frame)
        return seg.process(frame)

    m = Master(PairLink.responder_link(record), clock=VirtualClock())
    m.scan()
    s = m.slaves[0]
    image = build_firmware_image(info.vendor_id, info.product_code, 0x00000007, "v7.0",
                                 bytes(3000))
    seen = []
    bootstrap_update(m, 0, image, progress=seen.append)
    assert seen[-1].done == len(image)
    assert m.read_states([s])[0].state == AlState.INIT
    # every SM1 read of the transfer went to the bootstrap mailbox
    reads = {(d.ado, len(d.data)) for f in frames for d in decode_frame(f).datagrams
             if d.command == Command.FPRD and d.adp == s.station_address
             and len(d.data) > 8}
    assert (info.boot_tx_mailbox_offset, info.boot_tx_mailbox_size) in reads
    assert (info.tx_mailbox_offset, info.tx_mailbox_size) not in reads
    m.scan()
    assert m.slaves[0].identity.revision == 7 and m.slaves[1].identity.revision == 0x00010000


def test_bootstrap_refusals_are_typed() -> None:
    seg, m = _master(IO)
    s = m.slaves[0]
    vendor, product = s.identity.vendor_id, s.identity.product_code
    good = build_firmware_image(vendor, product, 0x00020003, "v2.3", bytes(5000))
    with pytest.raises(FoeIllegal, match="image is for vendor 0x00000001"):
        bootstrap_update(m, 0, build_firmware_image(1, 2, 3, "x", b""))
    with pytest.raises(FoeChecksumError, match="CRC"):
        bootstrap_update(m, 0, good[:-1] + bytes([good[-1] ^ 1]))
    with pytest.raises(FoeIllegal, match="not a firmware image"):
        bootstrap_update(m, 0, b"hello")
    with pytest.raises(FoeNoRights):
        bootstrap_update(m, 0, good, password=9)
    bootstrap_update(m, 0, good)
    m.scan()
    m.set_state("PREOP")
    s = m.slaves[0]
    assert s.identity.revision == 0x00020003
    assert s.sdo_read(0x100A, 0, "string") == "v2.3"
    assert s.sdo_read(0x1018, 3, "uint32") == 0x00020003


def test_boot_refused_without_bootstrap_mailbox_and_al_codes_typed() -> None:
    k64 = CORPUS_SII / "kickcat_freedom-k64f.bin"
    _seg, m = _master(f'[[slave]]\nname = "k64"\nsii = "{k64}"\nfoe = true\n')
    with pytest.raises(ConfigError, match="no bootstrap mailbox in the SII"):
        bootstrap_update(m, 0, b"x")
    assert m.read_states()[0].state == AlState.PREOP  # refused before anything was sent
    # a plain state request goes out (as IgH's does): the slave says 0x0013, typed
    m.set_state("INIT")
    with pytest.raises(BootstrapNotSupportedError) as info:
        m.set_state("BOOT")
    assert info.value.code == 0x0013
    # a slave with a bootstrap mailbox whose SMs are not programmed for it: 0x0015
    _seg, m2 = _master(IO)
    m2.set_state("INIT")
    m2.write(m2.slaves[0], reg.sm_address(0), bytes(8))
    with pytest.raises(BootMailboxConfigError) as info2:
        # requested without the master's mailbox set-up (states.set_state, prepare=None)
        states.set_state(m2.scheduler, m2.slaves, AlState.BOOT, prepare=None)
    assert info2.value.code == 0x0015
