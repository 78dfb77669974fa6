"""``pyethercat drive``: CiA 402 drives from the command line (status, enable, modes, moves, homing)."""

from __future__ import annotations

import json
import re
from typing import Any

import click

from pyethercat.cli._select import selection_options
from pyethercat.cli._session import open_session
from pyethercat.cli._util import parse_int
from pyethercat.errors import ConfigError
from pyethercat.master.control.drive_ops import DRIVE_ACTIONS, DriveAction, DriveReply

__all__ = ["register"]

_NEEDS_ARGUMENT = {"mode": "MODE", "move": "TARGET", "home": "METHOD"}


def format_drives(reply: DriveReply) -> list[str]:
    """One line per drive: position, state, mode, statusword, position, following error, error."""
    lines = []
    for d in reply.drives:
        pos = "-" if d.actual_position is None else str(d.actual_position)
        fe = "" if d.following_error is None else f"  following error {d.following_error}"
        err = f"  error 0x{d.error_code:04X} ({d.error_text})" if d.error_code else ""
        warn = "  warning" if d.warning else ""
        lines.append(f"{d.position}  {d.state:<22} {d.mode:<4} statusword 0x{d.statusword:04X}  "
                     f"position {pos}{fe}{err}{warn}")
    return lines


_NEGATIVE = re.compile(r"-(0[xX][0-9a-fA-F]+|\d+)")


class _DriveCommand(click.Command):
    """A move target or a (manufacturer-specific) homing method may be negative.

    "-5000" is not a cluster of short options: a negative number that is not the
    value of an option goes after "--", where click takes it as the argument.
    """

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if "--" not in args:
            takes_value = {name for p in self.get_params(ctx)
                           if isinstance(p, click.Option) and not p.is_flag for name in p.opts}
            numbers = [i for i, a in enumerate(args) if _NEGATIVE.fullmatch(a)
                       and not (i and args[i - 1] in takes_value)]
            if numbers:
                args = ([a for i, a in enumerate(args) if i not in numbers] + ["--"]
                        + [args[i] for i in numbers])
        return super().parse_args(ctx, args)


@click.command("drive", cls=_DriveCommand)
@click.argument("action", type=click.Choice(DRIVE_ACTIONS), metavar="ACTION")
@click.argument("argument", required=False, metavar="[MODE|TARGET|METHOD]")
@selection_options
@click.option("--velocity", default=None, metavar="V", help="Profile velocity 0x6081 (increments/s).")
@click.option("--accel", "accel", default=None, metavar="A",
              help="Profile acceleration and deceleration 0x6083/0x6084 (increments/s²).")
@click.option("--relative", is_flag=True, help="move: the target is relative.")
@click.option("--timeout", default=5.0, type=click.FloatRange(min=0.001), show_default=True,
              metavar="S", help="How long the drive may take.")
@click.option("--json", "as_json", is_flag=True, help="Print the drives as JSON.")
@click.pass_obj
def drive_command(obj: dict[str, Any], action: str, argument: str | None, position: str | None,
                  alias: str | None, velocity: str | None, accel: str | None, relative: bool,
                  timeout: float, as_json: bool) -> None:
    """Drive CiA 402 servo drives: ACTION is status, enable, disable, reset, quickstop,
    mode MODE (pp, pv, hm, csp, csv, cst), move TARGET, home METHOD.

    status works on any segment (by SDO when no master cycles); the other
    actions go through a running master's cycle ('pyethercat run' in another
    terminal) and need the drive's controlword and statusword in its PDOs.
    A move switches to profile position mode; home to homing mode. Prints
    every selected drive afterwards (without -p/-a: every drive of the
    segment). A negative TARGET or METHOD is a number, not an option.
    """
    want = _NEEDS_ARGUMENT.get(action)
    if want is not None and argument is None:
        raise ConfigError(f"drive {action} needs {want}")
    if want is None and argument is not None:
        raise ConfigError(f"drive {action} takes no argument (got {argument!r})")
    req = DriveAction(
        action, [], mode=argument if action == "mode" else None,
        target=parse_int(argument) if action == "move" and argument is not None else None,
        relative=relative,
        velocity=None if velocity is None else parse_int(velocity),
        acceleration=None if accel is None else parse_int(accel),
        method=parse_int(argument) if action == "home" and argument is not None else None,
        timeout=timeout)
    with open_session(obj) as session:
        # neither -p nor -a: every drive (the handler leaves other slaves out)
        positions = (None if position is None and alias is None
                     else session.select(position, alias))
        reply: DriveReply = session.call(DriveAction(**{**req.__dict__, "positions": positions}))
    if as_json:
        click.echo(json.dumps({"source": reply.source,
                               "drives": [d.__dict__ for d in reply.drives]}))
        return
    for line in format_drives(reply):
        click.echo(line)


def register(cli: click.Group) -> None:
    """Add ``drive`` to the ``pyethercat`` group."""
    cli.add_command(drive_command)
