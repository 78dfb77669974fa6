"""The topology file format, shared by the simulator and the master.

A topology file (TOML, documented with examples in ``docs/simulator.md``)
describes a segment: its slaves in ring order, wires from outputs to inputs,
faults, and frame drops. The simulator builds a segment from it
(``sim.topology``); the master takes it as the expected network
(``master.esi_config.expected_from_topology``). Both read it through
:func:`parse_topology_text`, which checks the document itself: known keys,
types, ranges, unique names, references to slaves that exist. It takes text
and does no I/O: reading the file, the SII images and ESI files the entries
name, and what depends on them (ports, process-data sizes) is each side's
business.

Format::

    [segment]                       # optional
    drop_probability = 0.0          # frames lost on the wire, 0..1
    seed = 1                        # random seed for the drops
    drift_ppm = 100.0               # slaves without drift_ppm draw theirs from
    drift_seed = 0                  #   +-drift_ppm with this seed (0.0: all exact)
    ring = true                     # cable redundancy: the master's second port is cabled
                                    #   to the last slave's free port (or "SLAVE:PORT")

    [[slave]]
    name = "coupler"                # unique; used by parent/wire/fault
    device = "builtin:coupler"      # or sii = "dump.bin" (relative to the file)
                                    # or esi = "dev.xml" with product/revision
                                    #   (esi = "builtin:NAME": an ESI shipped with pyethercat)
    alias, profile, drift_ppm, forwarding_delay_ns, cable_delay_ns, inputs,
    serial, parent + port           # optional (see docs/simulator.md)
    foe, foe_dir, foe_password, foe_busy_every, foe_wrap, foe_max_size,
    firmware_password, soe          # FoE/SoE servers (docs/foe.md, docs/soe.md)

    [[wire]]  from = "do8:0"  to = "di8:0"  bits = 8
    [[fault]] kind = "break_link" | "power_off" | "corrupt", slave, port, count

Every error raises :class:`~pyethercat.errors.ConfigError` naming the file
and the slave (or wire, fault) it concerns.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from typing import Any, Generic, Literal, Protocol, TypeVar

from pyethercat.errors import ConfigError

__all__ = [
    "DEFAULT_DRIFT_PPM",
    "FAULT_KINDS",
    "FaultEntry",
    "SegmentDoc",
    "SlaveEntry",
    "TopologyDoc",
    "WireEntry",
    "parse_topology_text",
]

SourceKind = Literal["device", "sii", "esi"]

_SLAVE_KEYS = {
    "name", "device", "sii", "esi", "product", "revision", "alias", "profile", "drift_ppm",
    "forwarding_delay_ns", "cable_delay_ns", "inputs", "parent", "port", "serial", "eoe",
    "foe", "foe_dir", "foe_password", "foe_busy_every", "foe_wrap", "foe_max_size",
    "firmware_password", "soe",
}
#: Keys that tune the FoE server (meaningless with ``foe = false``).
_FOE_TUNING = ("foe_dir", "foe_password", "foe_busy_every", "foe_wrap", "foe_max_size",
               "firmware_password")
#: Keys of a slave's ``eoe = {...}`` table (its IP side; see docs/eoe.md).
_EOE_KEYS = {"ip", "gateway", "mac", "netns", "http_port"}
_WIRE_KEYS = {"from", "to", "bits"}
_FAULT_KEYS = {"kind", "slave", "port", "count"}
FAULT_KINDS = ("break_link", "power_off", "corrupt")
_SEGMENT_KEYS = {"drop_probability", "seed", "drift_ppm", "drift_seed", "ring"}
#: Oscillators of slaves without their own ``drift_ppm`` deviate by up to this
#: (uniformly drawn with ``drift_seed``): the tolerance of common quartzes.
DEFAULT_DRIFT_PPM = 100.0
_TOP_KEYS = {"slave", "wire", "fault", "segment"}


@dataclass(frozen=True)
class SlaveEntry:
    """One ``[[slave]]`` table as written (checked, nothing looked up).

    ``kind`` says what ``source`` is: ``"device"`` a built-in key (the text
    after ``builtin:``), ``"sii"``/``"esi"`` a path as written (relative to the
    file's folder). ``parent``/``port`` are given only for a tree branch.
    """

    name: str
    kind: SourceKind
    source: str
    serial: int
    product: int | None = None
    revision: int | None = None
    alias: int | None = None
    profile: str | None = None
    #: None: drawn from the segment's ``drift_ppm`` / ``drift_seed``.
    drift_ppm: float | None = None
    forwarding_delay_ns: int | None = None
    cable_delay_ns: int = 5
    inputs: bytes | None = None
    parent: str | None = None
    port: int | None = None
    #: ``eoe = {...}`` as written (keys checked; the simulator reads the values).
    eoe: dict[str, Any] | None = None
    #: FoE/SoE servers: None as the SII announces (see docs/foe.md, docs/soe.md).
    foe: bool | None = None
    soe: bool | None = None
    #: ``foe_dir`` as written (relative to the file's folder).
    foe_dir: str | None = None
    foe_password: int = 0
    foe_busy_every: int = 0
    foe_wrap: int | None = None
    foe_max_size: int | None = None
    firmware_password: int = 0

    @property
    def written_source(self) -> str:
        """The source as the file writes it (``builtin:di8``, or the path)."""
        return f"builtin:{self.source}" if self.kind == "device" else self.source


@dataclass(frozen=True)
class WireEntry:
    """One ``[[wire]]``: output bit ``src_bit`` of ``src`` on, ``bits`` bits (None: as many as fit)."""

    src: str
    src_bit: int
    dst: str
    dst_bit: int
    bits: int | None


@dataclass(frozen=True)
class FaultEntry:
    """One ``[[fault]]`` (applied when the segment is built)."""

    kind: str
    slave: str
    port: int = 0
    count: int = 1


class _Named(Protocol):
    @property
    def name(self) -> str: ...


SlaveT = TypeVar("SlaveT", bound=_Named)
WireT = TypeVar("WireT")


@dataclass
class SegmentDoc(Generic[SlaveT, WireT]):
    """A topology's slaves, wires and faults with the segment-wide settings.

    As the file writes it (:class:`TopologyDoc`) or resolved by the simulator
    (``pyethercat.sim.topology.Topology``), which keep the same settings.
    """

    source: str
    slaves: list[SlaveT] = field(default_factory=list)
    wires: list[WireT] = field(default_factory=list)
    faults: list[FaultEntry] = field(default_factory=list)
    drop_probability: float = 0.0
    seed: int | None = None
    drift_ppm: float = DEFAULT_DRIFT_PPM
    drift_seed: int = 0
    #: Cable redundancy: master port B cabled to the last slave (True) or to (slave, port).
    ring: bool | tuple[str, int] = False

    def index(self, name: str) -> int:
        """Position of slave ``name`` (0 = first slave)."""
        for i, s in enumerate(self.slaves):
            if s.name == name:
                return i
        raise ConfigError(f"{self.source}: no slave named {name!r}")


@dataclass
class TopologyDoc(SegmentDoc[SlaveEntry, WireEntry]):
    """A checked topology document."""


# --- values ----------------------------------------------------------------------------


def _check_keys(raw: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = set(raw) - allowed
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} "
                          f"(allowed: {', '.join(sorted(allowed))})")


def to_int(value: Any, where: str, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (or a string of one, any base prefix) within [lo, hi]."""
    if isinstance(value, str):
        try:
            value = int(value, 0)
        except ValueError:
            raise ConfigError(f"{where}: {value!r} is not a number") from None
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: expected an integer, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ConfigError(f"{where}: {value} is out of range {lo}..{hi}")
    return value


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    return float(value)


def _str(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: expected a non-empty string, got {value!r}")
    return value


def _table_list(doc: dict[str, Any], key: str, source: str) -> list[dict[str, Any]]:
    value = doc.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ConfigError(f"{source}: {key!r} must be an array of tables ([[{key}]])")
    return value


# --- the document ------------------------------------------------------------------------


def parse_topology_text(text: str | dict[str, Any], source: str = "<topology>") -> TopologyDoc:
    """Parse and check topology TOML text (or an already-parsed dict)."""
    if isinstance(text, str):
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{source}: not valid TOML: {exc}") from exc
    else:
        raw = text
    unknown = set(raw) - _TOP_KEYS
    if unknown:
        raise ConfigError(f"{source}: unknown top-level key(s) {', '.join(sorted(unknown))} "
                          f"(expected [[slave]], [[wire]], [[fault]], [segment])")
    doc = TopologyDoc(source=source)
    seg = raw.get("segment", {})
    if not isinstance(seg, dict):
        raise ConfigError(f"{source}: [segment] must be a table")
    _check_keys(seg, _SEGMENT_KEYS, f"{source}: [segment]")
    if "drop_probability" in seg:
        p = _number(seg["drop_probability"], f"{source}: [segment] drop_probability")
        if not 0.0 <= p <= 1.0:
            raise ConfigError(f"{source}: [segment] drop_probability {p} is not within 0..1")
        doc.drop_probability = p
    if "seed" in seg:
        doc.seed = to_int(seg["seed"], f"{source}: [segment] seed")
    if "drift_ppm" in seg:
        doc.drift_ppm = abs(_number(seg["drift_ppm"], f"{source}: [segment] drift_ppm"))
    if "drift_seed" in seg:
        doc.drift_seed = to_int(seg["drift_seed"], f"{source}: [segment] drift_seed")
    if "ring" in seg:
        doc.ring = _ring(seg["ring"], f"{source}: [segment] ring")
    slaves = _table_list(raw, "slave", source)
    if not slaves:
        raise ConfigError(f"{source}: no [[slave]] tables: a segment needs at least one slave")
    seen: set[str] = set()
    for i, table in enumerate(slaves):
        doc.slaves.append(_slave(table, i, doc, seen))
    if doc.slaves[0].parent is not None:
        raise ConfigError(f"{source}: slave {doc.slaves[0].name!r}: the first slave is connected "
                          "to the master, it has no parent")
    position = {s.name: i for i, s in enumerate(doc.slaves)}
    if isinstance(doc.ring, tuple) and doc.ring[0] not in position:
        raise ConfigError(f"{source}: [segment] ring: no slave named {doc.ring[0]!r}")
    for i, s in enumerate(doc.slaves):
        if s.parent is not None and position.get(s.parent, i) >= i:
            where = f"{source}: slave {s.name!r}"
            if s.parent in position:
                raise ConfigError(f"{where}: parent {s.parent!r} must come earlier in the file")
            raise ConfigError(f"{where}: parent {s.parent!r} is not a slave of this file")
    for i, table in enumerate(_table_list(raw, "wire", source)):
        doc.wires.append(_wire(table, i, doc))
    for i, table in enumerate(_table_list(raw, "fault", source)):
        doc.faults.append(_fault(table, i, doc))
    return doc


def _slave(raw: dict[str, Any], i: int, doc: TopologyDoc, names: set[str]) -> SlaveEntry:
    src = doc.source
    label = f"{src}: slave #{i + 1}"
    name = _str(raw.get("name", ""), f"{label}: name") if "name" in raw else ""
    if not name:
        raise ConfigError(f"{label}: every [[slave]] needs a name")
    where = f"{src}: slave {name!r}"
    _check_keys(raw, _SLAVE_KEYS, where)
    if name in names:
        raise ConfigError(f"{where}: the name is used twice")
    names.add(name)
    kinds = [k for k in ("device", "sii", "esi") if k in raw]
    if len(kinds) != 1:
        raise ConfigError(f"{where}: give exactly one of device = \"builtin:...\", sii = ..., esi = ...")
    kind: SourceKind = kinds[0]
    source = _str(raw[kind], f"{where}: {kind}")
    if kind == "device":
        if not source.startswith("builtin:"):
            raise ConfigError(f"{where}: device {source!r} must be \"builtin:<name>\"")
        source = source.removeprefix("builtin:")
    if ("product" in raw or "revision" in raw) and kind != "esi":
        raise ConfigError(f"{where}: product/revision only go with esi = ...")
    opt: dict[str, Any] = {}
    if "product" in raw:
        opt["product"] = to_int(raw["product"], f"{where}: product")
    if "revision" in raw:
        opt["revision"] = to_int(raw["revision"], f"{where}: revision")
    if "alias" in raw:
        opt["alias"] = to_int(raw["alias"], f"{where}: alias", 0, 0xFFFF)
    if "profile" in raw:
        opt["profile"] = _str(raw["profile"], f"{where}: profile")
    if "drift_ppm" in raw:
        opt["drift_ppm"] = _number(raw["drift_ppm"], f"{where}: drift_ppm")
    if "forwarding_delay_ns" in raw:
        opt["forwarding_delay_ns"] = to_int(raw["forwarding_delay_ns"], f"{where}: forwarding_delay_ns", 0)
    if "cable_delay_ns" in raw:
        opt["cable_delay_ns"] = to_int(raw["cable_delay_ns"], f"{where}: cable_delay_ns", 0)
    if "inputs" in raw:
        text = _str(raw["inputs"], f"{where}: inputs").replace(" ", "")
        try:
            opt["inputs"] = bytes.fromhex(text.removeprefix("0x"))
        except ValueError:
            raise ConfigError(f"{where}: inputs {raw['inputs']!r} is not hex bytes") from None
    if "parent" in raw:
        opt["parent"] = _str(raw["parent"], f"{where}: parent")
        if "port" not in raw:
            raise ConfigError(f"{where}: parent needs a port (1, 2 or 3)")
    if "port" in raw:
        if "parent" not in raw:
            raise ConfigError(f"{where}: port needs a parent")
        opt["port"] = to_int(raw["port"], f"{where}: port", 1, 3)
    if "eoe" in raw:
        if not isinstance(raw["eoe"], dict):
            raise ConfigError(f"{where}: eoe: expected a table like {{ ip = \"192.168.100.10/24\" }}")
        _check_keys(raw["eoe"], _EOE_KEYS, f"{where}: eoe")
        opt["eoe"] = dict(raw["eoe"])
    opt.update(_mailbox_keys(raw, where))
    serial = to_int(raw.get("serial", i + 1), f"{where}: serial", 0, 0xFFFFFFFF)
    return SlaveEntry(name, kind, source, serial, **opt)


def _flag(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{where}: expected true or false, got {value!r}")
    return value


def _mailbox_keys(raw: dict[str, Any], where: str) -> dict[str, Any]:
    """The ``foe*``/``soe`` keys of a slave, checked."""
    opt: dict[str, Any] = {}
    for key in ("foe", "soe"):
        if key in raw:
            opt[key] = _flag(raw[key], f"{where}: {key}")
    if "foe_dir" in raw:
        opt["foe_dir"] = _str(raw["foe_dir"], f"{where}: foe_dir")
    for key in ("foe_password", "firmware_password"):
        if key in raw:
            opt[key] = to_int(raw[key], f"{where}: {key}", 0, 0xFFFFFFFF)
    if "foe_busy_every" in raw:
        opt["foe_busy_every"] = to_int(raw["foe_busy_every"], f"{where}: foe_busy_every", 0)
    if "foe_wrap" in raw:
        opt["foe_wrap"] = to_int(raw["foe_wrap"], f"{where}: foe_wrap", 2, 1 << 32)
    if "foe_max_size" in raw:
        opt["foe_max_size"] = to_int(raw["foe_max_size"], f"{where}: foe_max_size", 0)
    tuned = [k for k in _FOE_TUNING if k in raw]
    if tuned and opt.get("foe") is False:
        raise ConfigError(f"{where}: {', '.join(sorted(tuned))} given with foe = false")
    return opt


def _endpoint(text: Any, where: str, doc: TopologyDoc) -> tuple[str, int]:
    value = _str(text, where)
    name, _, bit = value.partition(":")
    if name not in (s.name for s in doc.slaves):
        raise ConfigError(f"{where}: no slave named {name!r}")
    return name, (to_int(bit, where, 0) if bit else 0)


def _wire(raw: dict[str, Any], i: int, doc: TopologyDoc) -> WireEntry:
    where = f"{doc.source}: wire #{i + 1}"
    _check_keys(raw, _WIRE_KEYS, where)
    if "from" not in raw or "to" not in raw:
        raise ConfigError(f"{where}: needs from = \"slave:bit\" and to = \"slave:bit\"")
    src, sbit = _endpoint(raw["from"], f"{where}: from", doc)
    dst, dbit = _endpoint(raw["to"], f"{where}: to", doc)
    bits = to_int(raw["bits"], f"{where}: bits", 1) if "bits" in raw else None
    return WireEntry(src, sbit, dst, dbit, bits)


def _fault(raw: dict[str, Any], i: int, doc: TopologyDoc) -> FaultEntry:
    where = f"{doc.source}: fault #{i + 1}"
    _check_keys(raw, _FAULT_KEYS, where)
    kind = _str(raw.get("kind", ""), f"{where}: kind") if "kind" in raw else ""
    if kind not in FAULT_KINDS:
        raise ConfigError(f"{where}: kind must be one of {', '.join(FAULT_KINDS)}")
    if "slave" not in raw:
        raise ConfigError(f"{where}: needs slave = \"name\"")
    slave = _str(raw["slave"], f"{where}: slave")
    doc.index(slave)
    port = 0
    if kind in ("break_link", "corrupt"):
        if "port" not in raw:
            raise ConfigError(f"{where}: {kind} needs a port (0-3)")
        port = to_int(raw["port"], f"{where}: port", 0, 3)
        if kind == "break_link" and port == 0 and doc.index(slave) == 0:
            raise ConfigError(f"{where}: port 0 of the first slave {slave!r} is the master's "
                              "cable; broken, no slave would answer (cut it at run time "
                              "with the control socket instead)")
    count = to_int(raw.get("count", 1), f"{where}: count", 1)
    return FaultEntry(kind, slave, port, count)


def _ring(value: Any, where: str) -> bool | tuple[str, int]:
    """``ring = true`` (the last slave's free port) or ``ring = "NAME:PORT"``."""
    if isinstance(value, bool):
        return value
    text = _str(value, where)
    name, sep, port = text.rpartition(":")
    if not sep or not name:
        raise ConfigError(f"{where}: {text!r}: use true or \"SLAVE:PORT\"")
    return name, to_int(port, f"{where} port", 1, 3)
