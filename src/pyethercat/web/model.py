"""What the dashboard shows, as JSON-able data: the segment, then each telemetry snapshot.

Pure functions and one small class, no I/O: :func:`describe_segment` turns
the master's scan (slaves rebuilt from the control socket's snapshots) and
its process-data configuration into the static part (identities, ports,
the tree, every PDO entry by name); :class:`LiveModel` turns each
:class:`~pyethercat.master.telemetry.TelemetrySnapshot` into the live part
(states with AL status text, per-port link state and error counters with
their rates, broken links, decoded process-data values, DC differences,
CiA 402 drives, events). The decoding runs here, in the dashboard's
process, never in the master's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pyethercat.master import diag
from pyethercat.master.config import PdoDirection, ProcessDataConfig
from pyethercat.master.image import ProcessImage, Variable, build_images
from pyethercat.master.slave import Slave
from pyethercat.master.slave_info import Port
from pyethercat.master.telemetry import TelemetrySnapshot
from pyethercat.wire import cia402
from pyethercat.wire.al import al_status_code_name, state_name

__all__ = ["describe_segment", "LiveModel", "format_value", "DRIVE_OBJECTS"]

#: CiA 402 objects the Drives page shows (index -> key), when a drive maps them.
DRIVE_OBJECTS = {
    0x6041: "statusword", 0x6040: "controlword", 0x6061: "mode", 0x6060: "mode_set",
    0x6064: "position", 0x607A: "target", 0x606C: "velocity", 0x6077: "torque",
    0x60F4: "following_error", 0x603F: "error_code",
}


def format_value(value: bool | int | float | bytes, bits: int) -> str:
    """A process-data value as the page prints it (``1``, ``-12``, ``0x00FF``, ``3.25``)."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    if isinstance(value, bytes):
        return value.hex(" ")
    return str(value)


@dataclass
class _Entry:
    position: int
    key: str
    var: Variable
    output: bool


def describe_segment(link: str, slaves: Sequence[Slave], config: ProcessDataConfig | None,
                     *, writable: bool, redundant: bool = False) -> dict[str, Any]:
    """The static part of the dashboard (sent once per page load and after a rescan)."""
    out: list[dict[str, Any]] = []
    for s in slaves:
        ident = s.identity
        ports = [{"n": p.number, "type": p.type.name.lower().replace("_", " "),
                  "implemented": p.implemented} for p in s.ports]
        children = {str(port): c.position for port, c in sorted(s.children.items())}
        mbx = s.mailbox
        out.append({
            "position": s.position, "name": s.name or "?", "station": s.station_address,
            "alias": s.alias, "vendor": ident.vendor_id, "product": ident.product_code,
            "revision": ident.revision, "serial": ident.serial,
            "esc": f"0x{s.esc.type:02X} rev {s.esc.revision}.{s.esc.build}",
            "ports": ports, "parent": s.parent.position if s.parent is not None else None,
            "parent_port": s.parent_port, "children": children,
            "mailbox": list(mbx.protocol_names) if mbx is not None else [],
            "coe": s.has_coe, "dc": s.dc_supported,
        })
    pdo: list[dict[str, Any]] = []
    drives: list[int] = []
    if config is not None:
        for pos, sc in sorted(config.slaves.items()):
            entries = [{"name": key, "index": v.info.index, "subindex": v.info.subindex,
                        "bits": v.bit_length, "type": v.type_name, "output": output,
                        "pdo": v.info.pdo_name}
                       for key, v, output in _entries_of(sc.variables)]
            if entries:
                pdo.append({"position": pos, "group": sc.group, "entries": entries})
            objects = {v.index for v in sc.variables}
            if {0x6040, 0x6041} <= objects:
                drives.append(pos)
    return {"link": link, "slaves": out, "pdo": pdo, "drives": drives, "writable": writable,
            "redundant": redundant, "configured": config is not None}


def _entries_of(variables: Sequence[Any]) -> list[tuple[str, Variable, bool]]:
    """(name the master's ``SlaveIO`` answers to, accessor, is output) in image order."""
    out: list[tuple[str, Variable, bool]] = []
    for direction in (PdoDirection.OUTPUTS, PdoDirection.INPUTS):
        chosen = [v for v in variables if v.direction is direction and v.index != 0]
        counts: dict[str, int] = {}
        for v in chosen:
            counts[v.name] = counts.get(v.name, 0) + 1
        for v in chosen:
            key = v.name if counts[v.name] == 1 else v.qualified_name
            out.append((key, Variable(v, bytearray(0)), direction is PdoDirection.OUTPUTS))
    return out


def _ports(dl: int | None, descriptor_ports: Sequence[Port]) -> list[dict[str, Any]]:
    out = []
    for p in descriptor_ports:
        if dl is None or not p.implemented:
            out.append({"n": p.number, "implemented": p.implemented, "known": False})
            continue
        now = Port.from_registers(p.number, 0, dl)
        out.append({"n": p.number, "implemented": True, "known": True, "link": now.link,
                    "loop_closed": now.loop_closed, "communication": now.communication})
    return out


class LiveModel:
    """Turns snapshots into the live JSON, keeping what rates and scopes need."""

    def __init__(self, slaves: Sequence[Slave], config: ProcessDataConfig | None) -> None:
        self.slaves = list(slaves)
        self.config = config
        self.images: dict[str, ProcessImage] = build_images(config) if config is not None else {}
        self._entries: list[tuple[int, list[tuple[str, Variable, bool]]]] = []
        self._drive_vars: dict[int, dict[str, Variable]] = {}
        if config is not None:
            for pos, sc in sorted(config.slaves.items()):
                buf = self.images[sc.group].buffer
                bound = [(key, Variable(v.info, buf), out)
                         for key, v, out in _entries_of(sc.variables)]
                self._entries.append((pos, bound))
                if {0x6040, 0x6041} <= {v.index for v in sc.variables}:
                    self._drive_vars[pos] = {
                        DRIVE_OBJECTS[v.index]: Variable(v, buf) for v in sc.variables
                        if v.index in DRIVE_OBJECTS}
        self._last_counters: dict[int, tuple[float, diag.SlaveCounters]] = {}
        self._rates: dict[int, list[float]] = {}
        #: (from, port, to) of each cable broken now -> (snapshot time, push) it was first seen.
        self._broken_since: dict[tuple[int | None, int | None, int], tuple[float, int]] = {}

    # -- one snapshot ----------------------------------------------------------------------

    def live(self, snap: TelemetrySnapshot, push: int = 0) -> dict[str, Any]:
        """The live part of the dashboard for one snapshot, the ``push``-th sent to browsers."""
        for g in snap.groups:
            img = self.images.get(g.name)
            if img is not None and len(img.buffer) == len(g.image):
                img.buffer[:] = g.image
        slaves = [self._slave(t, snap.registers_time) for t in snap.slaves]
        links = self._links(slaves, snap, push)
        return {
            "time": snap.time, "seq": snap.seq, "push": push, "cycle": _cycle(snap),
            "groups": [{"name": g.name, "wkc": g.wkc, "expected": g.expected_wkc, "ok": g.wkc_ok,
                        "errors": g.wkc_errors, "lost": g.lost, "exchanges": g.exchanges}
                       for g in snap.groups],
            "slaves": slaves, "links": links, "values": self._values(snap),
            "drives": self._drives(snap), "dc": _dc(snap), "events": [
                {"seq": e.seq, "time": e.time, "kind": e.kind, "text": e.text,
                 "position": e.position, "code": e.code, "register": e.register, "data": e.data}
                for e in snap.events],
            "registers_time": snap.registers_time, "registers_error": snap.registers_error,
            "faults": [{"kind": f.kind, "text": f.text, "ends": f.ends, "slaves": f.slaves,
                        "detail": f.detail} for f in snap.faults],
            "ports": [{"name": p.name, "carrier": p.carrier, "returning": p.returning,
                       "sent": p.sent, "received": p.received, "missing": p.missing}
                      for p in snap.ports],
            "ring_state": snap.ring_state,
        }

    def _slave(self, t: Any, at: float) -> dict[str, Any]:
        s = self.slaves[t.position] if t.position < len(self.slaves) else None
        ports = _ports(t.dl_status, s.ports if s is not None else [Port(n) for n in range(4)])
        counters = None
        rates: list[float] | None = None
        if t.counters is not None:
            c = diag.decode_error_counters(t.position, t.station_address, t.counters)
            counters = {"ports": [[p.invalid_frames, p.rx_errors, p.forwarded_rx_errors,
                                   p.lost_links] for p in c.ports],
                        "epu": c.processing_unit_errors, "pdi": c.pdi_errors, "total": c.total}
            rates = self._rate(t.position, at, c)
        health = t.supervision or ("ok" if t.answered else "no answer")
        if not t.answered:
            health = t.supervision if t.supervision not in ("", "ok") else "lost"
        return {
            "position": t.position, "state": state_name(t.state),
            "state_full": state_name(t.state | (0x10 if t.error else 0)), "error": t.error,
            "code": t.code, "code_text": al_status_code_name(t.code) if t.code else "",
            "answered": t.answered, "health": health, "recoveries": t.recoveries,
            "ports": ports, "counters": counters, "rates": rates,
            "dc_difference_ns": t.dc_difference_ns, "side": t.side,
        }

    def _rate(self, position: int, at: float, c: diag.SlaveCounters) -> list[float]:
        """Errors per second per port since the previous reading (counters saturate at 255)."""
        prev = self._last_counters.get(position)
        if prev is None or at <= prev[0]:
            if prev is None:
                self._last_counters[position] = (at, c)
            return self._rates.get(position, [0.0] * 4)
        dt = at - prev[0]
        rates = [max(0, now.total - before.total) / dt
                 for now, before in zip(c.ports, prev[1].ports, strict=True)]
        self._last_counters[position] = (at, c)
        self._rates[position] = rates
        return rates

    def _links(self, slaves: list[dict[str, Any]], snap: TelemetrySnapshot, push: int
               ) -> list[dict[str, Any]]:
        """Every cable of the scanned tree and whether it is broken now.

        A cable is broken when the ring service located a fault on it, when
        the slave before it answers but shows no link on that port, or when
        that slave answers and the one behind it does not. A broken cable
        carries the time and push number of the first snapshot that showed
        it broken (``since``, ``since_push``): the page prints it, and it is
        the dashboard's own measure of how soon it saw a cut.
        """
        located: dict[tuple[int, int], str] = {}
        for f in snap.faults:
            if f.kind in ("link", "cut", "port", "crc"):
                for end in f.ends:
                    located[(end[0], end[1])] = f"{f.kind}: {f.text}"
        out = []
        for s in self.slaves:
            if s.position >= len(slaves) or (s.parent is not None
                                             and s.parent.position >= len(slaves)):
                continue  # the master scanned again; the next segment message has it
            me = slaves[s.position]
            if s.parent is None or s.parent_port is None:
                fault = located.get((-1, 0)) or located.get((s.position, 0))
                broken = bool(fault) or not me["answered"]
                out.append({"from": None, "port": None, "to": s.position, "to_port": 0,
                            "broken": broken, "fault": fault or "",
                            **self._since((None, None, s.position), broken, snap.time, push)})
                continue
            parent = slaves[s.parent.position]
            port = next((p for p in parent["ports"] if p["n"] == s.parent_port), None)
            no_link = bool(port and port.get("known") and not port.get("link"))
            fault = located.get((s.parent.position, s.parent_port)) or located.get((s.position, 0))
            crc = bool(fault) and fault is not None and fault.startswith("crc")
            broken = (bool(fault) and not crc) or (parent["answered"] and (no_link or not me["answered"]))
            out.append({"from": s.parent.position, "port": s.parent_port, "to": s.position,
                        "to_port": 0, "broken": broken, "crc": crc, "fault": fault or "",
                        **self._since((s.parent.position, s.parent_port, s.position), broken,
                                      snap.time, push)})
        return out

    def _since(self, key: tuple[int | None, int | None, int], broken: bool, at: float,
               push: int) -> dict[str, Any]:
        if not broken:
            self._broken_since.pop(key, None)
            return {"since": None, "since_push": None}
        first = self._broken_since.setdefault(key, (at, push))
        return {"since": first[0], "since_push": first[1]}

    def _values(self, snap: TelemetrySnapshot) -> dict[str, list[list[str]]]:
        if not snap.groups:
            return {}
        out: dict[str, list[list[str]]] = {}
        for pos, bound in self._entries:
            out[str(pos)] = [[key, format_value(v.get(), v.bit_length)] for key, v, _o in bound]
        return out

    def _drives(self, snap: TelemetrySnapshot) -> list[dict[str, Any]]:
        if not snap.groups:
            return []
        out = []
        for pos, vars_ in sorted(self._drive_vars.items()):
            values = {k: v.get() for k, v in vars_.items()}
            sw = int(values.get("statusword", 0))
            state = None
            mode = None
            st = cia402.decode_state(sw)
            state = st.name.replace("_", " ").lower() if st is not None else "unknown"
            m = values.get("mode")
            if m is not None:
                try:
                    mode = cia402.OperationMode(int(m)).name
                except ValueError:
                    mode = str(m)
            fe = values.get("following_error")
            if fe is None and "target" in values and "position" in values:
                fe = int(values["target"]) - int(values["position"])
            out.append({"position": pos, "statusword": sw, "state": state, "mode": mode,
                        "mode_value": values.get("mode"),
                        "position_actual": values.get("position"),
                        "target": values.get("target"), "velocity": values.get("velocity"),
                        "torque": values.get("torque"), "following_error": fe,
                        "error_code": values.get("error_code")})
        return out


def _cycle(snap: TelemetrySnapshot) -> dict[str, Any]:
    c = snap.cycle

    def num(x: float) -> float | None:
        return None if math.isnan(x) else round(x, 2)

    return {"running": c.running, "period_us": c.period_us, "cycles": c.cycles, "late": c.late,
            "overruns": c.overruns, "skipped": c.skipped, "wkc_errors": c.wkc_errors,
            "lost_frames": c.lost_frames, "frames": c.frames, "bins_us": c.bins_us,
            "histogram": c.histogram, "window": c.window,
            "period_mean_us": num(c.period_mean_us), "period_min_us": num(c.period_min_us),
            "period_max_us": num(c.period_max_us), "jitter_p50_us": num(c.jitter_p50_us),
            "jitter_p99_us": num(c.jitter_p99_us), "jitter_max_us": num(c.jitter_max_us),
            "rtt_p50_us": num(c.rtt_p50_us), "rtt_p99_us": num(c.rtt_p99_us),
            "rtt_max_us": num(c.rtt_max_us), "link_up": c.link_up, "link_downs": c.link_downs}


def _dc(snap: TelemetrySnapshot) -> dict[str, Any]:
    d = snap.dc
    return {"set_up": d.set_up, "reference": d.reference, "mode": d.mode,
            "phase_error_ns": d.phase_error_ns, "locked": d.locked,
            "monitor_last_ns": d.monitor_last_ns, "monitor_worst_ns": d.monitor_worst_ns,
            "unstable": d.unstable,
            "slaves": [{"position": s.position, "kind": s.kind, "reference": s.reference,
                        "delay_ns": s.delay_ns, "offset_ns": s.offset_ns} for s in d.slaves]}
