"""Built-in simulated devices: their generated SII images, read back with the SII codec."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from pyethercat.errors import ConfigError
from pyethercat.sim.coe import coe_server
from pyethercat.sim.devices import (
    DEVICES,
    VENDOR_ID,
    DeviceRegistry,
    MailboxErrorApp,
    behaviour,
    get_builtin,
)
from pyethercat.sim.devices.builtin import BuiltinDevice
from pyethercat.sim.devices.coe_io import CoeIoModel
from pyethercat.sim.model import DeviceModel
from pyethercat.wire.mailbox.header import (
    MailboxErrorCode,
    MailboxType,
    decode_mailbox,
    decode_mailbox_error,
    encode_mailbox,
)
from pyethercat.wire.sii import (
    FmmuUsage,
    SiiPortType,
    SyncManagerType,
    parse_sii,
    sii_crc,
)


@pytest.mark.parametrize("key", sorted(DEVICES))
def test_image_parses_strictly_with_identity(key: str) -> None:
    dev = DEVICES[key]
    image = dev.sii_image(serial=7)
    assert len(image) == 2048  # word 0x3E = 15 -> 16 Kbit
    info = parse_sii(image, strict=True)
    assert info.checksum_ok and info.end_marker and not info.warnings
    assert image[14] == sii_crc(image[:14]) and image[15] == 0
    assert (info.vendor_id, info.product_code, info.revision, info.serial) == (
        dev.vendor_id,
        dev.product_code,
        dev.revision,
        7,
    )
    assert info.device_name == dev.name
    assert info.order_number == dev.order
    assert info.strings[0] == dev.order.encode()  # string 1: what SOEM shows as the name
    assert info.input_bits == dev.input_bits
    assert info.output_bits == dev.output_bits
    # Image bytes 0x10/0x14 hold vendor id/product code, little endian.
    assert struct.unpack_from("<II", image, 0x10) == (dev.vendor_id, dev.product_code)


def test_vendor_id_is_pec_ascii() -> None:
    assert VENDOR_ID.to_bytes(4, "big")[1:] == b"PEC"


IO_DEVICES = ("coupler", "di8", "do8", "di2", "ai2")


def test_io_builtins_carry_our_vendor_id() -> None:
    for key in IO_DEVICES:
        assert parse_sii(DEVICES[key].sii_image()).vendor_id == VENDOR_ID
        assert DEVICES[key].revision == 0x00010000


def test_process_data_sizes() -> None:
    assert {k: (DEVICES[k].input_bits, DEVICES[k].output_bits) for k in IO_DEVICES} == {
        "coupler": (0, 0),
        "di8": (8, 0),
        "do8": (0, 8),
        "di2": (2, 0),
        "ai2": (32, 0),
    }


def test_coupler_has_four_ports_and_no_process_data() -> None:
    info = parse_sii(DEVICES["coupler"].sii_image())
    assert info.general is not None
    assert info.general.ports == (SiiPortType.MII, SiiPortType.EBUS, SiiPortType.MII, SiiPortType.MII)
    assert info.sync_managers == [] and info.fmmus == []
    assert info.general.ebus_current_ma < 0  # it feeds the E-Bus


def test_digital_terminals_are_mailbox_less_like_el1xxx_el2xxx() -> None:
    for key, sm_type, usage in (
        ("di8", SyncManagerType.INPUTS, FmmuUsage.INPUTS),
        ("di2", SyncManagerType.INPUTS, FmmuUsage.INPUTS),
        ("do8", SyncManagerType.OUTPUTS, FmmuUsage.OUTPUTS),
    ):
        info = parse_sii(DEVICES[key].sii_image())
        assert info.rx_mailbox_size == 0 and info.tx_mailbox_size == 0
        (sm0,) = info.sync_managers
        assert sm0.sm_type == sm_type and sm0.start == 0x1000 and sm0.length == 1
        assert sm0.enabled
        assert info.fmmus[0] == usage
        # one PDO per channel on SM0, as Beckhoff's images have
        pdos = info.tx_pdos if sm_type == SyncManagerType.INPUTS else info.rx_pdos
        assert all(p.sync_manager == 0 and len(p.entries) == 1 for p in pdos)


def test_di2_is_two_bits() -> None:
    info = parse_sii(DEVICES["di2"].sii_image())
    assert [p.index for p in info.tx_pdos] == [0x1A00, 0x1A01]
    assert [e.bit_length for p in info.tx_pdos for e in p.entries] == [1, 1]
    assert [(e.index, e.subindex) for p in info.tx_pdos for e in p.entries] == [
        (0x6000, 1),
        (0x6010, 1),
    ]


def test_ai2_has_standard_mailbox_and_inputs_on_sm3() -> None:
    info = parse_sii(DEVICES["ai2"].sii_image())
    assert (info.rx_mailbox_offset, info.rx_mailbox_size) == (0x1000, 128)
    assert (info.tx_mailbox_offset, info.tx_mailbox_size) == (0x1080, 128)
    types = [s.sm_type for s in info.sync_managers]
    assert types == [
        SyncManagerType.MAILBOX_OUT,
        SyncManagerType.MAILBOX_IN,
        SyncManagerType.OUTPUTS,
        SyncManagerType.INPUTS,
    ]
    sm0, sm1, sm2, sm3 = info.sync_managers
    assert (sm0.control, sm1.control) == (0x26, 0x22)
    assert sm2.length == 0 and not sm2.enabled
    assert sm3.length == 4 and sm3.start == 0x1180
    assert [e.bit_length for p in info.tx_pdos for e in p.entries] == [16, 16]
    assert all(p.sync_manager == 3 for p in info.tx_pdos)
    # SM buffers fit the ET1200's 1 KiB of process RAM (3 buffers for SM3).
    assert sm3.start + 3 * sm3.length <= 0x1000 + 1024


def test_strings_are_shared_not_repeated() -> None:
    info = parse_sii(DEVICES["di8"].sii_image())
    assert info.strings.count(b"Input") == 1


def test_unknown_builtin_names_the_choices() -> None:
    with pytest.raises(ConfigError, match="choose one of ai2, .*coupler, di2, di8, do8"):
        get_builtin("di16")


class _FakePdi:
    def __init__(self) -> None:
        self.posted: list[bytes] = []

    def post_mailbox(self, data: bytes) -> bool:
        self.posted.append(data)
        return True


def test_what_each_kind_runs() -> None:
    di8 = DEVICES["di8"]
    assert behaviour(di8, parse_sii(di8.sii_image())).app is None  # plain IO: nothing runs
    ai2 = DEVICES["ai2"]
    assert isinstance(behaviour(ai2, parse_sii(ai2.sii_image())).app, MailboxErrorApp)
    # an SII dump with a mailbox gets the mailbox-error responder too
    assert isinstance(behaviour(None, parse_sii(ai2.sii_image())).app, MailboxErrorApp)
    assert not MailboxErrorApp().wants_output_events
    # CoE kinds: one model per kind and segment, one instance (with its CoE server) per slave
    coe = DEVICES["coe-io"]
    models: dict[object, DeviceModel] = {}
    first = behaviour(coe, parse_sii(coe.sii_image(serial=1)), models)
    second = behaviour(coe, parse_sii(coe.sii_image(serial=2)), models)
    assert isinstance(first.model, CoeIoModel) and second.model is first.model
    assert (first.instance, second.instance) == (0, 1)
    assert coe_server(second.app).od.value(0x1018, 4) == 2


def test_registry_loads_providers_and_entry_points_and_refuses_a_key_twice(
        monkeypatch: pytest.MonkeyPatch) -> None:
    extra = BuiltinDevice(key="my-di", product_code=0x77, order="MY-DI", name="my di", group="DigIn",
                          profile="ET1200", ports=DEVICES["di8"].ports, sync_managers=(), fmmus=())

    class EntryPoint:
        name = "mine"

        @staticmethod
        def load() -> object:
            return lambda: [extra]

    monkeypatch.setattr("pyethercat.sim.devices.registry.entry_points",
                        lambda group: [EntryPoint()] if group == "pyethercat.sim.devices" else [])
    reg = DeviceRegistry()
    assert reg.get_kind("my-di") is extra and "coe-io" in reg and "di8" in reg
    clash = BuiltinDevice(key="di8", product_code=1, order="X", name="x", group="X", profile="ET1200",
                          ports=extra.ports, sync_managers=(), fmmus=())
    with pytest.raises(ConfigError, match="'di8' is defined twice"):
        reg.register(clash)
    # nothing was added to the shared registry by importing or by this test
    assert "my-di" not in DEVICES


def test_mailbox_error_app_answers_unsupported_protocol() -> None:
    app = MailboxErrorApp()
    pdi = _FakePdi()
    app.pdi = pdi  # type: ignore[assignment]
    request = encode_mailbox(MailboxType.COE, b"\x00\x20\x40\x00\x10\x00\x00\x00\x00\x00",
                             counter=3, size=128)
    app.on_mailbox(request)
    (reply,) = pdi.posted
    header, payload = decode_mailbox(reply)
    assert header.type == MailboxType.ERR and header.counter == 3
    assert decode_mailbox_error(payload).code == MailboxErrorCode.UNSUPPORTED_PROTOCOL
    app.on_mailbox(b"\x01")  # not even a header
    header, payload = decode_mailbox(pdi.posted[-1])
    assert decode_mailbox_error(payload).code == MailboxErrorCode.SYNTAX


def test_coe_io_behaviour_per_instance_for_all_and_for_some_instances() -> None:
    # Each instance echoes with its own settings (0x8000:02 offset, 0x8000:03 invert),
    # whether a frame brought outputs for every instance (columns cut to the instances,
    # no index) or for some of them (gathered and scattered).
    coe = DEVICES["coe-io"]
    models: dict[object, DeviceModel] = {}
    runs = [behaviour(coe, parse_sii(coe.sii_image(serial=s)), models) for s in (1, 2, 3)]
    model = runs[0].model
    assert isinstance(model, CoeIoModel) and model.count == 3
    f = model.field
    f(0x7000, 1)[:3] = [0x0F, 0x0F, 0x0F]
    f(0x7000, 2)[:3] = [1, 2, 3]
    f(0x7000, 3)[:3] = [0xFFFF_FFFF, 10, 20]
    f(0x7000, 4)[:3] = [1, 0, 1]
    f(0x8000, 2)[:3] = [1, -5, 0]          # value 32 + offset, modulo 2^32
    f(0x8000, 3)[:3] = [0, 1, 1]           # the second and third invert their digital inputs
    count0 = f(0x6000, 4)[:3].copy()
    model.compute(np.arange(3))
    assert f(0x6000, 1)[:3].tolist() == [0x0F, 0xF0, 0xF0]
    assert f(0x6000, 2)[:3].tolist() == [1, 2, 3]
    assert f(0x6000, 3)[:3].tolist() == [0, 5, 20]
    assert f(0x6000, 5)[:3].tolist() == [1, 0, 1]
    assert (f(0x6000, 4)[:3] - count0).tolist() == [1, 1, 1]
    f(0x7000, 1)[:3] = [0x01, 0x02, 0x03]
    f(0x7000, 3)[:3] = [7, 7, 7]
    model.compute(np.array([1]))           # outputs of the second only (gathered)
    assert f(0x6000, 1)[:3].tolist() == [0x0F, 0xFD, 0xF0]
    assert f(0x6000, 3)[:3].tolist() == [0, 2, 20]
    assert (f(0x6000, 4)[:3] - count0).tolist() == [1, 2, 1]
    f(0x7000, 1)[:3] = [0x11, 0x12, 0x13]
    model.compute(np.array([0, 2]))        # the first and the third (gathered)
    assert f(0x6000, 1)[:3].tolist() == [0x11, 0xFD, 0xEC]
    assert f(0x6000, 3)[:3].tolist() == [8, 2, 7]
    assert (f(0x6000, 4)[:3] - count0).tolist() == [2, 2, 2]
