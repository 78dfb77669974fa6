"""Plain-text views of scanned slaves: the slave table, the verbose record, the tree.

Used by the command line (``pyethercat slaves [-v]``) and the demo. The
formats read well and split well: one slave per line in the table, with
whitespace-free columns; ``key: value`` lines in the verbose record.
"""

from __future__ import annotations

from collections.abc import Sequence

from pyethercat.master.slave_info import PORT_ORDER, SlaveInfo
from pyethercat.wire.registers import PortType
from pyethercat.wire.sii.model import CoeDetails, GeneralFlags

__all__ = ["slave_line", "slave_table", "slave_record", "topology_tree", "TABLE_HEADER",
           "igh_state", "alias_positions", "igh_slave_list"]

#: Column heads of :func:`slave_table` (``#`` so tools can skip the line).
TABLE_HEADER = "# pos  station/alias  state    flag  name"

_PORT_TYPE = {PortType.NOT_IMPLEMENTED: "-", PortType.NOT_CONFIGURED: "n/c",
              PortType.EBUS: "EBUS", PortType.MII: "MII"}


def _address(slave: SlaveInfo) -> str:
    return f"0x{slave.station_address:04X}/{slave.alias if slave.alias else '-'}"


def slave_line(slave: SlaveInfo) -> str:
    """``3  0x1004/-  PREOP  +  EL2004``: position, address/alias, state, flag, name.

    The flag is ``+`` when the slave shows no error, ``E`` when its AL
    status has the error flag set (the code follows the name then).
    """
    flag = "E" if slave.al_error else "+"
    text = (f"{slave.position:<5} {_address(slave):<14} {slave.al_state.name:<8} {flag:<5} "
            f"{slave.name}")
    if slave.al_error and slave.al_status_code:
        text += f"  [{slave.al_status_text}]"
    return text


def slave_table(slaves: Sequence[SlaveInfo], header: bool = True) -> str:
    """One line per slave (see :func:`slave_line`)."""
    lines = [TABLE_HEADER] if header else []
    lines += [slave_line(s) for s in slaves]
    return "\n".join(lines)


def _peer_text(slave: SlaveInfo, port: int) -> str:
    if port == 0 and slave.parent is None:
        return "master" if slave.ports[0].active else "-"
    peer = slave.ports[port].peer
    return f"slave {peer.position}" if peer is not None else "-"


def _dc_lines(slave: SlaveInfo, dc_delay_ns: int | None, dc_system_time: bool) -> list[str]:
    """IgH's two DC lines: support and width, and the transmission delay (0x0928)."""
    esc = slave.esc
    if not esc.dc_supported:
        return ["Distributed clocks: no"]
    if not dc_system_time:
        return ["Distributed clocks: yes, delay measurement only"]
    lines = [f"Distributed clocks: yes, {'64' if esc.dc_64bit else '32'} bit"]
    if dc_delay_ns is not None:
        lines.append(f"DC system time transmission delay: {dc_delay_ns} ns")
    return lines


def slave_record(slave: SlaveInfo, dc_delay_ns: int | None = None, dc_system_time: bool = True) -> str:
    """Everything known about one slave, ``key: value`` lines (``slaves -v``).

    ``dc_delay_ns``: its system time delay register 0x0928 as read now;
    ``dc_system_time``: False for a slave with receive-time latches only."""
    ident = slave.identity
    esc = slave.esc
    lines = [
        f"=== Slave {slave.position} ===",
        f"Name: {slave.name}",
        f"Station address: 0x{slave.station_address:04X}",
        f"Alias: {slave.alias}",
        f"State: {slave.al_state_name}",
        f"AL status code: {slave.al_status_text or '0x0000 No error'}",
        "Identity:",
        f"  Vendor ID: 0x{ident.vendor_id:08X}",
        f"  Product code: 0x{ident.product_code:08X}",
        f"  Revision: 0x{(ident.revision or 0):08X}",
        f"  Serial number: 0x{(ident.serial or 0):08X}",
        f"ESC: type 0x{esc.type:02X} revision {esc.revision} build 0x{esc.build:04X}, "
        f"{esc.fmmu_count} FMMUs, {esc.sm_count} SMs, {esc.ram_kib} KiB RAM",
        *_dc_lines(slave, dc_delay_ns, dc_system_time),
        f"LRW: {'yes' if slave.lrw_supported else 'no'}",
        "Ports:",
        "  port  type  link  loop    signal  peer",
    ]
    for p in slave.ports:
        lines.append(f"  {p.number:<5} {_PORT_TYPE.get(p.type, str(p.type)):<5} "
                     f"{'up' if p.link else 'down':<5} {'closed' if p.loop_closed else 'open':<7} "
                     f"{'yes' if p.communication else 'no':<7} {_peer_text(slave, p.number)}")
    if slave.parent is None:
        lines.append("Parent: master")
    else:
        lines.append(f"Parent: slave {slave.parent.position} port {slave.parent_port}")
    lines.append(f"Topology: {slave.topology_kind}")
    mb = slave.mailbox
    if mb is not None and slave.has_mailbox:
        lines += [
            "Mailbox:",
            f"  Receive (SM0): 0x{mb.rx_offset:04X}, {mb.rx_size} bytes",
            f"  Send (SM1): 0x{mb.tx_offset:04X}, {mb.tx_size} bytes",
            f"  Bootstrap receive: 0x{mb.boot_rx_offset:04X}, {mb.boot_rx_size} bytes",
            f"  Bootstrap send: 0x{mb.boot_tx_offset:04X}, {mb.boot_tx_size} bytes",
            f"  Protocols: {', '.join(mb.protocol_names) or '-'}",
        ]
    else:
        lines.append("Mailbox: none")
    sii = slave.sii
    if sii is None:
        lines.append(f"SII: {slave.sii_error or 'not read'}")
    else:
        gen = sii.general
        lines += [
            "SII:",
            f"  Size: {len(slave.sii_image)} bytes read, EEPROM {sii.eeprom_size_bytes} bytes",
            f"  Checksum: {'ok' if sii.checksum_ok else 'BAD'}",
            f"  Group: {sii.group_name or '-'}",
            f"  Image: {sii.image_name or '-'}",
            f"  Order number: {sii.order_number or '-'}",
            f"  Device name: {sii.device_name or '-'}",
        ]
        if gen is not None:
            coe = [f.name for f in CoeDetails if f.value and gen.coe_details & f and f.name]
            flags = [f.name for f in GeneralFlags if f.value and gen.flags & f and f.name]
            lines += [
                f"  CoE details: {', '.join(coe) or '-'}",
                f"  FoE: {'yes' if gen.foe_details & 1 else 'no'}",
                f"  EoE: {'yes' if gen.eoe_details & 1 else 'no'}",
                f"  Flags: {', '.join(flags) or '-'}",
                f"  E-bus current: {gen.ebus_current_ma} mA",
            ]
        lines += [
            f"  Sync managers: {len(sii.sync_managers)}",
            f"  RxPDOs: {len(sii.rx_pdos)} ({sii.output_bits} bits)",
            f"  TxPDOs: {len(sii.tx_pdos)} ({sii.input_bits} bits)",
            f"  DC modes: {len(sii.dc_modes)}",
        ]
    return "\n".join(lines)


def topology_tree(slaves: Sequence[SlaveInfo]) -> str:
    """The segment as a tree: which slave hangs on which port of which parent.

    ::

        master
        └─ 0 EK1100 (0x1001)
           ├─ port 3: 1 EL2004 (0x1002)
           └─ port 1: 2 EL1004 (0x1003)
              └─ port 1: 3 EL1008 (0x1004)
    """
    lines = ["master"]
    roots = [s for s in slaves if s.parent is None]

    def label(s: SlaveInfo, port: int | None) -> str:
        where = f"port {port}: " if port is not None else ""
        return f"{where}{s.position} {s.name} (0x{s.station_address:04X})"

    # Iterative depth-first walk (a line of 1000 slaves must not hit the recursion limit).
    stack: list[tuple[SlaveInfo, int | None, str, bool]] = [
        (s, None, "", n == len(roots) - 1) for n, s in reversed(list(enumerate(roots)))]
    while stack:
        slave, port, prefix, last = stack.pop()
        lines.append(f"{prefix}{'└─ ' if last else '├─ '}{label(slave, port)}")
        child_prefix = prefix + ("   " if last else "│  ")
        kids = [(p, c) for p, c in sorted(slave.children.items(),
                                          key=lambda kv: PORT_ORDER.index(kv[0]))]
        for n, (p, c) in reversed(list(enumerate(kids))):
            stack.append((c, p, child_prefix, n == len(kids) - 1))
    return "\n".join(lines)


def igh_state(state: int, error: bool) -> str:
    """A state as IgH's tool prints it: ``PREOP``, ``SAFEOP+ERROR``, ``???``."""
    names = {1: "INIT", 2: "PREOP", 3: "BOOT", 4: "SAFEOP", 8: "OP"}
    return names.get(state & 0x0F, "???") + ("+ERROR" if error else "")


def alias_positions(slaves: Sequence[SlaveInfo]) -> dict[int, tuple[int, int]]:
    """IgH's ``alias:relative position`` of every slave: the last alias met and the distance."""
    out: dict[int, tuple[int, int]] = {}
    alias, rel = 0, 0
    for s in slaves:
        if s.alias:
            alias, rel = s.alias, 0
        out[s.position] = (alias, rel)
        rel += 1
    return out


def igh_slave_list(slaves: Sequence[SlaveInfo], positions: Sequence[int] | None = None) -> list[str]:
    """``slaves`` lines exactly as IgH's ``ethercat slaves`` prints them.

    ``0  0:0  PREOP  +  EK1100 EtherCAT-Koppler (2A E-Bus)``: ring position,
    alias and position relative to it, state, flag (``+``, or ``E`` when the
    slave shows an AL error or its SII could not be read), name (or
    ``0xVENDOR:0xPRODUCT``). Columns are as wide as their widest entry. A
    slave with an AL error gets its status code after the name
    (``[0x001B Sync manager watchdog]``), which IgH's list does not show.
    """
    rel = alias_positions(slaves)
    chosen = set(positions) if positions is not None else None
    rows = []
    for s in slaves:
        if chosen is not None and s.position not in chosen:
            continue
        alias, pos = rel[s.position]
        name = s.name if s.sii is not None and s.name and s.name != "?" else (
            f"0x{s.identity.vendor_id:08x}:0x{s.identity.product_code:08x}")
        flag = "E" if s.al_error or s.sii_error else "+"
        if s.al_error and s.al_status_code:
            name += f"  [{s.al_status_text}]"
        rows.append((str(s.position), str(alias), str(pos), igh_state(int(s.al_state), s.al_error),
                     flag, name))
    if not rows:
        return []
    w = [max(len(r[k]) for r in rows) for k in range(4)]
    return [f"{r[0]:>{w[0]}}  {r[1]:>{w[1]}}:{r[2]:<{w[2]}}  {r[3]:<{w[3]}}  {r[4]}  {r[5]}"
            for r in rows]
