"""ENI export/import: round trips, ESI -> ENI -> device model -> SII, safety, errors."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pyethercat.errors import EsiError
from pyethercat.esi import load_esi
from pyethercat.esi.bundled import bundled_esi
from pyethercat.esi.eni import (
    EniCmd,
    EniConfig,
    EniDc,
    EniFrame,
    EniInitCmd,
    EniMailbox,
    EniPdo,
    EniPdoEntry,
    EniSlave,
    EniSm,
    EniVariable,
    build_eni,
    eni_slave_device,
    eni_slave_from_esi,
    load_eni,
    parse_eni,
)
from pyethercat.esi.sii_from_esi import esi_to_sii


def _seed_slave(position: int = 0) -> EniSlave:
    esi = load_esi(bundled_esi())
    return eni_slave_from_esi(
        esi.devices[0], vendor_id=esi.vendor.id, position=position,
        station_address=0x1001 + position,
    )  # fmt: skip


def test_seed_drive_slave_from_esi() -> None:
    s = _seed_slave()
    assert (s.vendor_id, s.product_code, s.revision) == (0xE4, 0x264860D2, 0x20000)
    assert s.assignment() == {2: (0x1600,), 3: (0x1A00,)}
    assert [x.size for x in s.sms] == [128, 128, 3, 7]
    assert s.mailbox is not None and s.mailbox.protocols == ("CoE",)
    assert [(c.index, c.data) for c in s.mailbox.init_cmds] == [(0x6040, b"\0\0"), (0x6060, b"\3")]
    assert s.dc == EniDc(op_mode="Synchron", assign_activate=0)
    dc = eni_slave_from_esi(
        load_esi(bundled_esi()).devices[0], vendor_id=0xE4, position=0, station_address=1,
        op_mode="DC", assignment={3: (0x1A00, 0x1A01)},
    )  # fmt: skip
    assert dc.dc is not None and dc.dc.assign_activate == 0x300
    assert dc.assignment()[3] == (0x1A00, 0x1A01) and dc.sms[3].size == 11


def _full_config() -> EniConfig:
    slaves = [_seed_slave(i) for i in range(3)]
    slaves[1] = EniSlave(
        name="io", position=1, station_address=0x1002, vendor_id=2, product_code=0x3EC3052,
        revision=0x130000, serial=7, alias=0x55, physics="KK",
        sms=(EniSm(index=0, kind="Inputs", start=0x1000, size=1, control=0, pdos=(0x1A00,)),),
        fmmus=("Inputs",),
        tx_pdos=(EniPdo(direction="tx", index=0x1A00, name="Ch1", sm=0, fixed=True,
                        entries=(EniPdoEntry(index=0x6000, subindex=1, bit_len=1, name="In",
                                             data_type="BOOL"),
                                 EniPdoEntry(index=0, subindex=0, bit_len=7))),),
        recv_bit_start=24, recv_bit_length=1,
    )  # fmt: skip
    return EniConfig(
        master_name="test", source=bytes.fromhex("020000000001"), slaves=tuple(slaves),
        cycle_time_us=1000,
        frames=(EniFrame(cmds=(EniCmd(states=("SAFEOP", "OP"), cmd=12, addr=0x10000,
                                      data_length=20, cnt=7, input_offs=26, output_offs=26,
                                      comment="LRW"),)),),
        input_bytes=10, output_bytes=6,
        inputs=(EniVariable(name="io.In", data_type="BOOL", bit_size=1, bit_offs=24),),
        outputs=(EniVariable(name="drive.Controlword", data_type="UINT", bit_size=16,
                             bit_offs=0),),
    )  # fmt: skip


def test_round_trip_full_config() -> None:
    cfg = _full_config()
    xml = build_eni(cfg)
    assert xml.startswith(b"<?xml") and b"<EtherCATConfig" in xml
    assert parse_eni(xml, "x.xml") == cfg
    # And once more: the XML is stable.
    assert build_eni(parse_eni(xml)) == xml


def test_round_trip_every_corpus_device(corpus_dir: Path) -> None:
    for f in sorted((corpus_dir / "esi").glob("*.xml")):
        if f.name.startswith("beckhoff"):
            continue  # 155 devices: covered by the benchmark; one device below
        esi = load_esi(f)
        slaves = tuple(
            eni_slave_from_esi(d, vendor_id=esi.vendor.id, position=i, station_address=0x1001 + i)
            for i, d in enumerate(esi.devices)
        )
        cfg = EniConfig(slaves=slaves)
        assert parse_eni(build_eni(cfg), f.name) == cfg, f.name


def test_device_model_from_eni_gives_the_same_sii_content() -> None:
    esi = load_esi(bundled_esi())
    dev = esi.devices[0]
    direct = esi_to_sii(dev, vendor_id=esi.vendor.id).info
    via = esi_to_sii(eni_slave_device(parse_eni(build_eni(EniConfig(slaves=(_seed_slave(),)))).slaves[0]),
                     vendor_id=esi.vendor.id).info  # fmt: skip
    assert (via.vendor_id, via.product_code, via.revision) == (0xE4, 0x264860D2, 0x20000)
    assert (via.rx_mailbox_offset, via.rx_mailbox_size, via.tx_mailbox_offset) == (
        direct.rx_mailbox_offset, direct.rx_mailbox_size, direct.tx_mailbox_offset,
    )  # fmt: skip
    assert via.mailbox_protocols == direct.mailbox_protocols
    assert [(s.start, s.length, s.control, s.sm_type) for s in via.sync_managers] == [
        (s.start, s.length, s.control, s.sm_type) for s in direct.sync_managers
    ]
    assert via.fmmus == direct.fmmus
    for a, b in ((via.rx_pdos, direct.rx_pdos), (via.tx_pdos, direct.tx_pdos)):
        assert [(p.index, p.sync_manager, [(e.index, e.subindex, e.bit_length, e.data_type)
                                           for e in p.entries]) for p in a] == \
               [(p.index, p.sync_manager, [(e.index, e.subindex, e.bit_length, e.data_type)
                                           for e in p.entries]) for p in b]  # fmt: skip
    assert (via.output_bits, via.input_bits) == (24, 56)


def test_load_eni_file(tmp_path: Path) -> None:
    p = tmp_path / "net.xml"
    p.write_bytes(build_eni(_full_config()))
    assert load_eni(p) == _full_config()
    with pytest.raises(EsiError, match="cannot read"):
        load_eni(tmp_path / "missing.xml")
    # Like load_esi: the size is checked before the file is read.
    with pytest.raises(EsiError, match=r"net\.xml: file is \d+ bytes, more than the limit of 100"):
        load_eni(p, max_bytes=100)


@pytest.mark.parametrize(
    ("xml", "message"),
    [
        (b"<EtherCATConfig><Config><Slave><Info><PhysAddr>1</PhysAddr></Info></Slave>"
         b"</Config></EtherCATConfig>", r"x.xml:1: Slave/Info: missing <VendorId>"),
        (b"<Foo/>", "not <EtherCATConfig>"),
        (b"<EtherCATConfig><Config>", "malformed XML"),
        (b"", "empty"),
        (b'<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY a "b">]>\n<EtherCATConfig/>',
         "DTD"),
        (b"<EtherCATConfig><Config><Slave><Info><PhysAddr>x1</PhysAddr></Info></Slave>"
         b"</Config></EtherCATConfig>", "PhysAddr: 'x1' is not a number"),
    ],
)  # fmt: skip
def test_bad_eni_is_a_clear_error(xml: bytes, message: str) -> None:
    with pytest.raises(EsiError, match=message):
        parse_eni(xml, "x.xml")


_names = st.text(st.characters(codec="ascii", categories=("L", "N")), max_size=12)
_u16 = st.integers(0, 0xFFFF)
_u32 = st.integers(0, 0xFFFFFFFF)


@st.composite
def _slaves(draw: st.DrawFn) -> EniSlave:
    entries = st.builds(EniPdoEntry, index=_u16, subindex=st.integers(0, 255),
                        bit_len=st.integers(1, 64), name=_names,
                        data_type=st.sampled_from([None, "UINT", "BOOL"]))  # fmt: skip
    pdo = st.builds(EniPdo, direction=st.sampled_from(["rx", "tx"]), index=_u16, name=_names,
                    sm=st.none() | st.integers(0, 7), fixed=st.booleans(),
                    mandatory=st.booleans(), entries=st.tuples(entries, entries))  # fmt: skip
    pdos = draw(st.lists(pdo, max_size=3))
    cmd = st.builds(EniInitCmd, transitions=st.tuples(st.sampled_from(["PS", "IP", "SO"])),
                    index=_u16, subindex=st.integers(0, 255), data=st.binary(max_size=8),
                    comment=_names, complete_access=st.booleans())  # fmt: skip
    mbx = st.none() | st.builds(EniMailbox, out_start=_u16, out_size=_u16, in_start=_u16,
                                in_size=_u16, protocols=st.tuples(st.sampled_from(["CoE", "FoE"])),
                                data_link_layer=st.booleans(),
                                poll_time_ms=st.none() | st.integers(0, 100),
                                init_cmds=st.lists(cmd, max_size=2).map(tuple))  # fmt: skip
    return EniSlave(
        name=draw(_names), position=draw(st.integers(0, 0xFFFF)), station_address=draw(_u16),
        vendor_id=draw(_u32), product_code=draw(_u32), revision=draw(_u32),
        serial=draw(st.none() | _u32), alias=draw(st.none() | _u16),
        sms=tuple(EniSm(index=i, kind=k, start=draw(_u16), size=draw(_u16),
                        control=draw(st.integers(0, 255)), enable=draw(st.booleans()),
                        pdos=tuple(draw(st.lists(_u16, max_size=2))))
                  for i, k in enumerate(draw(st.lists(st.sampled_from(
                      ["MBoxOut", "MBoxIn", "Outputs", "Inputs", "Unused"]), max_size=4)))),
        fmmus=tuple(draw(st.lists(st.sampled_from(["Outputs", "Inputs", "MBoxState"]),
                                  max_size=3))),
        rx_pdos=tuple(p for p in pdos if p.direction == "rx"),
        tx_pdos=tuple(p for p in pdos if p.direction == "tx"),
        mailbox=draw(mbx),
        dc=draw(st.none() | st.builds(EniDc, op_mode=_names, assign_activate=_u16,
                                      cycle_time0=_u32, shift_time0=st.integers(-10**6, 10**6))),
        send_bit_start=draw(st.none() | st.integers(0, 10**6)),
        send_bit_length=0,
    )  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(st.lists(_slaves(), max_size=3))
def test_round_trip_property(slaves: list[EniSlave]) -> None:
    cfg = EniConfig(slaves=tuple(slaves))
    assert parse_eni(build_eni(cfg)) == cfg
