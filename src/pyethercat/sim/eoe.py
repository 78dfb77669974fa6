"""EoE server of a simulated slave: Ethernet frames between the mailbox and an IP side.

:class:`EoeServer` serves mailbox type 2 on a slave's
:class:`~pyethercat.sim.mailbox.MailboxEngine`:

- fragments from the master are rebuilt (:class:`~pyethercat.wire.mailbox.eoe_stream.EoeReceiver`)
  and the whole frame goes to the slave's IP side, the *endpoint*, unless the
  address filter refuses it; a frame with the time-request flag is answered
  with a timestamp response (frame type 1) carrying the low 32 bits of the
  slave's clock when it passed the frame on;
- frames from the endpoint are fragmented to the SM1 size
  (:class:`~pyethercat.wire.mailbox.eoe_stream.EoeSender`) and posted one
  fragment at a time: the next one as soon as the master has read SM1 (the
  engine's idle hook), never more than one waiting in the engine, so a long
  frame does not fill the reply queue other protocols share. With "append
  timestamp" set (bit 16 of the set-IP flags, as Wireshark's
  ``packet-ecatmb.c`` decodes it) the last fragment carries the time;
- Set IP parameter (frame type 2) is handed to the endpoint, which applies
  it and gives the result code; Get IP parameter (6) answers what was set;
- Set/Get address filter (4/8): up to 16 MAC addresses and the no-broadcast
  flag, laid out as Wireshark's ``packet-ecatmb.h`` (``EoeMacFilterOptionsUnion``)
  has it (Wireshark itself marks the mask part as doubtful); an empty filter
  passes everything.

Endpoints (:class:`EoeEndpoint`): :class:`EchoEndpoint` answers ARP, ICMP
echo and UDP echo (port 7) for its address in Python, so EoE works without
privileges; ``sim.eoe_netns.NetnsEndpoint`` puts a TAP interface into a
network namespace of its own, where the Linux kernel is the slave's IP
stack and a web server shows the device's diagnostic page.
"""

from __future__ import annotations

import ipaddress
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from pyethercat.errors import MailboxError
from pyethercat.sim.mailbox import MailboxDevice, MailboxEngine, service_error
from pyethercat.wire.al import AlState
from pyethercat.wire.mailbox.eoe import (
    EoeFragment,
    EoeGetAddressFilterRequest,
    EoeGetAddressFilterResponse,
    EoeGetIpRequest,
    EoeGetIpResponse,
    EoeIpParameters,
    EoeResult,
    EoeSetAddressFilterRequest,
    EoeSetAddressFilterResponse,
    EoeSetIpRequest,
    EoeSetIpResponse,
    EoeTimestampResponse,
    decode_eoe,
)
from pyethercat.wire.mailbox.eoe_stream import EoeReceiver, EoeSender
from pyethercat.wire.mailbox.header import MailboxErrorCode, MailboxHeader, MailboxType

__all__ = [
    "APPEND_TIMESTAMP_FLAG",
    "default_mac",
    "AddressFilter",
    "EchoEndpoint",
    "EoeEndpoint",
    "EoeServer",
    "EoeSettings",
    "FdReader",
    "attach_eoe",
]

#: Set-IP flag bit 16: the slave appends its time to the frames it sends.
APPEND_TIMESTAMP_FLAG = 0x0001_0000
_MAX_FILTERS = 16
_BROADCAST = b"\xff" * 6

#: (file descriptor, callback when readable): what an endpoint asks a server loop to watch.
FdReader = tuple[int, Callable[[], None]]


def default_mac(serial: int) -> bytes:
    """A locally administered MAC for a simulated slave's IP side, from its serial number."""
    return bytes([0x02, 0x00, 0x45, 0x4F]) + (serial & 0xFFFF).to_bytes(2, "big")


class EoeEndpoint(Protocol):
    """The IP side of a simulated EoE slave."""

    def attach(self, deliver: Callable[[bytes], None], wants: Callable[[], bool]) -> None:
        """``deliver(frame)`` takes frames for the master; ``wants()``: room for more."""

    def send(self, frame: bytes) -> None:
        """A frame from the master for the IP side."""

    def configure(self, params: EoeIpParameters) -> int:
        """Apply Set IP parameter; the EoE result code."""

    def parameters(self) -> EoeIpParameters:
        """What Get IP parameter answers."""

    def readers(self) -> list[FdReader]:
        """Descriptors to watch (empty for endpoints that answer at once)."""

    def close(self) -> None:
        """Release what the endpoint holds (namespaces, sockets)."""


@dataclass
class EoeSettings:
    """The IP side of an EoE slave as a topology gives it (all optional)."""

    ip: ipaddress.IPv4Interface | None = None
    gateway: ipaddress.IPv4Address | None = None
    mac: bytes | None = None
    #: Network namespace for a kernel IP stack (``pyecat-...``); None: the Python echo stack.
    netns: str | None = None
    #: TCP port of the diagnostic web page inside the namespace.
    http_port: int = 80


@dataclass
class AddressFilter:
    """MAC filter of a slave: frames to other unicast addresses are dropped."""

    macs: list[bytes] = field(default_factory=list)
    no_broadcast: bool = False

    def passes(self, frame: bytes) -> bool:
        """Whether a frame from the master may reach the IP side."""
        dst = frame[:6]
        if dst == _BROADCAST:
            return not self.no_broadcast
        if not self.macs or dst[0] & 1:  # no filter set; multicast is not filtered here
            return True
        return dst in self.macs

    def encode(self) -> bytes:
        """Options word, 16 filter addresses, 4 masks (zero)."""
        opts = len(self.macs) | (0x80 if self.no_broadcast else 0)
        body = b"".join(self.macs).ljust(_MAX_FILTERS * 6, b"\x00")
        return struct.pack("<H", opts) + body + bytes(4 * 6)

    @classmethod
    def decode(cls, body: bytes) -> AddressFilter:
        if len(body) < 2:
            raise MailboxError("EoE address filter needs its options word")
        opts = struct.unpack_from("<H", body, 0)[0]
        count = opts & 0xF
        if len(body) < 2 + count * 6:
            raise MailboxError(f"EoE address filter announces {count} addresses, "
                               f"has room for {(len(body) - 2) // 6}")
        macs = [bytes(body[2 + 6 * i: 8 + 6 * i]) for i in range(count)]
        return cls(macs, bool(opts & 0x80))


@dataclass
class EoeServerStats:
    """Frames each way and what was refused."""

    filtered: int = 0
    timestamps: int = 0
    set_ip: int = 0


class EoeServer:
    """EoE on one simulated slave: a mailbox protocol server (see the module text).

    ``engine`` is the slave's mailbox engine (the server posts through it and
    takes its idle hook), ``tx_size`` its SM1 length, ``endpoint`` the IP
    side, ``clock_ns`` the slave's clock (timestamps and time-outs),
    ``status`` what the diagnostic page shows (None: the device has none).
    """

    def __init__(self, engine: MailboxEngine, tx_size: int, endpoint: EoeEndpoint,
                 clock_ns: Callable[[], int],
                 status: Callable[[], dict[str, Any]] | None = None) -> None:
        self.engine = engine
        self.endpoint = endpoint
        self.clock_ns = clock_ns
        self.status = status
        self.receiver = EoeReceiver()
        self.sender = EoeSender(tx_size, queue_limit=32)
        self.filter = AddressFilter()
        self.append_timestamp = False
        self.stats = EoeServerStats()
        engine.idle.append(self.pump)
        endpoint.attach(self.deliver, lambda: self.sender.room)

    @property
    def type(self) -> int:
        """Mailbox type 2."""
        return MailboxType.EOE

    def on_state_change(self, old: AlState, new: AlState) -> None:
        """Nothing to do: frames wait while the mailbox is stopped (reset drops them)."""

    def _now(self) -> float:
        return self.clock_ns() / 1e9

    # -- from the master -----------------------------------------------------------

    def handle(self, header: MailboxHeader, payload: bytes) -> None:
        """One EoE mailbox from the master."""
        try:
            msg = decode_eoe(payload)
        except MailboxError:
            raise service_error(MailboxErrorCode.SIZE_TOO_SHORT
                                if len(payload) < 4 else MailboxErrorCode.SERVICE_NOT_SUPPORTED
                                ) from None
        port = msg.port
        if isinstance(msg, EoeFragment):
            frame = self.receiver.feed(msg, self._now())
            if frame is None:
                return
            if not self.filter.passes(frame):
                self.stats.filtered += 1
                return
            self.endpoint.send(frame)
            if self.receiver.time_requested:
                self.stats.timestamps += 1
                stamp = struct.pack("<I", self.clock_ns() & 0xFFFFFFFF)
                self._reply(EoeTimestampResponse(stamp, port).encode())
        elif isinstance(msg, EoeSetIpRequest):
            self.stats.set_ip += 1
            flags = struct.unpack_from("<I", payload, 4)[0] if len(payload) >= 8 else 0
            self.append_timestamp = bool(flags & APPEND_TIMESTAMP_FLAG)
            result = self.endpoint.configure(msg.params)
            self._reply(EoeSetIpResponse(result, port).encode())
        elif isinstance(msg, EoeGetIpRequest):
            self._reply(EoeGetIpResponse(self.endpoint.parameters(), EoeResult.SUCCESS,
                                         port).encode())
        elif isinstance(msg, EoeSetAddressFilterRequest):
            try:
                self.filter = AddressFilter.decode(msg.data)
                result = EoeResult.SUCCESS
            except MailboxError:
                result = EoeResult.UNSPECIFIED_ERROR
            self._reply(EoeSetAddressFilterResponse(result, port).encode())
        elif isinstance(msg, EoeGetAddressFilterRequest):
            self._reply(EoeGetAddressFilterResponse(self.filter.encode(), port,
                                                    EoeResult.SUCCESS).encode())
        else:
            # responses and timestamps travel slave -> master only (SOES answers the same)
            self._reply(EoeSetIpResponse(EoeResult.UNSUPPORTED_FRAME_TYPE, port).encode())

    def _reply(self, payload: bytes) -> None:
        self.engine.send(MailboxType.EOE, payload)

    # -- to the master -------------------------------------------------------------

    def deliver(self, frame: bytes) -> None:
        """A frame from the IP side for the master."""
        stamp = self.clock_ns() & 0xFFFFFFFF if self.append_timestamp else None
        self.sender.push(frame, self._now(), timestamp=stamp)
        self.pump()

    def pump(self) -> None:
        """Post the next fragment when the engine has nothing waiting."""
        if self.engine.queue:
            return
        payload = self.sender.current(self._now())
        if payload is None:
            return
        self.sender.taken()  # the engine delivers it (re-posting it on a repeat request)
        self.engine.send(MailboxType.EOE, payload)

    def set_endpoint(self, endpoint: EoeEndpoint) -> None:
        """Replace the IP side (the old one is closed)."""
        self.endpoint.close()
        self.endpoint = endpoint
        endpoint.attach(self.deliver, lambda: self.sender.room)

    def readers(self) -> list[FdReader]:
        """What the server loop watches for this slave (the endpoint's descriptors)."""
        return self.endpoint.readers() if self.sender.room else []

    def reset(self) -> None:
        """The mailbox stopped (back to INIT): frames in flight are lost."""
        self.receiver = EoeReceiver()
        self.sender.clear()

    def close(self) -> None:
        self.endpoint.close()


# --- a Python IP stack that answers ARP, ping and UDP echo ------------------------------

_ETH = struct.Struct("!6s6sH")
_ARP = struct.Struct("!HHBBH6s4s6s4s")
_UDP_ECHO_PORT = 7


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\x00"
    total: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


class EchoEndpoint:
    """IP side in Python: ARP replies, ICMP echo replies and UDP echo (port 7).

    Answers only for its own address (none until Set IP parameter or the
    topology gives one). Needs no privileges: unit tests run EoE with it.
    """

    def __init__(self, settings: EoeSettings | None = None) -> None:
        s = settings or EoeSettings()
        self.mac = s.mac or b"\x02\x00\x00\xec\x00\x01"
        self.ip = s.ip
        self.gateway = s.gateway
        self.dns_server: ipaddress.IPv4Address | None = None
        self.dns_name: str | None = None
        self.received: list[bytes] = []
        self._deliver: Callable[[bytes], None] = lambda _f: None

    def attach(self, deliver: Callable[[bytes], None], wants: Callable[[], bool]) -> None:
        self._deliver = deliver

    def configure(self, params: EoeIpParameters) -> int:
        if params.mac is not None:
            self.mac = params.mac
        if params.ip is not None:
            mask = params.subnet or ipaddress.IPv4Address("255.255.255.0")
            self.ip = ipaddress.IPv4Interface(f"{params.ip}/{mask}")
        elif params.subnet is not None and self.ip is not None:
            self.ip = ipaddress.IPv4Interface(f"{self.ip.ip}/{params.subnet}")
        if params.gateway is not None:
            self.gateway = params.gateway
        if params.dns_server is not None:
            self.dns_server = params.dns_server
        if params.dns_name is not None:
            self.dns_name = params.dns_name
        return EoeResult.SUCCESS

    def parameters(self) -> EoeIpParameters:
        return EoeIpParameters(self.mac, self.ip.ip if self.ip else None,
                               self.ip.netmask if self.ip else None, self.gateway,
                               self.dns_server, self.dns_name)

    def readers(self) -> list[FdReader]:
        return []

    def close(self) -> None:
        pass

    def send(self, frame: bytes) -> None:
        self.received.append(frame)
        if len(self.received) > 64:
            del self.received[0]
        if len(frame) < _ETH.size or self.ip is None:
            return
        dst, src, ethertype = _ETH.unpack_from(frame)
        body = frame[_ETH.size:]
        if ethertype == 0x0806 and len(body) >= _ARP.size:
            self._arp(src, body)
        elif ethertype == 0x0800 and dst in (self.mac, _BROADCAST) and len(body) >= 20:
            self._ipv4(src, body)

    def _arp(self, src: bytes, body: bytes) -> None:
        htype, ptype, hlen, plen, op, sha, spa, _tha, tpa = _ARP.unpack_from(body)
        assert self.ip is not None
        if (htype, ptype, hlen, plen, op) != (1, 0x0800, 6, 4, 1) or tpa != self.ip.ip.packed:
            return
        reply = _ARP.pack(1, 0x0800, 6, 4, 2, self.mac, tpa, sha, spa)
        self._deliver(_ETH.pack(src, self.mac, 0x0806) + reply)

    def _ipv4(self, src_mac: bytes, body: bytes) -> None:
        assert self.ip is not None
        ihl = (body[0] & 0x0F) * 4
        total = struct.unpack_from("!H", body, 2)[0]
        if body[0] >> 4 != 4 or ihl < 20 or total > len(body) or body[16:20] != self.ip.ip.packed:
            return
        proto = body[9]
        src_ip = body[12:16]
        payload = body[ihl:total]
        if proto == 1 and len(payload) >= 8 and payload[0] == 8:  # ICMP echo request
            icmp = b"\x00\x00\x00\x00" + payload[4:]
            icmp = icmp[:2] + struct.pack("!H", _checksum(icmp)) + icmp[4:]
            self._send_ip(src_mac, src_ip, 1, icmp)
        elif proto == 17 and len(payload) >= 8:
            sport, dport, ulen = struct.unpack_from("!HHH", payload, 0)
            if dport == _UDP_ECHO_PORT and 8 <= ulen <= len(payload):
                data = payload[8:ulen]
                udp = struct.pack("!HHHH", _UDP_ECHO_PORT, sport, 8 + len(data), 0) + data
                pseudo = self.ip.ip.packed + src_ip + struct.pack("!BBH", 0, 17, len(udp))
                csum = _checksum(pseudo + udp) or 0xFFFF
                self._send_ip(src_mac, src_ip, 17, udp[:6] + struct.pack("!H", csum) + udp[8:])

    def _send_ip(self, dst_mac: bytes, dst_ip: bytes, proto: int, payload: bytes) -> None:
        assert self.ip is not None
        header = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(payload), 0, 0x4000, 64, proto,
                             0, self.ip.ip.packed, dst_ip)
        header = header[:10] + struct.pack("!H", _checksum(header)) + header[12:]
        self._deliver(_ETH.pack(dst_mac, self.mac, 0x0800) + header + payload)


def attach_eoe(app: MailboxDevice, tx_size: int, serial: int,
               status: Callable[[], dict[str, Any]] | None = None) -> EoeServer:
    """Give a mailbox device an EoE server (echo stack until the topology says otherwise)."""

    def clock_ns() -> int:
        return app.pdi.now_ns() if app.pdi is not None else 0

    server = EoeServer(app.mailbox, tx_size, EchoEndpoint(EoeSettings(mac=default_mac(serial))),
                       clock_ns, status)
    app.add_protocol(server)
    return server


def eoe_server(app: object) -> EoeServer | None:
    """The EoE server of a slave's application (None: it speaks no EoE)."""
    if isinstance(app, MailboxDevice):
        server = app.protocols.get(int(MailboxType.EOE))
        if isinstance(server, EoeServer):
            return server
    return None
