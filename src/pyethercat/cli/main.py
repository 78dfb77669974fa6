"""The ``pyethercat`` command line (in the manner of IgH's ``ethercat`` tool).

Each command group lives in its own module under ``pyethercat.cli`` and is
registered here. As with IgH's tool:

* verbs may be abbreviated: a unique prefix (``sl`` for ``slaves``), else
  letters in order (``rr`` for ``reg_read``) when that is unique;
* options may come before or after the verb: ``pyethercat -p 1 upload ...``
  and ``pyethercat upload --iface eth0 -p 1 ...`` both work;
* every failure is one line on stderr and exit status 1 (IgH's tool exits
  1 for usage and command errors alike); success is 0.
"""

from __future__ import annotations

import sys
from typing import Any

import click

from pyethercat.cli._util import parse_int
from pyethercat.errors import EtherCATError
from pyethercat.master.pdu import DEFAULT_RETRIES, DEFAULT_TIMEOUT

__all__ = ["cli", "main", "parse_int", "normalize_argv", "EXIT_FAILURE"]

#: Exit status of every failure (IgH's ``ethercat`` returns 1 for all of them).
EXIT_FAILURE = 1

#: Global options that take a value, and flags; accepted anywhere on the line.
_GLOBAL_VALUE = frozenset({"--iface", "--udp", "--sim", "--redundant-iface", "--redundant-udp",
                           "--frame-timeout", "--retries"})
_GLOBAL_FLAG = frozenset({"--direct"})
#: Verbs with options of their own by those names (``sim --iface`` serves there).
_OWN_GLOBALS = frozenset({"sim"})
def normalize_argv(args: list[str], verbs: list[str],
                   value_options: frozenset[str] = frozenset()) -> list[str]:
    """Global options first, then the verb, then every other option and argument.

    ``verbs`` are the command names (to tell a verb given by a prefix from
    an option value); ``value_options`` the command options that take a
    value (a value given before the verb is moved with its option).
    """
    front: list[str] = []
    before: list[str] = []
    rest: list[str] = []
    verb: str | None = None
    i = 0
    while i < len(args):
        tok = args[i]
        if tok == "--":
            rest.extend(args[i:])
            break
        name = tok.split("=", 1)[0]
        own = verb is not None and _resolve(verb, verbs) in _OWN_GLOBALS
        if name in _GLOBAL_VALUE and not own:
            take = 1 if "=" in tok else 2
            front.extend(args[i:i + take])
            i += take
            continue
        if tok in _GLOBAL_FLAG and not own:
            front.append(tok)
            i += 1
            continue
        if verb is None:
            if tok in ("-h", "--help"):
                front.append(tok)
            elif tok.startswith("-") and len(tok) > 1:
                before.append(tok)
                # "-p 0" carries its value along; "-p0" and "--position=0" are one token.
                if name in value_options and "=" not in tok and i + 1 < len(args):
                    before.append(args[i + 1])
                    i += 1
            else:
                verb = tok
        else:
            rest.append(tok)
        i += 1
    if verb is None:
        return front + before
    return front + [verb] + before + rest


def _resolve(name: str, verbs: list[str]) -> str | None:
    found = _matches(name, verbs)
    return found[0] if len(found) == 1 else None


def _matches(name: str, verbs: list[str]) -> list[str]:
    """IgH's matching: the exact name, else names starting with it, else letters in order."""
    if name in verbs:
        return [name]
    found = [v for v in verbs if v.startswith(name)]
    if found:
        return found

    def in_order(verb: str) -> bool:
        pos = 0
        for ch in name:
            pos = verb.find(ch, pos)
            if pos < 0:
                return False
            pos += 1
        return True

    return [v for v in verbs if in_order(v)]


class _Group(click.Group):
    """Click group with IgH's verb matching and argument order; failures are one line.

    Every failure exits with 1 (IgH's ``ethercat`` does), as one line on
    stderr (a usage error points to ``--help`` instead of click's usage block).
    """

    def _value_options(self) -> frozenset[str]:
        """Every option of every command that takes a value (``-p``, ``--seconds``...)."""
        out: set[str] = set()
        todo: list[click.Command] = list(self.commands.values())
        while todo:
            cmd = todo.pop()
            if isinstance(cmd, click.Group):
                todo.extend(cmd.commands.values())
            for param in cmd.params:
                if isinstance(param, click.Option) and not param.is_flag and not param.count:
                    out.update(param.opts)
        return frozenset(out)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        found = _matches(cmd_name, self.list_commands(ctx))
        if len(found) > 1:
            raise click.UsageError(f"ambiguous command {cmd_name!r}: it matches "
                                   f"{', '.join(found)}", ctx)
        return super().get_command(ctx, found[0]) if found else None

    def resolve_command(self, ctx: click.Context, args: list[str]
                        ) -> tuple[str | None, click.Command | None, list[str]]:
        name, cmd, rest = super().resolve_command(ctx, args)
        # The full name, not the abbreviation typed (``--help`` and errors show it).
        return (cmd.name if cmd is not None else name), cmd, rest

    def invoke(self, ctx: click.Context) -> Any:
        try:
            super().invoke(ctx)
        except EtherCATError as exc:
            click.echo(f"pyethercat: error: {_one_line(str(exc))}", err=True)
            sys.exit(EXIT_FAILURE)
        # Commands report through output and exit status, never a return value;
        # main() relies on None here to tell a normal end from ctx.exit(code).
        return None

    def main(self, args: Any = None, prog_name: str | None = None,
             complete_var: str | None = None, standalone_mode: bool = True,
             **extra: Any) -> Any:
        argv = list(sys.argv[1:] if args is None else args)
        argv = normalize_argv(argv, self.list_commands(click.Context(self)), self._value_options())
        if not standalone_mode:
            return super().main(argv, prog_name, complete_var, standalone_mode, **extra)
        try:
            code = super().main(argv, prog_name, complete_var, False, **extra)
        except click.UsageError as exc:
            where = exc.ctx.command_path if exc.ctx is not None else (prog_name or "pyethercat")
            click.echo(f"pyethercat: error: {_one_line(exc.format_message())} "
                       f"(see '{where} --help')", err=True)
            sys.exit(EXIT_FAILURE)
        except click.ClickException as exc:
            click.echo(f"pyethercat: error: {_one_line(exc.format_message())}", err=True)
            sys.exit(EXIT_FAILURE)
        except click.Abort:
            click.echo("pyethercat: aborted", err=True)
            sys.exit(EXIT_FAILURE)
        except EtherCATError as exc:  # raised while parsing (a bad value callback)
            click.echo(f"pyethercat: error: {_one_line(str(exc))}", err=True)
            sys.exit(EXIT_FAILURE)
        sys.exit(code if isinstance(code, int) else 0)


def _one_line(text: str) -> str:
    return " ".join(text.split())


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--iface", metavar="IF", help="Network interface of the EtherCAT segment (raw socket), "
              "or a link name with a scheme: unix:PATH, udp:HOST:PORT, ring:A,B.")
@click.option("--udp", metavar="HOST:PORT", help="EtherCAT over UDP peer.")
@click.option("--sim", metavar="TOPOLOGY.toml", help="Simulated segment from a topology file.")
@click.option("--redundant-iface", metavar="IF",
              help="Second port of a ring (cable redundancy): cabled to the last slave.")
@click.option("--redundant-udp", metavar="HOST:PORT", help="Second port of a ring over UDP.")
@click.option("--direct", is_flag=True,
              help="Open the segment directly even when a master runs on it (warns).")
@click.option("--frame-timeout", type=click.FloatRange(0, min_open=True), metavar="SECONDS",
              envvar="PYETHERCAT_FRAME_TIMEOUT", show_envvar=True,
              help=f"How long a frame has to come back before it is sent again "
                   f"[default: {DEFAULT_TIMEOUT:g}]. Raise it for a simulator on a busy machine.")
@click.option("--retries", type=click.IntRange(0), metavar="N", envvar="PYETHERCAT_RETRIES",
              show_envvar=True,
              help=f"How often a lost frame is sent again [default: {DEFAULT_RETRIES}].")
@click.pass_context
def cli(ctx: click.Context, iface: str | None, udp: str | None, sim: str | None,
        redundant_iface: str | None, redundant_udp: str | None, direct: bool,
        frame_timeout: float | None, retries: int | None) -> None:
    """EtherCAT master, simulator and tools.

    Commands can be abbreviated; options may come before or after the
    command. While a master runs on the segment (``pyethercat run`` or a
    program), commands go to it through its control socket.
    """
    ctx.ensure_object(dict)
    ctx.obj["iface"] = iface
    ctx.obj["udp"] = udp
    ctx.obj["sim"] = sim
    ctx.obj["redundant_iface"] = redundant_iface
    ctx.obj["redundant_udp"] = redundant_udp
    ctx.obj["direct"] = direct
    ctx.obj["frame_timeout"] = frame_timeout
    ctx.obj["retries"] = retries


_MODULES = ("decode", "sim", "slave_cmds", "reg_cmds", "sii_cmds", "info_cmds", "run_cmds",
            "coe_cmds", "esi_cmds", "dc_cmds", "eoe_cmds", "ring_cmds", "demo", "foe_cmds",
            "soe_cmds", "gateway_cmds", "drive_cmds", "web_cmds")


def _register() -> None:
    """Attach the command modules (each module adds its commands)."""
    import importlib

    for name in _MODULES:
        module = importlib.import_module(f"pyethercat.cli.{name}")
        module.register(cli)


_register()


def main() -> None:
    """Entry point of the ``pyethercat`` program."""
    cli(prog_name="pyethercat")
