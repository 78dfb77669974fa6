"""Small helpers shared by the command modules.

A module of its own because the command modules are imported by
``cli.main`` while it registers them: importing ``cli.main`` back from them
would be circular.
"""

from __future__ import annotations

import click

from pyethercat.errors import ConfigError

__all__ = ["parse_int", "number"]


def parse_int(value: str) -> int:
    """Parse a number given on the command line; ``0x`` hex is accepted.

    A bad value is a usage error (:class:`click.BadParameter`, exit status 2).
    """
    try:
        return int(value, 0)
    except ValueError:
        raise click.BadParameter(f"not a number: {value!r}") from None


def number(text: str, what: str, maximum: int | None = None) -> int:
    """A number as typed on the command line (``0x`` hex accepted), named ``what`` in errors.

    With ``maximum`` it must lie in ``0..maximum``. Raises :class:`ConfigError`.
    """
    try:
        value = int(text, 0)
    except ValueError:
        raise ConfigError(f"{what}: not a number: {text!r}") from None
    if maximum is not None and not 0 <= value <= maximum:
        raise ConfigError(f"{what} {text} out of range 0..0x{maximum:X}")
    return value
