"""Unit tests of the ESI parser and model on small hand-written documents."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pyethercat.errors import EsiError
from pyethercat.esi import (
    EsiDevice,
    Text,
    parse_bool,
    parse_esi,
    parse_hex_bytes,
    parse_int,
    type_info,
)
from pyethercat.wire.mailbox.datatypes import DataType

DRIVE = """<?xml version="1.0" encoding="ISO-8859-1"?>
<!-- a comment before the root -->
<EtherCATInfo Version="1.6">
  <Vendor FileVersion="3">
    <Id>#x000000E4</Id>
    <Name LcId="1033">Metronix</Name>
    <ImageData16x14>424D
      E600</ImageData16x14>
  </Vendor>
  <Descriptions>
    <Groups>
      <Group SortOrder="1">
        <Type>Drives</Type>
        <Name LcId="1033">Drives</Name>
        <Name LcId="1031">Antriebe</Name>
      </Group>
    </Groups>
    <Devices>
      <Device Physics="YY">
        <Type ProductCode="4660" RevisionNo="0x00000002" CheckRevisionNo="EQ_OR_G">Drive</Type>
        <Name LcId="1033">Servo drive</Name>
        <Name LcId="1031">Servoregler \xb5s</Name>
        <Info>
          <Electrical><EBusCurrent>0</EBusCurrent></Electrical>
          <Mailbox><Timeout><RequestTimeout>100</RequestTimeout><ResponseTimeout>2000</ResponseTimeout></Timeout></Mailbox>
        </Info>
        <GroupType>Drives</GroupType>
        <Fmmu>Outputs</Fmmu>
        <Fmmu>Inputs</Fmmu>
        <Fmmu>MBoxState</Fmmu>
        <Sm MinSize="34" MaxSize="256" DefaultSize="128" StartAddress="#x1800" ControlByte="#x26" Enable="1">MBoxOut</Sm>
        <Sm MinSize="34" MaxSize="256" DefaultSize="192" StartAddress="#x1c00" ControlByte="#x22" Enable="true">MBoxIn</Sm>
        <Sm StartAddress="#x1100" ControlByte="#x64" Enable="1">Outputs</Sm>
        <Sm StartAddress="#x1400" ControlByte="#x20" Enable="1">Inputs</Sm>
        <RxPdo Fixed="1" Mandatory="true" Sm="2">
          <Index>#x1600</Index>
          <Name>Outputs</Name>
          <Entry><Index>#x6040</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name><DataType>UINT</DataType></Entry>
          <Entry><Index>#x6060</Index><SubIndex>0</SubIndex><BitLen>8</BitLen><Name>Mode_Of_Operation</Name><DataType>USINT</DataType></Entry>
          <Entry><Index>0</Index><BitLen>8</BitLen></Entry>
        </RxPdo>
        <RxPdo Sm="2">
          <Index>#x1601</Index>
          <Name>Position</Name>
          <Exclude>#x1602</Exclude>
          <Entry><Index>#x607A</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><DataType>DINT</DataType></Entry>
        </RxPdo>
        <RxPdo Sm="2">
          <Index>#x1602</Index>
          <Name>Velocity</Name>
          <Exclude>#x1601</Exclude>
          <Entry><Index>#x60FF</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><DataType>DINT</DataType></Entry>
        </RxPdo>
        <RxPdo>
          <Index>#x1603</Index>
          <Name>Torque (optional)</Name>
          <Entry><Index>#x6071</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><DataType>INT</DataType></Entry>
        </RxPdo>
        <TxPdo Fixed="1" Sm="3">
          <Index>#x1a00</Index>
          <Name>Inputs</Name>
          <Entry><Index>#x6041</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><DataType>UINT</DataType></Entry>
          <Entry><Index>#x6064</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><DataType>DINT</DataType></Entry>
          <Entry><Index>#x60FD</Index><SubIndex>0</SubIndex><BitLen>2</BitLen><DataType>BIT2</DataType></Entry>
        </TxPdo>
        <TxPdo>
          <Index>#x1a01</Index>
          <Name>Velocity actual</Name>
          <Entry><Index>#x606C</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><DataType>DINT</DataType></Entry>
        </TxPdo>
        <Mailbox DataLinkLayer="true">
          <CoE SdoInfo="true" PdoAssign="1" PdoConfig="false" CompleteAccess="true" SegmentedSdo="true">
            <InitCmd>
              <Transition>PS</Transition>
              <Index>#x6060</Index>
              <SubIndex>0</SubIndex>
              <Data>03</Data>
              <Comment>velocity mode</Comment>
            </InitCmd>
            <InitCmd CompleteAccess="1">
              <Transition>PS</Transition>
              <Transition>SO</Transition>
              <Index>7186</Index>
              <SubIndex>0</SubIndex>
              <Data>0100 0016</Data>
            </InitCmd>
            <EdsFile>drive.eds</EdsFile>
          </CoE>
          <EoE IP="true" MAC="1"/>
          <FoE/>
        </Mailbox>
        <Dc>
          <OpMode>
            <Name>DC</Name>
            <Desc>DC-Synchron</Desc>
            <AssignActivate>#x0300</AssignActivate>
            <CycleTimeSync0 Factor="1">0</CycleTimeSync0>
            <ShiftTimeSync0>250000</ShiftTimeSync0>
            <CycleTimeSync1 Factor="-1">0</CycleTimeSync1>
            <ShiftTimeSync1>0</ShiftTimeSync1>
            <Sm No="2"><Pdo>#x1600</Pdo><Pdo>#x1602</Pdo></Sm>
            <Sm No="3"><Pdo OSFac="1">#x1a00</Pdo><Pdo>#x1a01</Pdo></Sm>
          </OpMode>
          <OpMode>
            <Name>FreeRun</Name>
            <Desc>SM-Synchron</Desc>
            <AssignActivate>#x0</AssignActivate>
          </OpMode>
        </Dc>
        <Eeprom>
          <ByteSize>4096</ByteSize>
          <ConfigData>080E00CC0A00</ConfigData>
          <BootStrap>0018000100180001</BootStrap>
          <Category><CatNo>100</CatNo><Data>0102</Data></Category>
        </Eeprom>
        <Profile>
          <ProfileNo>402</ProfileNo>
          <Dictionary>
            <DataTypes>
              <DataType><Name>UDINT</Name><BitSize>32</BitSize></DataType>
              <DataType><Name>DT1C12ARR</Name><BaseType>UINT</BaseType><BitSize>32</BitSize>
                <ArrayInfo><LBound>1</LBound><Elements>2</Elements></ArrayInfo></DataType>
              <DataType><Name>DT1C12</Name><BitSize>48</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs>
                  <Flags><Access>rw</Access></Flags></SubItem>
                <SubItem><Name>Elements</Name><Type>DT1C12ARR</Type><BitSize>32</BitSize><BitOffs>16</BitOffs>
                  <Flags><Access WriteRestrictions="PreOP">rw</Access></Flags></SubItem>
              </DataType>
            </DataTypes>
            <Objects>
              <Object>
                <Index>#x1000</Index><Name>Device type</Name><Type>UDINT</Type><BitSize>32</BitSize>
                <Info><DefaultData>92010200</DefaultData></Info>
                <Flags><Access>ro</Access><Category>m</Category></Flags>
              </Object>
              <Object>
                <Index>#x1C12</Index><Name>RxPDO assign</Name><Type>DT1C12</Type><BitSize>48</BitSize>
                <Info>
                  <SubItem><Name>SubIndex 000</Name><Info><DefaultData>01</DefaultData></Info></SubItem>
                  <SubItem><Name>SubIndex 001</Name><Info><DefaultData>0016</DefaultData></Info></SubItem>
                  <SubItem><Name>SubIndex 002</Name><Info><DefaultData>0000</DefaultData></Info></SubItem>
                </Info>
              </Object>
              <Object>
                <Index>#x6041</Index><Name>Statusword</Name><Type>UINT</Type><BitSize>16</BitSize>
                <Flags><Access>ro</Access><PdoMapping>T</PdoMapping><Backup>0</Backup></Flags>
              </Object>
            </Objects>
          </Dictionary>
        </Profile>
      </Device>
    </Devices>
  </Descriptions>
</EtherCATInfo>
""".encode("latin-1")


@pytest.fixture(scope="module")
def drive() -> EsiDevice:
    return parse_esi(DRIVE, "drive.xml").find_device(0x1234)


def test_file_level() -> None:
    esi = parse_esi(DRIVE, "drive.xml")
    assert esi.source == "drive.xml" and esi.version == "1.6"
    assert esi.vendor.id == 0xE4 and str(esi.vendor.name) == "Metronix"
    assert esi.vendor.file_version == 3 and esi.vendor.image == bytes.fromhex("424DE600")
    g = esi.group("Drives")
    assert g is not None and g.sort_order == 1 and g.name.pick(1031) == "Antriebe"
    with pytest.raises(EsiError, match="no device with product code 0x00001235"):
        esi.find_device(0x1235)
    with pytest.raises(EsiError, match="revision 0x00000003"):
        esi.find_device(0x1234, 3)


def test_identity_and_names(drive: EsiDevice) -> None:
    assert drive.identity == (0x1234, 2)
    assert drive.check_revision == "EQ_OR_G" and drive.physics == "YY"
    assert drive.name.pick(1031) == "Servoregler \u00b5s"  # ISO-8859-1 decoded
    assert drive.name.pick(1036) == "Servo drive"  # French absent: English
    assert drive.info.request_timeout == 100 and drive.info.response_timeout == 2000
    assert drive.info.ebus_current == 0


def test_sms_fmmus_mailbox(drive: EsiDevice) -> None:
    assert [(s.start_address, s.control_byte, s.kind) for s in drive.sms] == [
        (0x1800, 0x26, "MBoxOut"),
        (0x1C00, 0x22, "MBoxIn"),
        (0x1100, 0x64, "Outputs"),
        (0x1400, 0x20, "Inputs"),
    ]
    assert drive.sms[0].min_size == 34 and drive.sms[0].max_size == 256 and drive.sms[1].enable
    assert drive.mailbox_sizes == (128, 192)
    assert [f.name for f in drive.fmmus] == ["Outputs", "Inputs", "MBoxState"]
    mb = drive.mailbox
    assert mb is not None and mb.protocols == ("CoE", "EoE", "FoE") and mb.data_link_layer
    assert mb.eoe is not None and mb.eoe.ip and mb.eoe.mac and not mb.eoe.time_stamp
    coe = mb.coe
    assert coe is not None
    assert coe.sdo_info and coe.pdo_assign and not coe.pdo_config and coe.complete_access
    assert coe.segmented_sdo and not coe.pdo_upload and coe.eds_file == "drive.eds"
    c0, c1 = coe.init_cmds
    assert (c0.transitions, c0.index, c0.subindex, c0.data, c0.comment) == (
        ("PS",),
        0x6060,
        0,
        b"\x03",
        "velocity mode",
    )
    assert c1.transitions == ("PS", "SO") and c1.index == 0x1C12 and c1.complete_access
    assert c1.data == bytes.fromhex("01000016")


def test_pdos(drive: EsiDevice) -> None:
    p = drive.rx_pdos[0]
    assert p.index == 0x1600 and p.fixed and p.mandatory and p.sm == 2
    assert p.bit_size == 32 and p.entries[2].is_padding and p.entries[2].subindex == 0
    e = p.entries[0]
    assert e.mapping == 0x60400010 and str(e.name) == "Controlword"
    assert e.type_info is not None and e.type_info.code == DataType.UNSIGNED16
    assert drive.tx_pdos[0].entries[2].type_info is not None
    assert drive.tx_pdos[0].entries[2].type_info.bit_size == 2


def test_default_layout_honours_exclude(drive: EsiDevice) -> None:
    # 0x1600 mandatory; 0x1601 default; 0x1602 excluded by 0x1601; 0x1603 optional.
    assert [p.index for p in drive.default_pdos("rx")] == [0x1600, 0x1601]
    assert [p.index for p in drive.default_pdos("tx")] == [0x1A00]
    layout = drive.pdo_layout()
    assert [s.sm.index for s in layout.sms] == [2, 3]
    sm2, sm3 = layout.for_sm(2), layout.for_sm(3)
    assert sm2 is not None and sm2.pdo_indices == (0x1600, 0x1601) and sm2.bit_size == 64
    assert sm3 is not None and sm3.bit_size == 50 and sm3.byte_size == 7
    assert layout.output_bits == 64 and layout.input_bits == 50


def test_layout_from_op_mode_and_explicit_assignment(drive: EsiDevice) -> None:
    layout = drive.pdo_layout(op_mode="dc")
    sm2, sm3 = layout.for_sm(2), layout.for_sm(3)
    assert sm2 is not None and sm2.pdo_indices == (0x1600, 0x1602)
    assert sm3 is not None and sm3.pdo_indices == (0x1A00, 0x1A01) and sm3.bit_size == 82
    custom = drive.pdo_layout(assignment={2: (0x1603,)})
    sm2 = custom.for_sm(2)
    assert sm2 is not None and sm2.bit_size == 16
    with pytest.raises(EsiError, match="no DC op mode named 'Sync1'"):
        drive.pdo_layout(op_mode="Sync1")
    with pytest.raises(EsiError, match="PDO 0x1700"):
        drive.pdo_layout(assignment={2: (0x1700,)})
    with pytest.raises(EsiError, match="SM9"):
        drive.pdo_layout(assignment={9: (0x1600,)})


def test_dc_and_eeprom(drive: EsiDevice) -> None:
    assert drive.dc is not None
    dc, free = drive.dc.op_modes
    assert dc.assign_activate == 0x0300 and dc.desc == "DC-Synchron"
    assert dc.cycle_time_sync0 == 0 and dc.cycle_time_sync0_factor == 1
    assert dc.shift_time_sync0 == 250000 and not dc.shift_time_sync0_input
    assert dc.cycle_time_sync1_factor == -1 and dc.shift_time_sync1 == 0
    assert dc.sm_pdos == ((2, (0x1600, 0x1602)), (3, (0x1A00, 0x1A01)))
    assert free.assign_activate == 0 and free.cycle_time_sync0 is None
    ee = drive.eeprom
    assert ee is not None and ee.byte_size == 4096
    assert ee.config_data == bytes.fromhex("080E00CC0A00")
    assert ee.bootstrap == bytes.fromhex("0018000100180001")
    assert ee.categories == ((100, b"\x01\x02"),)


def test_dictionary(drive: EsiDevice) -> None:
    assert drive.profiles[0].profile_no == (402,)
    d = drive.dictionary
    assert d is not None
    o1000 = d.object(0x1000)
    assert o1000 is not None and o1000.info.default_data == bytes.fromhex("92010200")
    assert o1000.flags.access == "ro" and o1000.flags.category == "m" and not o1000.flags.writable
    [e] = d.entries(o1000)
    assert (e.subindex, e.code, e.bit_size) == (0, DataType.UNSIGNED32, 32)
    o1c12 = d.object(0x1C12)
    assert o1c12 is not None
    flat = d.entries(o1c12)
    assert [(x.subindex, x.type, x.bit_size) for x in flat] == [
        (0, "USINT", 8),
        (1, "UINT", 16),
        (2, "UINT", 16),
    ]
    assert flat[1].default == bytes.fromhex("0016") and flat[1].name == "SubIndex 001"
    assert flat[1].flags.write_restrictions == "PreOP"
    arr = d.type_info("DT1C12ARR")
    assert arr is not None and arr.code == DataType.UNSIGNED16 and arr.count == 2
    sw = d.object(0x6041)
    assert sw is not None and sw.flags.tx_mappable and not sw.flags.rx_mappable


def test_namespaced_elements_and_comments() -> None:
    doc = b"""<?xml version="1.0"?>
<e:EtherCATInfo xmlns:e="urn:x"><!-- c --><e:Vendor><e:Id>#x9</e:Id><?pi x?></e:Vendor>
<e:Descriptions><e:Devices><e:Device><!-- c --><e:Type ProductCode="#x9252">L</e:Type>
</e:Device></e:Devices></e:Descriptions></e:EtherCATInfo>"""
    esi = parse_esi(doc)
    assert esi.vendor.id == 9 and esi.devices[0].product_code == 0x9252
    assert esi.devices[0].revision == 0  # RevisionNo missing
    assert esi.devices[0].pdo_layout().sms == ()


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("#x1600", 0x1600),
        ("0x1600", 0x1600),
        ("5632", 5632),
        ("#x00000002", 2),
        ("#X1a", 0x1A),
        ("  #xF3F\n", 0xF3F),
        ("#x0x6041", 0x6041),
        ("-1", -1),
        ("0", 0),
    ],
)
def test_parse_int(text: str, value: int) -> None:
    assert parse_int(text) == value


@pytest.mark.parametrize("text", ["", "x", "#x", "0x", "1.5", "1_000", "#xG", "12a", None])
def test_parse_int_rejects(text: str | None) -> None:
    with pytest.raises(ValueError):
        parse_int(text)


@given(st.integers(min_value=0, max_value=2**64))
def test_parse_int_roundtrip(n: int) -> None:
    assert parse_int(f"#x{n:X}") == n
    assert parse_int(f"0x{n:08x}") == n
    assert parse_int(str(n)) == n


@given(st.binary(max_size=64))
def test_parse_hex_roundtrip(data: bytes) -> None:
    text = data.hex()
    spaced = " ".join(text[i : i + 4] for i in range(0, len(text), 4))
    assert parse_hex_bytes(text) == data
    assert parse_hex_bytes(spaced.upper()) == data


def test_parse_bool() -> None:
    assert parse_bool("true") and parse_bool(" 1 ") and parse_bool("True")
    assert not parse_bool("false") and not parse_bool("0")
    with pytest.raises(ValueError):
        parse_bool("yes")


def test_text_pick() -> None:
    t = Text(((1031, "Eingang"), (1033, "Input")))
    assert t.pick(1031) == "Eingang" and t.pick() == "Input" and str(t) == "Input"
    assert Text(((1031, "Eingang"),)).pick() == "Eingang"
    assert Text(((None, "plain"), (1031, "de"))).pick(1036) == "plain"
    assert Text().pick() == "" and not Text()


@pytest.mark.parametrize(
    ("name", "code", "bits"),
    [
        ("BOOL", DataType.BOOLEAN, 1),
        ("BIT2", DataType.BIT2, 2),
        ("BIT8", DataType.BIT8, 8),
        ("USINT", DataType.UNSIGNED8, 8),
        ("SINT", DataType.INTEGER8, 8),
        ("UINT", DataType.UNSIGNED16, 16),
        ("INT", DataType.INTEGER16, 16),
        ("UDINT", DataType.UNSIGNED32, 32),
        ("DINT", DataType.INTEGER32, 32),
        ("ULINT", DataType.UNSIGNED64, 64),
        ("LINT", DataType.INTEGER64, 64),
        ("REAL", DataType.REAL32, 32),
        ("LREAL", DataType.REAL64, 64),
        ("BYTE", DataType.BYTE, 8),
        ("UINT16", DataType.UNSIGNED16, 16),
        ("STRING(10)", DataType.VISIBLE_STRING, 80),
        ("ARRAY [0..3] OF UINT", DataType.UNSIGNED16, 64),
        ("ARRAY [1..2] OF STRING(3)", DataType.VISIBLE_STRING, 48),
    ],
)
def test_type_info(name: str, code: DataType, bits: int) -> None:
    info = type_info(name)
    assert info is not None and info.code == code and info.bit_size == bits


def test_type_info_unknown() -> None:
    assert type_info("DT1018") is None
    assert type_info("ARRAY [3..1] OF UINT") is None
    assert type_info("ARRAY [0..1] OF NOPE") is None


def test_type_cycle_in_dictionary_does_not_recurse_forever() -> None:
    from pyethercat.esi import EsiDataType, EsiDictionary

    d = EsiDictionary(
        data_types={
            "A": EsiDataType(name="A", bit_size=8, base_type="B"),
            "B": EsiDataType(name="B", bit_size=8, base_type="A"),
        }
    )
    assert d.type_info("A") is None


def _with_transition(text: str) -> bytes:
    return DRIVE.replace(b"<Transition>SO</Transition>", f"<Transition>{text}</Transition>".encode())


def test_init_cmd_transitions_are_checked_against_the_state_machine() -> None:
    coe = parse_esi(_with_transition("sp")).find_device(0x1234).mailbox.coe  # type: ignore[union-attr]
    assert coe is not None and coe.init_cmds[1].transitions == ("PS", "SP")
    # PREOP -> OP is no transition of the EtherCAT state machine: the file is wrong.
    with pytest.raises(EsiError, match=r"drive.xml:\d+: CoE/InitCmd/Transition: 'PO' is no state transition"):
        parse_esi(_with_transition("PO"), "drive.xml")
