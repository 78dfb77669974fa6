"""A raw link whose interface or far end goes down and comes back (veth pair, root).

What the kernel does, and what the link makes of it:
- far end down: our interface loses its carrier (``carrier()`` False), sends
  still succeed (the frames go nowhere), nothing comes back;
- our interface down: ``send`` raises LinkDownError, and so does the one
  ``recv`` that gets the kernel's notice;
- back up: frames flow again on the same socket; ``carrier()`` True.
"""

from __future__ import annotations

import subprocess
import time

import pytest

from pyethercat.errors import LinkDownError, LinkError
from pyethercat.link import CaptureLink, PairLink, RawLink
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.frame import encode_frame

pytestmark = pytest.mark.root


def _frame(index: int) -> bytes:
    return encode_frame([Datagram.device(Command.APRD, 0, 0x0000, 2, index)])


def _set(name: str, state: str) -> None:
    subprocess.run(["ip", "link", "set", name, state], check=True)


def _until(cond, seconds: float = 5.0) -> bool:  # noqa: ANN001
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


def _flows(a: RawLink, b: RawLink, index: int) -> bool:
    b.send(_frame(index))
    return a.recv(0.1) == _frame(index)


def test_far_end_down_and_up(veth_pair: tuple[str, str]) -> None:
    a_name, b_name = veth_pair
    with RawLink(a_name) as a, RawLink(b_name) as b:
        assert _until(lambda: a.carrier() is True)
        _set(b_name, "down")
        assert _until(lambda: a.carrier() is False)
        a.send(_frame(1))  # no error: the frame just goes nowhere
        assert a.recv(0.05) is None
        _set(b_name, "up")
        assert _until(lambda: a.carrier() is True)
        assert _until(lambda: _flows(a, b, 2))


def test_own_interface_down_and_up(veth_pair: tuple[str, str]) -> None:
    a_name, b_name = veth_pair
    with RawLink(a_name) as a, RawLink(b_name) as b:
        _set(a_name, "down")
        assert a.carrier() is False
        with pytest.raises(LinkDownError, match=f"network interface {a_name} is down"):
            a.send(_frame(1))
        # the kernel's notice reaches one recv; the next ones just wait
        with pytest.raises(LinkDownError):
            a.recv(0.05)
        assert a.recv(0.05) is None
        assert a.down_notices == 1
        _set(a_name, "up")
        assert _until(lambda: a.carrier() is True)
        assert _until(lambda: _flows(a, b, 3))
        # the capture wrapper passes the carrier on
        assert CaptureLink(a, "/dev/null").carrier() is True


def test_carrier_of_a_deleted_interface_and_of_links_that_cannot_tell(
        veth_pair: tuple[str, str]) -> None:
    a_name, _ = veth_pair
    a = RawLink(a_name)
    try:
        subprocess.run(["ip", "link", "del", a_name], check=True)
        with pytest.raises(LinkError, match="has gone"):
            a.send(_frame(1))
        assert a.carrier() is False
    finally:
        a.close()
    assert a.carrier() is False
    assert PairLink.responder_link(lambda f: f).carrier() is None
