"""The examples of docs/master.md and docs/coe.md do what the text says."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

from pyethercat.errors import ConfigError
from pyethercat.link.pair import PairLink
from pyethercat.master.coe import resolve_dtype
from pyethercat.master.master import Master
from pyethercat.sim.topology import load_topology
from pyethercat.wire.mailbox.datatypes import TYPE_NAMES

REPO = Path(__file__).resolve().parents[2]


def test_master_md_five_lines_read_the_input_the_output_drove() -> None:
    text = (REPO / "docs" / "master.md").read_text()
    code = text.split("## In five lines", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    assert 'Master.open(iface="eth1")' in code
    segment = load_topology(REPO / "examples" / "demo.toml").build()
    link = PairLink.responder_link(segment.process)
    code = code.replace('Master.open(iface="eth1")', "Master(link)")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "master.md", "exec"), {"Master": Master, "link": link})  # noqa: S102
    # slave 3's outputs are wired to slave 2's inputs: the printed input is the 1 written.
    assert out.getvalue().split()[0] in ("1", "True"), out.getvalue()


def test_coe_md_lists_exactly_the_accepted_type_names() -> None:
    text = (REPO / "docs" / "coe.md").read_text()
    table = text.split("<!-- type-names -->", 1)[1].split("<!-- /type-names -->", 1)[0]
    listed = set(re.findall(r"`([a-z0-9_]+)`", table))
    accepted = {n for n in TYPE_NAMES if not n.startswith("sm")}
    assert listed == accepted
    for name in listed:
        resolve_dtype(name)
    assert resolve_dtype("int") == resolve_dtype("INTEGER16")
    assert resolve_dtype("0x0007") == resolve_dtype("UNSIGNED32")
    # Sign-and-magnitude is the command line's notation; as a dtype it would decode wrongly.
    for name in ("sm8", "sm16", "SM32", "sm64"):
        with pytest.raises(ConfigError, match="sign-and-magnitude"):
            resolve_dtype(name)
