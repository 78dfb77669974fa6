"""ESI and ENI commands: ``esi show``, ``esi sii``, ``xml``, ``eni export``, ``eni import``.

``esi show FILE [--product X] [--revision Y]``: the devices of an ESI file, or
one device in detail. ``esi sii FILE --product X [--revision Y] -o eeprom.bin``:
the SII image of a device (``--compare VENDOR.bin`` lists the fields that differ
from another image). ``xml -p POS [-o FILE]``: an ESI file for a live slave,
from its SII and (over CoE SDO information, when it has it) its dictionary.
``eni export -o FILE``: scan, configure and write the network as ENI.
``eni import FILE``: start from an ENI (identities checked, no SII read) and
show what was configured.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from pyethercat.cli._select import selection_options, single
from pyethercat.cli._session import own_master
from pyethercat.cli._util import number, parse_int
from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.esi.model import EsiDevice, EsiFile

__all__ = ["register"]


def _int(value: str | None) -> int | None:
    return None if value is None else parse_int(value)


def _esi_path(name: str) -> Path:
    """A file path, or ``builtin:NAME`` for an ESI shipped with pyethercat."""
    if name.startswith("builtin:"):
        from pyethercat.esi.bundled import SEED002_DRIVE, bundled_esi

        return bundled_esi(name.removeprefix("builtin:") or SEED002_DRIVE)
    return Path(name)


def format_device_list(esi: EsiFile) -> str:
    """One line per device revision."""
    lines = [f"vendor 0x{esi.vendor.id:08X} {esi.vendor.name}: {len(esi)} device(s)"]
    for d in esi:
        lay = d.pdo_layout()
        protos = ",".join(d.mailbox.protocols) if d.mailbox else "-"
        lines.append(
            f"  0x{d.product_code:08X} rev 0x{d.revision:08X}  {d.type_name:<16} "
            f"out {lay.output_bits:>4} bit  in {lay.input_bits:>4} bit  mbx {protos:<10} "
            f"{d.name.pick()}"
        )
    return "\n".join(lines)


def format_device(esi: EsiFile, d: EsiDevice) -> str:
    """A device in detail: identity, SMs, FMMUs, PDOs, mailbox, InitCmds, DC, EEPROM."""
    out = [
        f"{d.type_name}: {d.name.pick()}",
        f"  vendor 0x{esi.vendor.id:08X} product 0x{d.product_code:08X} "
        f"revision 0x{d.revision:08X}  group {d.group_type or '-'}  physics {d.physics or '-'}",
    ]
    for s in d.sms:
        out.append(
            f"  SM{s.index}: {s.name or '-':<8} start 0x{s.start_address or 0:04X} "
            f"size {s.default_size or 0:>4} control 0x{s.control_byte or 0:02X}"
            f"{'' if s.enable else ' (disabled)'}"
        )
    if d.fmmus:
        out.append("  FMMUs: " + ", ".join(f.name for f in d.fmmus))
    default = {p.index for s in d.pdo_layout().sms for p in s.pdos}
    for p in d.pdos:
        flags = [x for x, on in (("fixed", p.fixed), ("mandatory", p.mandatory),
                                 ("default", p.index in default)) if on]  # fmt: skip
        excl = " excludes " + ",".join(f"0x{x:04X}" for x in p.excludes) if p.excludes else ""
        out.append(
            f"  {'RxPDO' if p.direction == 'rx' else 'TxPDO'} 0x{p.index:04X} "
            f"{p.name.pick()!r} sm {p.sm if p.sm is not None else '-'} {p.bit_size} bit "
            f"[{' '.join(flags)}]{excl}"
        )
        for e in p.entries:
            out.append(
                f"      0x{e.index:04X}:{e.subindex:02X} {e.bit_len:>3} bit "
                f"{e.data_type or '-':<8} {e.name.pick()}"
            )
    if d.mailbox is not None:
        m = d.mailbox
        out.append(f"  mailbox: {', '.join(m.protocols) or '-'}"
                   f"{' (data link layer)' if m.data_link_layer else ''}")  # fmt: skip
        if m.coe is not None:
            c = m.coe
            flags = [n for n, on in (("SdoInfo", c.sdo_info), ("PdoAssign", c.pdo_assign),
                                     ("PdoConfig", c.pdo_config), ("PdoUpload", c.pdo_upload),
                                     ("CompleteAccess", c.complete_access),
                                     ("SegmentedSdo", c.segmented_sdo)) if on]  # fmt: skip
            if c.ds402_channels:
                flags.append(f"DS402Channels={c.ds402_channels}")
            out.append(f"  CoE: {' '.join(flags) or '-'}")
            for ic in c.init_cmds:
                out.append(
                    f"  InitCmd {'/'.join(ic.transitions)} 0x{ic.index:04X}:{ic.subindex:02X} "
                    f"= {ic.data.hex() or '-'}  {ic.comment or ''}".rstrip()
                )
    if d.dc is not None:
        for mode in d.dc.op_modes:
            out.append(f"  DC op mode {mode.name!r}: AssignActivate 0x{mode.assign_activate:04X}"
                       f" {mode.desc or ''}".rstrip())  # fmt: skip
    if d.eeprom is not None:
        ee = d.eeprom
        out.append(f"  EEPROM: {ee.byte_size or '-'} bytes, ConfigData "
                   f"{ee.config_data.hex() if ee.config_data else '-'}")  # fmt: skip
    od = d.dictionary
    if od is not None:
        out.append(f"  dictionary: {len(od.objects)} objects")
    return "\n".join(out)


def register(cli: click.Group) -> None:
    """Add the ``esi``, ``xml`` and ``eni`` commands."""

    @cli.group("esi")
    def esi_group() -> None:
        """ESI device description files."""

    @esi_group.command("show")
    @click.argument("file")
    @click.option("--product", help="Product code (0x hex ok): show this device in detail.")
    @click.option("--revision", help="Revision (default: the highest).")
    def esi_show(file: str, product: str | None, revision: str | None) -> None:
        """List the devices of FILE, or one in detail (builtin:seed002_drive.xml works too)."""
        from pyethercat.esi.parse import load_esi

        if revision is not None and product is None:
            raise ConfigError("esi show: --revision needs --product (which device's revision)")
        esi = load_esi(_esi_path(file))
        if product is None:
            click.echo(format_device_list(esi))
            return
        prod = _int(product)
        assert prod is not None
        click.echo(format_device(esi, esi.find_device(prod, _int(revision))))

    @esi_group.command("sii")
    @click.argument("file")
    @click.option("--product", help="Product code (needed when the file has several products).")
    @click.option("--revision", help="Revision (default: the highest).")
    @click.option("-o", "--output", required=True, help="Where to write the EEPROM image.")
    @click.option("--serial", default="0", help="Serial number to write (default 0).")
    @click.option("--no-pdos", is_flag=True, help="Leave the PDO categories out.")
    @click.option("--compare", metavar="IMAGE", help="Also list differences from this image.")
    def esi_sii(file: str, product: str | None, revision: str | None, output: str,
                serial: str, no_pdos: bool, compare: str | None) -> None:  # fmt: skip
        """Write the SII (EEPROM) image of a device of FILE."""
        from pyethercat.esi.parse import load_esi
        from pyethercat.esi.sii_from_esi import esi_to_sii, pick_device, sii_differences
        from pyethercat.wire.sii import parse_sii

        serial_no = number(serial, "--serial", 0xFFFFFFFF)  # SII words 0x0E-0x0F: 32 bits
        esi = load_esi(_esi_path(file))
        dev = pick_device(esi, _int(product), _int(revision))
        res = esi_to_sii(dev, vendor_id=esi.vendor.id, serial=serial_no,
                         include_pdos=False if no_pdos else None)  # fmt: skip
        try:
            Path(output).write_bytes(res.image)
        except OSError as exc:
            raise ConfigError(f"cannot write {output}: {exc.strerror or exc}") from exc
        click.echo(f"{dev}: {len(res.image)} bytes written to {output}")
        for n in res.notes:
            click.echo(f"note: {n}")
        if compare is not None:
            try:
                other = parse_sii(Path(compare).read_bytes())
            except OSError as exc:
                raise ConfigError(f"cannot read {compare}: {exc.strerror or exc}") from exc
            diffs = sii_differences(res.info, other)
            click.echo(f"{len(diffs)} difference(s) from {compare}")
            for d in diffs:
                click.echo(f"  {d}")

    @cli.command("xml")
    @selection_options
    @click.option("-o", "--output", metavar="FILE", help="Write to this file (default: standard output).")
    @click.pass_context
    def xml_cmd(ctx: click.Context, position: str | None, alias: str | None,
                output: str | None) -> None:
        """Write an ESI file for a live slave (SII, plus its dictionary over CoE)."""
        from pyethercat.esi.from_sii import DictEntry, DictObject, esi_from_sii
        from pyethercat.wire.mailbox.coe import ObjectCode
        from pyethercat.wire.sii import CoeDetails

        with own_master(ctx.obj) as conn:
            m = conn.master
            m.scan()
            s = m.slaves[single([x.alias for x in m.slaves], position, alias, "xml")]
            if s.sii is None:
                raise ConfigError(f"{s.describe()}: SII not readable ({s.sii_error})")
            objects: list[DictObject] = []
            client: Any = getattr(s, "coe", None)
            gen = s.sii.general
            if client is not None and gen is not None and gen.coe_details & CoeDetails.SDO_INFO:
                try:
                    m.set_state("PREOP", [s])
                    for index in client.od_list():
                        desc = client.object_description(index)
                        obj = DictObject(index, desc.name, desc.object_code)
                        subs = [0] if desc.object_code == ObjectCode.VAR else range(desc.max_subindex + 1)
                        for sub in subs:
                            try:
                                e = client.entry_description(index, sub)
                            except EtherCATError:
                                continue
                            obj.entries.append(DictEntry(sub, e.description, e.data_type,
                                                         e.bit_length, e.object_access,
                                                         e.default_value))  # fmt: skip
                        if obj.entries:
                            objects.append(obj)
                except EtherCATError as exc:
                    click.echo(f"note: dictionary not read ({exc})", err=True)
            data = esi_from_sii(s.sii, objects or None)
        if output is None:
            click.echo(data.decode("utf-8"), nl=False)
        else:
            try:
                Path(output).write_bytes(data)
            except OSError as exc:
                raise ConfigError(f"cannot write {output}: {exc.strerror or exc}") from exc
            click.echo(f"{len(data)} bytes written to {output} ({len(objects)} objects)")

    @cli.group("eni")
    def eni_group() -> None:
        """ENI network configuration files."""

    @eni_group.command("export")
    @click.option("-o", "--output", required=True, help="ENI file to write.")
    @click.option("--cycle", default="1000", help="Cycle time in microseconds to record.")
    @click.option("--expect", metavar="TOPOLOGY.toml",
                  help="Check the scan against this network and configure from its ESI files.")
    @click.pass_context
    def eni_export(ctx: click.Context, output: str, cycle: str, expect: str | None) -> None:
        """Scan, configure and write the network as an ENI file."""
        from pyethercat.esi.eni import build_eni
        from pyethercat.master.esi_config import (
            apply_esi_config,
            eni_from_master,
            expected_from_topology,
        )

        with own_master(ctx.obj) as conn:
            m = conn.master
            m.scan()
            if expect is not None:
                apply_esi_config(m, expected_from_topology(expect))
            m.configure()
            eni = eni_from_master(m, cycle_time_us=_int(cycle))
        try:
            Path(output).write_bytes(build_eni(eni))
        except OSError as exc:
            raise ConfigError(f"cannot write {output}: {exc.strerror or exc}") from exc
        click.echo(f"{len(eni.slaves)} slaves, {eni.output_bytes} output and "
                   f"{eni.input_bytes} input bytes written to {output}")  # fmt: skip

    @eni_group.command("import")
    @click.argument("file")
    @click.option("--op", is_flag=True, help="Then bring the segment to OP for a moment.")
    @click.pass_context
    def eni_import(ctx: click.Context, file: str, op: bool) -> None:
        """Start from an ENI file: check identities, configure without reading SII."""
        from pyethercat.esi.eni import load_eni
        from pyethercat.master.esi_config import start_from_eni

        eni = load_eni(file)
        with own_master(ctx.obj) as conn:
            m = conn.master
            start_from_eni(m, eni)
            cfg = m.configure()
            for s in m.slaves:
                sc = cfg.slaves[s.position]
                click.echo(f"{s.position:>3} {s.address_text:<8} {s.name:<24} identity ok  "
                           f"out {sc.output_bits} bit in {sc.input_bits} bit")  # fmt: skip
            if op:
                # The states reached while cycling (the stop takes the slaves back to PREOP).
                with m.start(cycle=0.001):
                    reached = " ".join(s.al_state_name for s in m.slaves)
                click.echo("states: " + reached)
