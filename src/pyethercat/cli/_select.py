"""Slave selection as IgH's ``ethercat`` tool does it: ``-p/--position`` and ``-a/--alias``.

Both take number lists: ``3``, ``1,4``, ``5-7,9``, ``-3`` (0 to 3), ``2-``
(2 to the last), ``-`` (all). Then (IgH ``Command::selectedSlaves``):

1. neither given: every slave;
2. only ``-p``: absolute ring positions;
3. only ``-a``: the slaves with that alias and the ones after each up to
   the next slave with another alias;
4. both: ``-p`` counts from the slave with the alias (0 = the slave itself).

Numbers are decimal, or hexadecimal with ``0x``.
"""

from __future__ import annotations

from collections.abc import Sequence

import click

from pyethercat.errors import ConfigError

__all__ = ["MAX_ALIAS", "parse_list", "select", "select_configs", "single", "selection_options"]


def _number(text: str, i: int) -> tuple[int, int]:
    """A number at ``text[i:]`` and the index after it."""
    j = i
    if text.startswith(("0x", "0X"), i):
        j = i + 2
        while j < len(text) and text[j] in "0123456789abcdefABCDEF":
            j += 1
        if j == i + 2:
            raise ConfigError(f"no hex digits after 0x at position {i} of {text!r}")
        return int(text[i + 2:j], 16), j
    while j < len(text) and text[j].isdigit():
        j += 1
    return int(text[i:j]), j


#: Aliases are 16 bit (SII word 4, register 0x0012).
MAX_ALIAS = 0xFFFF


def parse_list(text: str, maximum: int, *, limit: int | None = None,
               what: str = "number") -> list[int]:
    """The numbers a list names; an open range ends at ``maximum`` (-1: nothing).

    A descending range ``7-5`` gives 5, 6, 7 (as IgH); duplicates are kept
    out, the order is that of the list. A number above ``limit`` is refused
    (:class:`ConfigError` naming it as ``what``) before any range is expanded.
    """
    if limit is not None:
        _check_limit(text, limit, what)
    out: list[int] = []
    i = 0
    text = text.strip()
    while i < len(text):
        c = text[i]
        if c == ",":
            i += 1
            continue
        if c.isdigit():
            first, i = _number(text, i)
        elif c == "-":
            first = 0
        else:
            raise ConfigError(f"invalid character {c!r} at position {i} of {text!r} "
                              "(write numbers like 3, 1,4, 5-7 or -)")
        if i < len(text) and text[i] == "-":
            i += 1
            if i < len(text) and text[i].isdigit():
                second, i = _number(text, i)
                lo, hi = min(first, second), max(first, second)
                items = range(lo, hi + 1)
            else:
                items = range(first, maximum + 1)
        else:
            items = range(first, first + 1)
        if i < len(text) and text[i] != ",":
            raise ConfigError(f"invalid character {text[i]!r} at position {i} of {text!r} "
                              "(write numbers like 3, 1,4, 5-7 or -)")
        out.extend(n for n in items if n not in out)
    return out


def _check_limit(text: str, limit: int, what: str) -> None:
    i = 0
    text = text.strip()
    while i < len(text):
        if text[i].isdigit():
            value, j = _number(text, i)
            if value > limit:
                raise ConfigError(f"{what} {text[i:j]} out of range 0..0x{limit:X}")
            i = j
        else:
            i += 1


def select(aliases: Sequence[int], position: str | None, alias: str | None) -> list[int]:
    """Ring positions chosen by ``-p``/``-a`` among slaves whose aliases are ``aliases``."""
    count = len(aliases)
    positions = position if position is not None else "-"
    if alias is None or alias == "-":
        return [p for p in parse_list(positions, count - 1) if p < count]
    chosen: list[int] = []
    for wanted in parse_list(alias, max(aliases, default=0) or -1, limit=MAX_ALIAS,
                             what="alias"):
        group: list[int] = []
        last = 0
        for pos, a in enumerate(aliases):
            if a:
                if last and last == wanted and a != wanted:
                    break  # a second block of the same alias would make -p ambiguous
                last = a
            if last == wanted:
                group.append(pos)
        for rel in parse_list(positions, len(group) - 1):
            if rel < len(group) and group[rel] not in chosen:
                chosen.append(group[rel])
    return chosen


def single(aliases: Sequence[int], position: str | None, alias: str | None, verb: str) -> int:
    """The one position ``-p``/``-a`` select; :class:`ConfigError` unless exactly one."""
    chosen = select(aliases, position, alias)
    if len(chosen) != 1:
        hint = "" if chosen else f" (the segment has {len(aliases)} slave" \
                                 f"{'s' if len(aliases) != 1 else ''})"
        raise ConfigError(f"the slave selection matches {len(chosen)} slaves{hint}; "
                          f"'{verb}' needs exactly one (use -p POSITION or -a ALIAS)")
    return chosen[0]


def select_configs(keys: Sequence[tuple[int, int]], position: str | None,
                   alias: str | None) -> list[int]:
    """Indices of the slave configurations ``-p``/``-a`` select, as IgH's ``config`` does.

    ``keys`` are the configurations' ``(alias, position)`` addresses. Unlike
    the slave selection, ``-p`` alone counts from every alias (IgH
    ``Command::selectedConfigs``: aliases default to all, positions to all
    within each alias); the result is ordered by alias, then position.
    """
    if alias is None and position is None:
        return list(range(len(keys)))
    by_alias: dict[int, dict[int, int]] = {}
    for i, (a, p) in enumerate(keys):
        by_alias.setdefault(a, {})[p] = i
    chosen: list[int] = []
    top = max(by_alias, default=0)
    for a in parse_list(alias or "-", top, limit=MAX_ALIAS, what="alias"):
        group = by_alias.get(a)
        if group is None:
            continue
        for p in parse_list(position or "-", max(group)):
            if p in group and group[p] not in chosen:
                chosen.append(group[p])
    return sorted(chosen, key=lambda i: keys[i])


def _checked_alias(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    # While the options are parsed: a bad list fails before the segment is opened.
    if value is not None:
        parse_list(value, 0, limit=MAX_ALIAS, what="alias")
    return value


def _checked_position(ctx: click.Context, param: click.Parameter,
                      value: str | None) -> str | None:
    if value is not None:
        parse_list(value, 0)
    return value


def selection_options(fn: click.decorators.FC) -> click.decorators.FC:
    """Add ``-p/--position`` and ``-a/--alias`` (IgH slave selection) to a command.

    Both lists are checked as they are parsed (syntax; aliases within 16 bits).
    """
    fn = click.option("-a", "--alias", "alias", metavar="ALIAS", callback=_checked_alias,
                      help="Slave alias (list); -p then counts from it.")(fn)
    return click.option("-p", "--position", "position", metavar="POS",
                        callback=_checked_position,
                        help="Ring position (list: 1,3 or 2-5; with -a: relative).")(fn)
