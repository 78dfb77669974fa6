"""The ``pyethercat`` command line (in the style of the IgH ``ethercat`` tool).

Each command group lives in its own module under ``pyethercat.cli`` and is
registered here. Errors from the library become a one-line reason on stderr
and a non-zero exit status.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from pyethercat.errors import EtherCATError

__all__ = ["cli", "main", "parse_int"]


class _Group(click.Group):
    """Click group that turns library errors into one-line messages."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except EtherCATError as exc:
            click.echo(f"pyethercat: error: {exc}", err=True)
            sys.exit(1)


def parse_int(value: str) -> int:
    """Parse a number given on the command line; ``0x`` hex is accepted."""
    try:
        return int(value, 0)
    except ValueError:
        raise click.BadParameter(f"not a number: {value!r}") from None


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--iface", metavar="IF", help="Network interface of the EtherCAT segment (raw socket).")
@click.option("--udp", metavar="HOST:PORT", help="EtherCAT over UDP peer.")
@click.option("--sim", metavar="TOPOLOGY.toml", help="Simulated segment from a topology file.")
@click.pass_context
def cli(ctx: click.Context, iface: str | None, udp: str | None, sim: str | None) -> None:
    """EtherCAT master, simulator and tools."""
    ctx.ensure_object(dict)
    ctx.obj["iface"] = iface
    ctx.obj["udp"] = udp
    ctx.obj["sim"] = sim


def _register() -> None:
    """Attach the command modules that exist (each module adds its commands)."""
    import importlib

    for name in ("decode", "sim", "master_cmds", "run_cmds", "coe_cmds", "esi_cmds", "demo"):
        try:
            module = importlib.import_module(f"pyethercat.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"pyethercat.cli.{name}":
                raise
            continue
        module.register(cli)


_register()


def main() -> None:
    """Entry point of the ``pyethercat`` program."""
    cli(prog_name="pyethercat")
