"""Topology files: building a simulated segment from one.

The format is shared with the master (``pyethercat.topology``, documented
with examples in ``docs/simulator.md``): this module reads the file, resolves
every ``[[slave]]`` into what it is (a built-in kind, an SII image, an ESI
device) with its ESC profile, places the slaves on their ports, checks wires
and faults against the devices, and builds the :class:`Segment`.

Slaves form a line in file order: a slave without ``parent`` joins the
previous slave of the file, on that slave's first free port of 1, 2, 3 (in
that order; port 0 always faces the master). A slave with ``parent``/``port``
is placed on that port of an earlier slave (a tree branch).

Every error raises :class:`~pyethercat.errors.ConfigError` naming the file and
the slave (or wire/fault) it concerns.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pyethercat.errors import ConfigError, SiiError
from pyethercat.sim.devices import get_builtin
from pyethercat.sim.devices.builtin import BuiltinDevice, with_serial
from pyethercat.sim.devices.esi_device import EsiSlave, load_esi_device
from pyethercat.sim.eoe import EchoEndpoint, EoeSettings, eoe_server
from pyethercat.sim.foe import FoeOptions
from pyethercat.sim.profiles import DEVICE_PROFILES, PROFILES, EscProfile
from pyethercat.sim.protocols import MailboxOptions
from pyethercat.topology import (
    FaultEntry,
    SegmentDoc,
    SlaveEntry,
    WireEntry,
    parse_topology_text,
    to_int,
)
from pyethercat.wire.registers import PortType
from pyethercat.wire.sii import MailboxProtocol, SiiInfo, SiiPortType, parse_sii, sii_crc
from pyethercat.wire.sii.model import CategoryType

if TYPE_CHECKING:
    from pyethercat.clock import TimeSource
    from pyethercat.sim.device import DeviceApp
    from pyethercat.sim.segment import Segment

__all__ = [
    "FaultConfig",
    "ResolvedSlave",
    "Topology",
    "WireConfig",
    "build_segment",
    "close_eoe",
    "load_topology",
    "parse_topology",
]

@dataclass
class ResolvedSlave:
    """One ``[[slave]]`` table, checked and resolved (the file's entry as written is
    :class:`~pyethercat.topology.SlaveEntry`)."""

    name: str
    source: str  # "builtin:di8", or the SII/ESI path as written
    sii: bytes  # the EEPROM image the slave will carry
    info: SiiInfo  # the parsed image (identity, PDOs)
    profile: EscProfile  # resolved ESC profile (ports adjusted to the SII)
    builtin: BuiltinDevice | None = None
    sii_path: Path | None = None
    alias: int | None = None
    drift_ppm: float | None = None
    forwarding_delay_ns: int | None = None
    cable_delay_ns: int = 5
    inputs: bytes | None = None
    parent: str | None = None  # resolved: every slave but the first has one
    port: int | None = None
    #: The ESI device when the slave was made from ``esi = ...`` (its app serves the OD).
    esi: EsiSlave | None = None
    #: The IP side of an EoE slave (``eoe = {...}``); None: the Python echo stack.
    eoe: EoeSettings | None = None
    #: FoE/SoE servers (the ``foe*``/``soe`` keys).
    mailbox: MailboxOptions = field(default_factory=MailboxOptions)

    @property
    def input_bits(self) -> int:
        """Input process data bits (TxPDOs with a sync manager)."""
        return self.info.input_bits

    @property
    def output_bits(self) -> int:
        """Output process data bits (RxPDOs with a sync manager)."""
        return self.info.output_bits

    @property
    def ports(self) -> tuple[int, ...]:
        """Port numbers this slave has (from its resolved ESC profile)."""
        return self.profile.implemented_ports


@dataclass(frozen=True)
class WireConfig:
    """One ``[[wire]]``: ``bits`` output bits of ``src`` drive input bits of ``dst``."""

    src: str
    src_bit: int
    dst: str
    dst_bit: int
    bits: int


FaultConfig = FaultEntry
"""One ``[[fault]]`` applied at build time (the file's entry as it is)."""


@dataclass
class Topology(SegmentDoc[ResolvedSlave, WireConfig]):
    """A parsed topology file. :meth:`build` makes the :class:`Segment`."""

    def build(self, clock: TimeSource | None = None) -> Segment:
        """Build the segment (see :func:`build_segment`)."""
        return build_segment(self, clock=clock)


# --- parsing -------------------------------------------------------------------


def load_topology(path: str | Path) -> Topology:
    """Read and check a topology file; relative SII/ESI paths are taken from its folder."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read topology file {p}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({exc.reason})") from exc
    return parse_topology(text, base_dir=p.parent, source=str(p))


def parse_topology(
    text: str | dict[str, Any], base_dir: str | Path = ".", source: str = "<topology>"
) -> Topology:
    """Parse topology TOML text (or an already-parsed dict) and resolve its slaves."""
    doc = parse_topology_text(text, source)
    topo = Topology(source=source, drop_probability=doc.drop_probability, seed=doc.seed,
                    drift_ppm=doc.drift_ppm, drift_seed=doc.drift_seed,
                    ring=doc.ring)
    base = Path(base_dir)
    parsed: dict[bytes, SiiInfo] = {}  # slaves of one image share its parse (read only)
    for entry in doc.slaves:
        topo.slaves.append(_resolve_slave(entry, topo, base, parsed))
    _place(topo)
    for w in doc.wires:
        topo.wires.append(_check_wire(w, topo))
    for i, f in enumerate(doc.faults):
        _check_fault(f, i, topo)
        topo.faults.append(f)
    return topo


def _resolve_slave(entry: SlaveEntry, topo: Topology, base: Path,
                   parsed: dict[bytes, SiiInfo]) -> ResolvedSlave:
    where = f"{topo.source}: slave {entry.name!r}"
    builtin: BuiltinDevice | None = None
    sii_path: Path | None = None
    esi_slave: EsiSlave | None = None
    if entry.kind == "device":
        try:
            builtin = get_builtin(entry.source)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        image = builtin.sii_image(serial=entry.serial)
    elif entry.kind == "sii":
        sii_path = (base / entry.source) if not Path(entry.source).is_absolute() else Path(entry.source)
        try:
            image = sii_path.read_bytes()
        except OSError as exc:
            raise ConfigError(
                f"{where}: cannot read SII file {sii_path}: {exc.strerror or exc}"
            ) from exc
    else:
        try:
            esi_slave = load_esi_device(_esi_file(entry.source, base, where), entry.product,
                                        entry.revision, entry.serial)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        image = esi_slave.sii
    # Slaves whose images differ only in the serial number share one parse.
    key = with_serial(image, 0) if len(image) >= 0x20 else image
    info = parsed.get(key)
    if info is None:
        try:
            info = parsed[key] = parse_sii(key)
        except SiiError as exc:
            raise ConfigError(f"{where}: SII image {entry.written_source} is unusable: {exc}") from exc
    if len(image) >= 0x20:
        serial = int.from_bytes(image[0x1C:0x20], "little")
        if serial != info.serial:
            info = replace(info, serial=serial)
    profile_name = entry.profile if entry.profile is not None else default_profile(builtin, info)
    if profile_name.upper() not in PROFILES:
        raise ConfigError(
            f"{where}: unknown ESC profile {profile_name!r}: "
            f"choose one of {', '.join(sorted(PROFILES))}"
        )
    profile = profile_for(PROFILES[profile_name.upper()], info)
    _check_image(image, info, profile, f"{where}: SII image {entry.written_source}")
    cfg = ResolvedSlave(
        name=entry.name, source=entry.written_source, sii=image, info=info,
        profile=profile, builtin=builtin,
        sii_path=sii_path, alias=entry.alias, drift_ppm=entry.drift_ppm,
        forwarding_delay_ns=entry.forwarding_delay_ns, cable_delay_ns=entry.cable_delay_ns,
        inputs=entry.inputs, parent=entry.parent, port=entry.port, esi=esi_slave,
    )
    if cfg.inputs is not None:
        limit = (cfg.input_bits + 7) // 8
        if len(cfg.inputs) > limit:
            raise ConfigError(
                f"{where}: inputs has {len(cfg.inputs)} bytes, the device has {limit} input bytes"
            )
    cfg.mailbox = _mailbox_options(entry, base, where)
    if entry.eoe is not None:
        cfg.eoe = _eoe_settings(entry.eoe, f"{where}: eoe")
        if not info.mailbox_protocols & MailboxProtocol.EOE:
            raise ConfigError(f"{where}: eoe given, but the device does not speak EoE")
    return cfg


def _mailbox_options(entry: SlaveEntry, base: Path, where: str) -> MailboxOptions:
    """The FoE/SoE settings of a slave, ``foe_dir`` taken from the file's folder."""
    foe = FoeOptions(password=entry.foe_password, busy_every=entry.foe_busy_every,
                     firmware_password=entry.firmware_password)
    if entry.foe_wrap is not None:
        foe.wrap = entry.foe_wrap
    if entry.foe_max_size is not None:
        foe.max_size = entry.foe_max_size
    if entry.foe_dir is not None:
        folder = Path(entry.foe_dir)
        folder = folder if folder.is_absolute() else base / folder
        if not folder.is_dir():
            raise ConfigError(f"{where}: foe_dir {folder} is not a folder")
        foe.directory = folder
    return MailboxOptions(foe=entry.foe, soe=entry.soe, foe_options=foe)


def _esi_file(source: str, base: Path, where: str) -> Path:
    """``esi = "PATH"`` (relative to the topology file) or ``"builtin:NAME"`` (shipped ESI)."""
    if source.startswith("builtin:"):
        from pyethercat.errors import EsiError
        from pyethercat.esi.bundled import SEED002_DRIVE, bundled_esi

        try:
            return bundled_esi(source.removeprefix("builtin:") or SEED002_DRIVE)
        except EsiError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    return base / source


def _check_image(image: bytes, info: SiiInfo, profile: EscProfile, where: str) -> None:
    """Refuse an SII image a real slave could not run from, saying why.

    A wrong header checksum (the ESC would not load its configuration words),
    an image ending inside the fixed area (words 0x00-0x3F), a damaged standard
    category, or a mailbox or sync manager outside the chip's process RAM
    (0x1000 up to the profile's RAM end; process data may also use the
    digital I/O registers from 0x0F00): such an image would otherwise fail
    much later, in a master, with an unrelated error (a frame too large for
    a 64 KiB mailbox read from 0xFFFF words).
    """
    if len(image) < 128:
        raise ConfigError(f"{where}: {len(image)} bytes end inside the fixed area "
                          "(words 0x00-0x3F, 128 bytes)")
    if not info.checksum_ok:
        raise ConfigError(f"{where}: header checksum (word 0x07) is 0x{info.checksum & 0xFF:02X}, "
                          f"the CRC of words 0x00-0x06 is 0x{sii_crc(image):02X}")
    for w in info.warnings:
        # A standard category damaged; a vendor one (named by its number) may be cut short.
        head = w.split()
        if len(head) > 1 and head[0] == "category" and head[1] in CategoryType.__members__:
            raise ConfigError(f"{where}: {w}")
    end = profile.ram_end
    (rx, tx), (boot_rx, boot_tx) = info.mailbox_layout(), info.mailbox_layout(boot=True)
    boxes = (("receive mailbox", *rx), ("send mailbox", *tx),
             ("bootstrap receive mailbox", *boot_rx), ("bootstrap send mailbox", *boot_tx))
    # Mailboxes live in the process RAM; process-data SMs may also use the digital
    # I/O registers 0x0F00-0x0FFF (ET1200 terminals such as the EL2004 do).
    windows = [(what, start, size, 0x1000) for what, start, size in boxes if size]
    windows += [(f"sync manager {n}", sm.start, sm.length, 0x0F00)
                for n, sm in enumerate(info.sync_managers) if sm.length]
    for what, start, size, low in windows:
        if start < low or start + size > end:
            raise ConfigError(f"{where}: {what} at 0x{start:04X} with {size} bytes lies outside "
                              f"0x{low:04X}-0x{end - 1:04X} (process RAM of profile "
                              f"{profile.name})")


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: expected a non-empty string, got {value!r}")
    return value


def _eoe_settings(raw: dict[str, Any], where: str) -> EoeSettings:
    """``eoe = { ip = "A/P", gateway = "G", mac = "M", netns = "pyecat-...", http_port = 80 }``
    (keys checked by ``pyethercat.topology``)."""
    import ipaddress

    from pyethercat.link.tap import parse_mac

    out = EoeSettings()
    try:
        if "ip" in raw:
            out.ip = ipaddress.IPv4Interface(_text(raw["ip"], f"{where}: ip"))
        if "gateway" in raw:
            out.gateway = ipaddress.IPv4Address(_text(raw["gateway"], f"{where}: gateway"))
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if "mac" in raw:
        try:
            out.mac = parse_mac(_text(raw["mac"], f"{where}: mac"))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    if "netns" in raw:
        out.netns = _text(raw["netns"], f"{where}: netns")
        if not out.netns.startswith("pyecat-"):
            raise ConfigError(f"{where}: netns {out.netns!r} must start with 'pyecat-'")
    if "http_port" in raw:
        out.http_port = to_int(raw["http_port"], f"{where}: http_port", 1, 65535)
    return out


def _place(topo: Topology) -> None:
    """Resolve parent/port of every slave; check ports exist and are free."""
    used: dict[str, set[int]] = {s.name: {0} for s in topo.slaves}
    names = [s.name for s in topo.slaves]
    for i, s in enumerate(topo.slaves):
        if i == 0:
            continue
        where = f"{topo.source}: slave {s.name!r}"
        if s.parent is None:
            prev = topo.slaves[i - 1]
            free = [p for p in (1, 2, 3) if p not in used[prev.name] and p in prev.ports]
            if not free:
                raise ConfigError(
                    f"{where}: the previous slave {prev.name!r} has no free port; "
                    f"give parent/port"
                )
            s.parent, s.port = prev.name, free[0]
        else:
            parent = topo.slaves[names.index(s.parent)]
            assert s.port is not None
            if s.port not in parent.ports:
                raise ConfigError(f"{where}: slave {parent.name!r} has no port {s.port}")
            if s.port in used[parent.name]:
                raise ConfigError(f"{where}: port {s.port} of {parent.name!r} is already in use")
        assert s.parent is not None and s.port is not None
        used[s.parent].add(s.port)


def _check_wire(w: WireEntry, topo: Topology) -> WireConfig:
    where = f"{topo.source}: wire #{len(topo.wires) + 1}"
    out_bits = topo.slaves[topo.index(w.src)].output_bits
    in_bits = topo.slaves[topo.index(w.dst)].input_bits
    if out_bits == 0:
        raise ConfigError(f"{where}: slave {w.src!r} has no outputs to wire from")
    if in_bits == 0:
        raise ConfigError(f"{where}: slave {w.dst!r} has no inputs to wire to")
    bits = w.bits if w.bits is not None else min(out_bits - w.src_bit, in_bits - w.dst_bit)
    if bits < 1 or w.src_bit + bits > out_bits:
        raise ConfigError(f"{where}: {w.src!r} has {out_bits} output bits, "
                          f"bits {w.src_bit}+{bits} do not fit")
    if w.dst_bit + bits > in_bits:
        raise ConfigError(f"{where}: {w.dst!r} has {in_bits} input bits, "
                          f"bits {w.dst_bit}+{bits} do not fit")
    return WireConfig(w.src, w.src_bit, w.dst, w.dst_bit, bits)


def _check_fault(f: FaultEntry, i: int, topo: Topology) -> None:
    if f.kind not in ("break_link", "corrupt"):
        return
    where = f"{topo.source}: fault #{i + 1}"
    cfg = topo.slaves[topo.index(f.slave)]
    # Port 0 always has a cable (to the parent, or to the master); ports 1-3
    # only when another slave hangs there. A fault elsewhere would be
    # silently a no-op.
    cabled = {0} | {s.port for s in topo.slaves if s.parent == f.slave and s.port is not None}
    if f.port not in cfg.ports:
        raise ConfigError(f"{where}: slave {f.slave!r} has no port {f.port} "
                          f"(ports {', '.join(map(str, cfg.ports))})")
    if f.port not in cabled:
        raise ConfigError(f"{where}: port {f.port} of slave {f.slave!r} has no cable")


# --- building ------------------------------------------------------------------------


def build_segment(topo: Topology, clock: TimeSource | None = None) -> Segment:
    """Make a :class:`pyethercat.sim.segment.Segment` from a parsed topology.

    ``clock``: the segment's time source (a virtual clock by default).
    """
    from pyethercat.sim.devices import Behaviour, behaviour
    from pyethercat.sim.devices.esi_device import esi_model
    from pyethercat.sim.model import DeviceModel
    from pyethercat.sim.protocols import add_mailbox_protocols
    from pyethercat.sim.segment import Segment, SimSlaveSpec

    seg = Segment(clock=clock)
    index: dict[str, int] = {}
    # One device model per kind (built-in key, or ESI file + device) for this segment.
    models: dict[object, DeviceModel] = {}
    rng = random.Random(topo.drift_seed)
    for s in topo.slaves:
        # Drawn for every slave, so one slave's own value leaves the others' as they were.
        drawn = rng.uniform(-topo.drift_ppm, topo.drift_ppm)
        where = f"{topo.source}: slave {s.name!r}"
        esi_key = None
        if s.esi is not None:
            esi_key = (str(s.esi.path), s.esi.device.product_code, s.esi.device.revision)
            if esi_key not in models:
                model = esi_model(s.esi, s.info)
                if model is not None:
                    models[esi_key] = model
        if esi_key is not None and esi_key in models:
            instance, app = models[esi_key].instance_app(s.info)
            run = Behaviour(app, models[esi_key], instance)
        else:
            run = behaviour(s.builtin, s.info, models)
        if s.eoe is not None:
            _eoe_endpoint(run.app, s.eoe, s.name, where)
        app = add_mailbox_protocols(run.app, s.info, s.mailbox, where=where)
        spec = SimSlaveSpec(
            name=s.name,
            sii=s.sii,
            profile=s.profile,
            app=app,
            alias=s.alias,
            drift_ppm=drawn if s.drift_ppm is None else s.drift_ppm,
            forwarding_delay_ns=s.forwarding_delay_ns,
            initial_inputs=s.inputs,
            sii_info=s.info,
            model=run.model,
            instance=run.instance,
        )
        try:
            if s.parent is None:
                idx = seg.add_slave(spec, cable_delay_ns=s.cable_delay_ns)
            else:
                idx = seg.add_slave(
                    spec, parent=index[s.parent], port=s.port, cable_delay_ns=s.cable_delay_ns
                )
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        index[s.name] = idx
    if topo.ring:
        where = f"{topo.source}: [segment] ring"
        try:
            if not isinstance(topo.ring, tuple):
                seg.close_ring()
            else:
                name, port = topo.ring
                if name not in index:
                    raise ConfigError(f"no slave named {name!r}")
                seg.close_ring(index[name], port)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    for w in topo.wires:
        seg.wire(index[w.src], w.src_bit, index[w.dst], w.dst_bit, w.bits)
    if topo.drop_probability:
        seg.drop_probability(topo.drop_probability, seed=topo.seed)
    for f in topo.faults:
        i = index[f.slave]
        if f.kind == "break_link":
            seg.break_link(i, f.port)
        elif f.kind == "power_off":
            seg.power_off(i)
        else:
            seg.corrupt_frames(i, f.port, f.count)
    return seg


def _eoe_endpoint(app: DeviceApp | None, settings: EoeSettings, name: str, where: str) -> None:
    """Give an EoE slave its IP side: a namespace with the kernel's stack, or the echo stack."""
    server = eoe_server(app)
    if server is None:
        raise ConfigError(f"{where}: eoe given, but its application has no EoE server")
    if settings.netns is not None:
        from pyethercat.sim.eoe_netns import NetnsEndpoint

        status = server.status
        if status is None:
            raise ConfigError(f"{where}: this device has no diagnostic page for its namespace")
        if settings.mac is None:
            settings.mac = server.endpoint.parameters().mac
        try:
            server.set_endpoint(NetnsEndpoint(settings, status, name))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    else:
        if settings.mac is None:
            settings.mac = server.endpoint.parameters().mac
        server.set_endpoint(EchoEndpoint(settings))


def close_eoe(segment: Segment) -> None:
    """Release the IP sides of a segment's EoE slaves (namespaces, TAPs, web servers)."""
    for slave in segment.slaves:
        server = eoe_server(slave.spec.app)
        if server is not None:
            server.close()


def device_spec(device: str, name: str, base_dir: str | Path = ".", **entry: Any) -> Any:
    """The slave spec of one device as a topology entry names it (``builtin:di8``), for
    plugging into a running segment; ``entry`` adds keys of a ``[[slave]]`` table
    (``serial``, ``alias``, ``inputs``...)."""
    topo = parse_topology({"slave": [{"name": name, "device": device, **entry}]}, base_dir,
                          source=f"device {device!r}")
    return build_segment(topo).slaves[0].spec


def default_profile(builtin: BuiltinDevice | None, info: SiiInfo) -> str:
    """ESC profile name for a slave whose topology entry names none.

    Built-ins carry their own. An SII image of a device whose real chip is
    known (``profiles.DEVICE_PROFILES``, by vendor and product code: EK1100,
    EL1004, EL2828, EL2889) gets that device's profile. Otherwise the ports
    decide: at most two ports, all E-Bus, is an ET1200-class chip (Beckhoff
    terminals); more ports or MII ports an ET1100 (couplers, junctions, MII
    devices).
    """
    if builtin is not None:
        return builtin.profile
    known = DEVICE_PROFILES.get((info.vendor_id, info.product_code))
    if known is not None:
        return known
    gen = info.general
    if gen is None or gen.physical_ports == 0:
        return "ET1100"
    used = [p for p in gen.ports if p != SiiPortType.NOT_USED]
    if len(used) <= 2 and all(p == SiiPortType.EBUS for p in used):
        return "ET1200"
    return "ET1100"


_SII_TO_REG_PORT = {
    SiiPortType.MII: PortType.MII,
    SiiPortType.EBUS: PortType.EBUS,
}


def profile_for(profile: EscProfile, info: SiiInfo) -> EscProfile:
    """``profile`` with its ports set as the SII's General category describes them.

    The chip decides which ports exist; the board (as its SII says) decides
    which of them are wired and whether as MII or E-Bus, so the SII wins: a
    port it marks unused becomes "not implemented" (or stays "not configured"
    where the chip reports its unused port so, as the ET1200's port 3 of a
    real EL1004 reads), a port it wires exists. An SII without port
    information keeps the chip's ports.
    """
    gen = info.general
    if gen is None or gen.physical_ports == 0:
        return profile
    ports = list(profile.ports)
    for n, sii_type in enumerate(gen.ports):
        reg = _SII_TO_REG_PORT.get(sii_type) if isinstance(sii_type, SiiPortType) else None
        if reg is None:
            keep = ports[n] == PortType.NOT_CONFIGURED
            ports[n] = PortType.NOT_CONFIGURED if keep else PortType.NOT_IMPLEMENTED
        else:
            ports[n] = reg
    if tuple(ports) == profile.ports:
        return profile
    return profile.replace(ports=tuple(ports))
