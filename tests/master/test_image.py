"""Process image: named, typed access at bit offsets, raw and numpy views."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from master_sii_helpers import BOOL, INT16, REAL32, UINT8, UINT16, di, do, io_sii

from pyethercat.errors import ConfigError
from pyethercat.master.config import SlaveDescription, configure
from pyethercat.master.image import ProcessImage, build_images


def image_of(*siis):
    cfg = configure([SlaveDescription(i, 0x1001 + i, s) for i, s in enumerate(siis)])
    return build_images(cfg)["main"]


def test_bits_of_packed_terminals_land_in_the_right_places():
    img = image_of(do(2), do(2), di(2))
    o0, o1 = img.slave_outputs(0), img.slave_outputs(1)
    o0["Output 2"] = 1
    o1["Output 1"] = True
    assert img.buffer[0] == 0b0000_0110
    assert list(o1) == ["Output 1", "Output 2"]
    assert o1["Output 1"] is True and o1["Output 2"] is False
    img.buffer[1] = 0b10
    ins = img.slave_inputs(2)
    assert ins["Input 1"] is False and ins["Input 2"] is True
    assert ins.values_dict() == {"Input 1": False, "Input 2": True}


def test_typed_values_round_trip():
    sii = io_sii("mixed", outputs=[("flag", 1, BOOL), ("small", 8, UINT8), ("word", 16, UINT16),
                                   ("signed", 16, INT16), ("real", 32, REAL32)])
    img = image_of(sii)
    out = img.slave_outputs(0)
    # "flag" takes bit 0, so "small" starts at bit 1: unaligned integer access
    out["flag"] = 1
    out["small"] = 0xA5
    out["word"] = 0xBEEF
    out["signed"] = -2
    out["real"] = 1.5
    assert out["small"] == 0xA5 and out["word"] == 0xBEEF and out["signed"] == -2
    assert out["real"] == 1.5
    raw = int.from_bytes(img.buffer, "little")
    assert raw & 1 == 1 and (raw >> 1) & 0xFF == 0xA5
    assert (raw >> 9) & 0xFFFF == 0xBEEF
    assert struct.unpack("<f", ((raw >> 41) & 0xFFFFFFFF).to_bytes(4, "little"))[0] == 1.5
    with pytest.raises(ConfigError, match="out of range 0..255"):
        out["small"] = 256
    with pytest.raises(ConfigError, match=r"-32768..32767"):
        out["signed"] = 40000
    with pytest.raises(ConfigError, match="has no output 'nope'"):
        out["nope"] = 1
    with pytest.raises(ConfigError, match="read-only"):
        img.slave_inputs(0)  # exists but is empty
        img.slave_inputs(0)["x"] = 1


def test_aligned_values_use_struct_and_views_share_the_buffer():
    img = image_of(io_sii("a", outputs=[("w", 16, UINT16)], inputs=[("i", 16, INT16)]))
    img.slave_outputs(0)["w"] = 0x1234
    assert bytes(img.outputs) == b"\x34\x12"
    view = img.inputs_view()
    view[:] = np.frombuffer(struct.pack("<h", -300), dtype=np.uint8)
    assert img.slave_inputs(0)["i"] == -300
    ov = img.outputs_view()
    ov[0] = 0xFF
    assert img.buffer[0] == 0xFF
    var = img.variable(0, "w")
    var.set(7)
    assert var.get() == 7 and img.slave_outputs(0)[(0x7000, 1)] == 7


def test_duplicate_entry_names_need_the_pdo_name(corpus_dir):
    from pyethercat.wire.sii import parse_sii

    el = parse_sii((corpus_dir / "sii" / "ethercrab_el2004.bin").read_bytes())
    img = image_of(el)
    out = img.slave_outputs(0)
    out["Channel 3.Output"] = 1
    assert img.buffer[0] == 0b0100
    assert "Output" not in out and "Channel 3.Output" in out
    out["Output 4"] = 1  # repeated names are numbered in image order
    assert img.buffer[0] == 0b1100 and out["Channel 4.Output"] is True


@given(st.lists(st.integers(1, 16), min_size=1, max_size=12), st.data())
def test_any_bit_layout_round_trips(widths, data):
    sii = io_sii("h", outputs=[(f"v{i}", w, 0) for i, w in enumerate(widths)])
    img = image_of(sii)
    out = img.slave_outputs(0)
    values = [data.draw(st.integers(0, (1 << w) - 1)) for w in widths]
    for i, v in enumerate(values):
        out[f"v{i}"] = v
    assert [out[f"v{i}"] for i in range(len(widths))] == values
    packed = sum(v << sum(widths[:i]) for i, v in enumerate(values))
    assert int.from_bytes(img.buffer, "little") == packed


def test_image_repr_and_slave_bytes():
    img = image_of(do(2), do(2))
    assert isinstance(img, ProcessImage) and "1 output" in repr(img)
    img.slave_outputs(1)["Output 2"] = 1
    from pyethercat.master.config import PdoDirection

    assert img.slave_bytes(1, PdoDirection.OUTPUTS) == b"\x08"
