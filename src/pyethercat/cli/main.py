"""The ``pyethercat`` command line (in the style of the IgH ``ethercat`` tool).

Each command group lives in its own module under ``pyethercat.cli`` and is
registered here. Errors from the library become a one-line reason on stderr
and a non-zero exit status.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from pyethercat.cli._util import parse_int
from pyethercat.errors import EtherCATError

__all__ = ["cli", "main", "parse_int"]


class _Group(click.Group):
    """Click group whose every failure is one line on stderr and a non-zero exit.

    Library errors exit with 1; usage errors (a missing option, an unknown
    command, a bad value) with click's 2, as one line that points to
    ``--help`` instead of click's usage block.
    """

    def invoke(self, ctx: click.Context) -> Any:
        try:
            super().invoke(ctx)
        except EtherCATError as exc:
            click.echo(f"pyethercat: error: {exc}", err=True)
            sys.exit(1)
        # Commands report through output and exit status, never a return value;
        # main() relies on None here to tell a normal end from ctx.exit(code).
        return None

    def main(self, args: Any = None, prog_name: str | None = None,
             complete_var: str | None = None, standalone_mode: bool = True,
             **extra: Any) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            where = exc.ctx.command_path if exc.ctx is not None else (prog_name or "pyethercat")
            click.echo(f"pyethercat: error: {exc.format_message()} (see '{where} --help')",
                       err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            click.echo(f"pyethercat: error: {exc.format_message()}", err=True)
            sys.exit(exc.exit_code)
        except click.Abort:
            click.echo("pyethercat: aborted", err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


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

    for name in ("decode", "sim", "master_cmds", "run_cmds", "coe_cmds", "esi_cmds", "dc_cmds",
                 "demo"):
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
