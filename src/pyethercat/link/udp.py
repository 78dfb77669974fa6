"""EtherCAT over UDP (port 34980).

On the wire each UDP datagram holds exactly what follows the EtherType in a
raw Ethernet frame: the 2-byte EtherCAT header and its body, without padding
(ETG.8200; Wireshark's ``packet-ethercat-frame.c`` decodes UDP port 0x88A4 the
same way). The :class:`~pyethercat.link.base.Link` API carries whole
Ethernet frames, so this link converts at the edge:

* ``send(frame)`` checks the EtherType (0x88A4, optionally behind a VLAN tag),
  drops the 14-byte Ethernet header and the padding after the EtherCAT length,
  and sends the rest to the peer;
* ``recv()`` puts a synthetic Ethernet header in front of a received payload
  (destination ``rx_dst``, default broadcast; source ``rx_src``; EtherType
  0x88A4) and zero-pads it to 60 bytes. A payload that no Ethernet frame
  could carry (longer than 1500 bytes, which would make a frame over 1514
  bytes, or shorter than the 2-byte EtherCAT header) is dropped, counted in
  ``dropped_too_long``/``dropped_too_short`` and logged on the
  ``pyethercat.link`` logger: a stray or hostile datagram must not stop a
  master's receive loop, and nothing above the link expects such a frame.

The MAC addresses of sent frames are therefore not transported. The default
``rx_src`` depends on the role, so that received frames look as they would on
a wire (in captures, for decoders): a link with a fixed ``peer`` (a master)
receives frames that slaves have returned, so their source is the master's
MAC with the locally administered bit set (``12:10:10:10:10:10``); a server
link (no peer) receives frames a master sent, with source
``10:10:10:10:10:10``. Nothing depends on it: every datagram comes from the
peer, so the link never shows our own frames (``sees_own_frames`` is False).

A master gives ``peer`` (the simulator's or gateway's address) and binds an
ephemeral port on 127.0.0.1 by default; it then accepts datagrams from that
peer only. A server gives no peer and a fixed ``bind``; it answers whoever
sent the last datagram.
"""

from __future__ import annotations

import logging
import socket
import struct

from pyethercat.errors import LinkError
from pyethercat.link.base import SocketLink
from pyethercat.wire.frame import (
    BROADCAST_MAC,
    ECAT_HEADER_SIZE,
    ECAT_LENGTH_MASK,
    ETH_HEADER_SIZE,
    MASTER_MAC,
    MAX_FRAME_SIZE,
    UDP_PORT,
    ecat_offset,
    ethernet_frame,
    returned_source_mac,
)

__all__ = ["MAX_UDP_PAYLOAD", "UdpLink", "parse_hostport", "frame_to_udp_payload", "udp_payload_to_frame"]

_MAX_UDP = 65535
#: Longest payload that still fits a frame of MAX_FRAME_SIZE (1514) bytes.
MAX_UDP_PAYLOAD = MAX_FRAME_SIZE - ETH_HEADER_SIZE

_log = logging.getLogger("pyethercat.link")


def parse_hostport(text: str, default_port: int = UDP_PORT) -> tuple[str, int]:
    """Parse ``HOST[:PORT]`` (port defaults to 34980)."""
    host, sep, port = text.rpartition(":")
    if not sep:
        return text, default_port
    try:
        number = int(port, 0)
    except ValueError:
        raise LinkError(f"bad UDP port in {text!r}") from None
    if not 0 <= number <= 0xFFFF:
        raise LinkError(f"UDP port {number} out of range in {text!r}")
    return host or "127.0.0.1", number


def frame_to_udp_payload(frame: bytes) -> bytes:
    """The EtherCAT part of an Ethernet frame (header + body, padding dropped)."""
    if len(frame) < ETH_HEADER_SIZE + ECAT_HEADER_SIZE:
        raise LinkError(f"frame of {len(frame)} bytes is too short for EtherCAT")
    start = ecat_offset(frame)
    if start is None or len(frame) < start + ECAT_HEADER_SIZE:
        ethertype = (frame[12] << 8) | frame[13]
        raise LinkError(f"EtherType 0x{ethertype:04X} cannot travel as EtherCAT over UDP")
    (word,) = struct.unpack_from("<H", frame, start)
    end = start + ECAT_HEADER_SIZE + (word & ECAT_LENGTH_MASK)
    # A lying length is passed on unchanged: the receiver is the one to judge it.
    return bytes(frame[start : min(end, len(frame))])


def udp_payload_to_frame(
    payload: bytes, src: bytes = MASTER_MAC, dst: bytes = BROADCAST_MAC
) -> bytes:
    """An Ethernet frame around an EtherCAT-over-UDP payload, zero-padded to 60 bytes."""
    return ethernet_frame(payload, src, dst)


def _resolve(host: str, port: int) -> tuple[str, int]:
    try:
        info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except OSError as exc:
        raise LinkError(f"cannot resolve UDP address {host}:{port}: {exc}") from exc
    addr = info[0][4]
    return str(addr[0]), int(addr[1])


class UdpLink(SocketLink):
    """EtherCAT frames over a UDP socket (IPv4)."""

    #: Every datagram received comes from the peer (and a master's link takes
    #: datagrams from its peer only): never our own frame.
    sees_own_frames = False

    def __init__(
        self,
        peer: tuple[str, int] | str | None = None,
        bind: tuple[str, int] | str = ("127.0.0.1", 0),
        name: str | None = None,
        rx_src: bytes | None = None,
        rx_dst: bytes = BROADCAST_MAC,
    ) -> None:
        """Bind a UDP socket; ``peer`` fixes where frames go (see the module docstring).

        ``rx_src``/``rx_dst`` are the MACs of the synthetic Ethernet header put on
        received frames; ``rx_src`` defaults by role as the module docstring says.
        """
        bind_addr = parse_hostport(bind, 0) if isinstance(bind, str) else bind
        self._peer: tuple[str, int] | None = None
        self._fixed_peer = peer is not None
        if peer is not None:
            self._peer = _resolve(*(parse_hostport(peer) if isinstance(peer, str) else peer))
        if rx_src is None:
            rx_src = returned_source_mac(MASTER_MAC) if peer is not None else MASTER_MAC
        if len(rx_src) != 6 or len(rx_dst) != 6:
            raise LinkError("rx_src and rx_dst must be 6-byte MAC addresses")
        #: Source and destination MACs of the synthetic header on received frames.
        self.rx_src = rx_src
        self.rx_dst = rx_dst
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(bind_addr)
        except OSError as exc:
            sock.close()
            raise LinkError(f"cannot bind UDP {bind_addr[0]}:{bind_addr[1]}: {exc}") from exc
        sock.setblocking(False)
        #: Received payloads dropped as longer than MAX_UDP_PAYLOAD bytes.
        self.dropped_too_long = 0
        #: Received payloads dropped as shorter than the EtherCAT header.
        self.dropped_too_short = 0
        # Named by the address the user gave: the peer of a master's link (error
        # messages then say where nothing answered), the bound address of a server's.
        where = self._peer if self._peer is not None else sock.getsockname()
        super().__init__(name or f"udp:{where[0]}:{where[1]}", sock)

    @property
    def address(self) -> tuple[str, int]:
        """The local (host, port) the socket is bound to."""
        addr = self._sock.getsockname()
        return str(addr[0]), int(addr[1])

    @property
    def peer(self) -> tuple[str, int] | None:
        """Where frames are sent (fixed, or learned from the last received datagram)."""
        return self._peer

    def send(self, frame: bytes) -> None:
        self._check_open()
        if self._peer is None:
            raise LinkError(f"link {self.name}: no peer to send to yet (nothing received)")
        payload = frame_to_udp_payload(frame)
        try:
            self._sock.sendto(payload, self._peer)
        except BlockingIOError:
            pass  # socket buffer full: the frame is lost, as on Ethernet
        except OSError as exc:
            raise LinkError(f"link {self.name}: send to {self._peer} failed: {exc}") from exc

    def _receive(self, left: float | None) -> bytes | None:
        try:
            payload, addr = self._sock.recvfrom(_MAX_UDP)
        except (BlockingIOError, ConnectionRefusedError):
            # ECONNREFUSED: an ICMP "port unreachable" for an earlier send.
            self._wait_readable(left)
            return None
        except OSError as exc:
            raise LinkError(f"link {self.name}: receive failed: {exc}") from exc
        source = (str(addr[0]), int(addr[1]))
        if self._fixed_peer and source != self._peer:
            return None  # not from our peer: ignore
        if not ECAT_HEADER_SIZE <= len(payload) <= MAX_UDP_PAYLOAD:
            self._drop(payload, source)
            return None
        if not self._fixed_peer:
            self._peer = source
        return udp_payload_to_frame(payload, self.rx_src, self.rx_dst)

    def _drop(self, payload: bytes, source: tuple[str, int]) -> None:
        """Count and log a payload that cannot become an Ethernet frame."""
        if len(payload) < ECAT_HEADER_SIZE:
            self.dropped_too_short += 1
            count = self.dropped_too_short
            why = f"shorter than the {ECAT_HEADER_SIZE}-byte EtherCAT header"
        else:
            self.dropped_too_long += 1
            count = self.dropped_too_long
            why = f"longer than {MAX_UDP_PAYLOAD} bytes (a frame over {MAX_FRAME_SIZE} bytes)"
        # The first of a kind is a warning; repeats go to debug so that a flood of
        # junk cannot flood the log too.
        _log.log(
            logging.WARNING if count == 1 else logging.DEBUG,
            "link %s: dropped a %d-byte UDP payload from %s:%d: %s (%d so far)",
            self.name, len(payload), source[0], source[1], why, count,
        )
