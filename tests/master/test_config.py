"""Process-data configuration from SII: sync managers, FMMUs, layouts, datagrams, WKC."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from master_sii_helpers import BOOL, INT16, UINT16, coupler, di, do, io_sii

from pyethercat.errors import ConfigError
from pyethercat.master.config import (
    DEFAULT_LOGICAL_BASE,
    GroupSpec,
    Layout,
    PdoDirection,
    SlaveDescription,
    configure,
)
from pyethercat.wire import registers as reg
from pyethercat.wire.datagram import MAX_DATA, Command
from pyethercat.wire.sii import parse_sii
from pyethercat.wire.sii.model import FmmuUsage, SiiFmmus


def specs(*siis, features=0):
    return [SlaveDescription(i, 0x1001 + i, s, features=features) for i, s in enumerate(siis)]


def test_packed_layout_shares_bytes_between_small_terminals():
    cfg = configure(specs(coupler(), do(2), do(2), do(4), di(2), di(8)))
    g = cfg.groups[0]
    assert g.logical_base == DEFAULT_LOGICAL_BASE
    # outputs: 2 + 2 + 4 bits in one byte; inputs: 2 bits, then 8 bits on a new byte
    assert (g.output_bytes, g.input_bytes) == (1, 2)
    f1, f2, f3 = (cfg.slaves[p].fmmus[0] for p in (1, 2, 3))
    assert [(f.logical_start, f.logical_start_bit, f.logical_stop_bit, f.length) for f in (f1, f2, f3)] == [
        (0x10000, 0, 1, 1), (0x10000, 2, 3, 1), (0x10000, 4, 7, 1)]
    assert all(f.physical_start == 0x1100 and f.physical_start_bit == 0 for f in (f1, f2, f3))
    assert all(f.fmmu_type == reg.FmmuType.WRITE for f in (f1, f2, f3))
    f4 = cfg.slaves[4].fmmus[0]
    assert (f4.index, f4.logical_start, f4.logical_start_bit, f4.logical_stop_bit) == (1, 0x10001, 0, 1)
    assert f4.fmmu_type == reg.FmmuType.READ and f4.bit_length == 2
    f5 = cfg.slaves[5].fmmus[0]
    assert (f5.logical_start, f5.logical_start_bit, f5.logical_stop_bit, f5.length) == (0x10002, 0, 7, 1)
    # the 2-bit terminal's first input sits at bit 8 of the image
    v = cfg.slaves[4].variables
    assert [(x.name, x.bit_offset, x.bit_length) for x in v] == [("Input 1", 8, 1), ("Input 2", 9, 1)]
    # one LRW, WKC = 2 * 3 output slaves + 1 * 2 input slaves
    (d,) = g.datagrams
    assert (d.command, d.logical_address, d.length, d.expected_wkc) == (Command.LRW, 0x10000, 3, 8)
    assert (d.copy_start, d.copy_end) == (1, 3)
    assert d.positions == (1, 2, 3, 4, 5)


def test_packed_block_never_straddles_a_byte():
    cfg = configure(specs(do(3), do(3), do(3)))
    offs = [(f.logical_start - 0x10000, f.logical_start_bit) for p in range(3) for f in cfg.slaves[p].fmmus]
    assert offs == [(0, 0), (0, 3), (1, 0)]
    assert cfg.groups[0].output_bytes == 2


def test_byte_layout_gives_every_slave_whole_bytes():
    cfg = configure(specs(do(2), do(2), di(2)), [GroupSpec("io", layout="byte")])
    g = cfg.groups[0]
    assert g.layout is Layout.BYTE
    assert (g.output_bytes, g.input_bytes) == (2, 1)
    for p, (start, stop) in enumerate([(0x10000, 7), (0x10001, 7), (0x10002, 7)]):
        f = cfg.slaves[p].fmmus[0]
        assert (f.logical_start, f.logical_start_bit, f.logical_stop_bit) == (start, 0, stop)


def test_bytewise_esc_is_not_packed():
    sl = specs(do(2), do(2))
    sl[1].features = reg.Feature.FMMU_BYTE_ORIENTED
    cfg = configure(sl)
    assert cfg.slaves[1].fmmus[0].logical_start == 0x10001
    assert cfg.slaves[1].fmmus[0].logical_stop_bit == 7


def test_sync_manager_register_values():
    sii = io_sii("mixed", outputs=[("Out", 16, UINT16)], inputs=[("In", 16, INT16), ("Flag", 1, BOOL)],
                 mailbox=True)
    cfg = configure([SlaveDescription(0, 0x1001, sii)])
    sc = cfg.slaves[0]
    got = {s.index: (s.start, s.length, s.control, s.activate) for s in sc.sync_managers}
    assert got == {0: (0x1000, 128, 0x26, 1), 1: (0x1080, 128, 0x22, 1),
                   2: (0x1100, 2, 0x64, 1), 3: (0x1180, 3, 0x20, 1)}
    sm2 = sc.sync_managers[2]
    assert sm2.address == 0x0810
    assert sm2.encode() == struct.pack("<HHBBBB", 0x1100, 2, 0x64, 0, 1, 0)
    assert [a for a, _ in sc.mailbox_writes()] == [0x0800, 0x0808]
    writes = sc.process_data_writes()
    # FMMU 2 maps the SM1 status byte (0x080D) after the inputs (mailbox polling)
    assert [a for a, _ in writes] == [0x0810, 0x0818, 0x0600, 0x0610, 0x0620]
    fmmu_in = dict(writes)[0x0610]
    assert fmmu_in == struct.pack("<IHBBHBBB3x", 0x10002, 3, 0, 7, 0x1180, 0, 1, 1)
    assert dict(writes)[0x0620] == struct.pack("<IHBBHBBB3x", 0x10005, 1, 0, 7, 0x080D, 0, 1, 1)
    assert (sc.output_bits, sc.input_bits) == (16, 17)
    assert sc.mailbox_status_offset == 5
    g = cfg.groups[0]
    assert (g.output_bytes, g.input_bytes, g.status_bytes, g.size) == (2, 3, 1, 6)
    # LRW: 2 for the write FMMU, 1 for the reads (inputs and status of one slave)
    assert [(d.command, d.length, d.expected_wkc, d.copy_start, d.copy_end)
            for d in g.datagrams] == [(Command.LRW, 6, 3, 2, 6)]
    plain = configure([SlaveDescription(0, 0x1001, sii)], mailbox_status=False)
    assert plain.groups[0].size == 5 and plain.slaves[0].mailbox_status_offset == -1


def test_mailbox_status_bytes_follow_the_inputs():
    mbx_io = io_sii("mbx", outputs=[("Out", 8, UINT16)], inputs=[("In", 8, INT16)], mailbox=True)
    only_mbx = io_sii("mbx-only", mailbox=True)
    sl = [SlaveDescription(0, 0x1001, di(2)), SlaveDescription(1, 0x1002, mbx_io),
          SlaveDescription(2, 0x1003, only_mbx), SlaveDescription(3, 0x1004, mbx_io, fmmu_count=2)]
    cfg = configure(sl)
    g = cfg.groups[0]
    # outputs: 2 x 1 byte; inputs: di2 bits + 2 x 1 byte; then 2 status bytes
    assert (g.output_bytes, g.input_bytes, g.status_bytes) == (2, 3, 2)
    assert [cfg.slaves[p].mailbox_status_offset for p in range(4)] == [-1, 5, 6, -1]
    # the SII's "SyncM status" FMMU (index 2) reads 0x080D; a slave without process
    # data uses it too; the slave with only two FMMUs is polled with frames
    st = [f for f in cfg.slaves[2].fmmus if f.physical_start == 0x080D]
    assert [(f.index, f.logical_start, f.length, f.fmmu_type) for f in st] == [
        (2, 0x10006, 1, reg.FmmuType.READ)]
    assert any("mailbox status" in w for w in cfg.slaves[3].warnings)
    # WKC: writes 2 x 2, reads: di2, slave 1 (inputs + status), slave 2, slave 3
    assert [(d.length, d.expected_wkc) for d in g.datagrams] == [(7, 4 + 4)]
    # a slave whose SII reserves no FMMU for it takes a free one; LRD covers the status
    sii = io_sii("x", inputs=[("In", 8, INT16)], mailbox=True)
    sii.categories = [SiiFmmus([FmmuUsage.INPUTS]) if isinstance(c, SiiFmmus) else c
                      for c in sii.categories]
    one = configure([SlaveDescription(0, 0x1001, sii, features=reg.Feature.LRW_NOT_SUPPORTED)])
    assert [(f.index, f.physical_start) for f in one.slaves[0].fmmus] == [(0, 0x1180), (1, 0x080D)]
    d = one.groups[0].datagrams
    assert [(x.command, x.offset, x.length, x.expected_wkc) for x in d] == [(Command.LRD, 0, 2, 1)]


def test_no_lrw_slave_switches_group_to_lwr_lrd():
    sl = specs(do(8), di(8), do(2))
    sl[1].features = reg.Feature.LRW_NOT_SUPPORTED
    g = configure(sl).groups[0]
    assert not g.uses_lrw
    assert [(d.command, d.offset, d.length, d.expected_wkc) for d in g.datagrams] == [
        (Command.LWR, 0, 2, 2), (Command.LRD, 2, 1, 1)]
    assert (g.datagrams[0].copy_start, g.datagrams[0].copy_end) == (0, 0)
    assert (g.datagrams[1].copy_start, g.datagrams[1].copy_end) == (2, 3)


def test_frame_split_at_1486_bytes_on_slave_boundaries():
    # 200 slaves with 10 output bytes each = 2000 bytes: must split.
    big = io_sii("big", outputs=[(f"w{i}", 16, UINT16) for i in range(5)])
    g = configure(specs(*[big] * 200)).groups[0]
    assert g.output_bytes == 2000
    lens = [d.length for d in g.datagrams]
    assert lens == [1480, 520]
    assert all(d.length <= MAX_DATA for d in g.datagrams)
    assert [d.expected_wkc for d in g.datagrams] == [2 * 148, 2 * 52]
    assert g.datagrams[1].logical_address == 0x10000 + 1480
    assert g.expected_wkc == 400


def test_split_inside_a_block_counts_the_slave_in_both_datagrams():
    huge = io_sii("huge", inputs=[(f"w{i}", 64, 0x1B) for i in range(250)])
    g = configure(specs(huge)).groups[0]
    assert [d.length for d in g.datagrams] == [MAX_DATA, 2000 - MAX_DATA]
    assert [d.expected_wkc for d in g.datagrams] == [1, 1]


def test_groups_have_their_own_logical_base_and_images():
    sl = specs(do(8), di(8), do(4), di(4))
    cfg = configure(sl, [GroupSpec("fast", [0, 1], cycle=0.001), GroupSpec("slow", None, cycle=0.01)])
    fast, slow = cfg.groups
    assert (fast.logical_base, slow.logical_base) == (0x10000, 0x20000)
    assert [s.position for s in fast.slaves] == [0, 1]
    assert [s.position for s in slow.slaves] == [2, 3]
    assert slow.datagrams[0].logical_address == 0x20000
    assert cfg.slaves[3].fmmus[0].logical_start == 0x20001
    assert cfg.group("slow") is slow
    with pytest.raises(ConfigError, match="no process-data group named 'x'"):
        cfg.group("x")


def test_bad_group_specs_raise_config_errors():
    sl = specs(do(8), di(8))
    with pytest.raises(ConfigError, match="slave 1 is in groups"):
        configure(sl, [GroupSpec("a", [0, 1]), GroupSpec("b", [1])])
    with pytest.raises(ConfigError, match="names slave 7"):
        configure(sl, [GroupSpec("a", [7])])
    with pytest.raises(ConfigError, match="has process data but belongs to no group"):
        configure(sl, [GroupSpec("a", [0])])
    with pytest.raises(ConfigError, match="layout"):
        configure(sl, [GroupSpec("a", None, layout="diagonal")])
    with pytest.raises(ConfigError, match="overlap"):
        configure(sl, [GroupSpec("a", [0], logical_base=0x100), GroupSpec("b", [1], logical_base=0x100)])


def test_pdo_mapping_hook_replaces_sii_pdos():
    from pyethercat.master.config import MappedPdo, MappedPdoEntry

    sl = specs(io_sii("drive", outputs=[("x", 8, 5)], inputs=[("y", 8, 5)]))
    sl[0].pdo_mapping = {0: [MappedPdo(0x1601, "RxPDO", (MappedPdoEntry(0x7010, 1, 32, 7, "Target"),),
                                 PdoDirection.OUTPUTS, 0)],
                         1: [MappedPdo(0x1A01, "TxPDO", (MappedPdoEntry(0x6010, 1, 32, 7, "Actual"),
                                                   MappedPdoEntry(0, 0, 16)), PdoDirection.INPUTS, 1)]}
    cfg = configure(sl)
    assert (cfg.slaves[0].output_bits, cfg.slaves[0].input_bits) == (32, 48)
    assert [v.name for v in cfg.slaves[0].variables] == ["Target", "Actual"]


# --- real SII dumps -----------------------------------------------------------------


def _load(corpus_dir: Path, name: str):
    return parse_sii((corpus_dir / "sii" / name).read_bytes())


def test_el2004_from_corpus_is_packed_bitwise(corpus_dir: Path):
    ek, el = _load(corpus_dir, "ethercrab_ek1100.bin"), _load(corpus_dir, "ethercrab_el2004.bin")
    cfg = configure(specs(ek, el, el))
    g = cfg.groups[0]
    assert (g.output_bytes, g.input_bytes) == (1, 0)
    a, b = cfg.slaves[1], cfg.slaves[2]
    assert a.sync_managers[0].start == 0x0F00 and a.sync_managers[0].length == 1
    assert (a.fmmus[0].logical_start_bit, a.fmmus[0].logical_stop_bit) == (0, 3)
    assert (b.fmmus[0].logical_start_bit, b.fmmus[0].logical_stop_bit) == (4, 7)
    assert [v.qualified_name for v in a.variables] == [f"Channel {i}.Output" for i in range(1, 5)]
    assert g.datagrams[0].expected_wkc == 4
    # byte-aligned: one byte each
    assert configure(specs(ek, el, el), [GroupSpec("m", layout="byte")]).groups[0].output_bytes == 2


def test_el2889_contiguous_sync_managers_share_one_fmmu(corpus_dir: Path):
    cfg = configure(specs(_load(corpus_dir, "ethercrab_el2889.bin")))
    sc = cfg.slaves[0]
    assert [(s.index, s.start, s.length) for s in sc.process_data_sync_managers] == [
        (0, 0x0F00, 1), (1, 0x0F01, 1)]
    (f,) = sc.fmmus
    assert (f.length, f.physical_start, f.bit_length) == (2, 0x0F00, 16)
    assert len(sc.variables) == 16 and sc.variables[15].bit_offset == 15


def test_every_corpus_sii_configures_without_error(corpus_dir: Path):
    for path in sorted((corpus_dir / "sii").glob("*.bin")):
        sii = parse_sii(path.read_bytes())
        cfg = configure([SlaveDescription(0, 0x1001, sii)])
        g = cfg.groups[0]
        for d in g.datagrams:
            assert d.length <= MAX_DATA
        sc = cfg.slaves[0]
        assert g.output_bytes == sc.output_bytes and g.input_bytes >= 0, path.name
