"""Links: move whole Ethernet frames (raw socket, UDP, socketpair, in-process pair, capture tee).

All links implement :class:`pyethercat.link.base.Link`: ``send(frame)``,
``recv(timeout) -> frame | None``, ``fileno()``, ``close()``, context manager.
"""

from pyethercat.link.base import Link
from pyethercat.link.capture import CaptureLink
from pyethercat.link.pair import PairLink
from pyethercat.link.raw import RawLink
from pyethercat.link.udp import UdpLink
from pyethercat.link.unix import UnixLink

__all__ = ["Link", "CaptureLink", "PairLink", "RawLink", "UdpLink", "UnixLink"]
