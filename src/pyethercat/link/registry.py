"""Links by name: ``open_link("raw:eth1")``, ``"udp:10.0.0.2:34980"``, ``"unix:/run/seg.sock"``.

The one place where a link is made from text, for :meth:`Master.open
<pyethercat.master.master.Master.open>` and the command line alike. A name is
``SCHEME:REST``; a name without a known scheme is an interface name (raw):

===========================  ===============================================
``raw:IF`` or ``IF``         AF_PACKET socket on interface ``IF``
                             (:class:`~pyethercat.link.raw.RawLink`)
``udp:HOST[:PORT]``          EtherCAT over UDP to ``HOST`` (port 34980 by
                             default); with ``serve=True`` bound there instead,
                             answering whoever sends (a simulator's side)
``unix:PATH``                a ``SOCK_SEQPACKET`` Unix socket listening at
                             ``PATH`` (:class:`~pyethercat.link.unix.UnixLink`)
``unix:fd:N``                an inherited socket file descriptor ``N``
``ring:A,B``                 the ports A and B of a ring, each a name as
                             above (``ring:eth1,eth2``,
                             ``ring:udp:h:34980,udp:h:34981``;
                             :class:`~pyethercat.link.redundant.RedundantLink`)
===========================  ===============================================

Further schemes plug in with :func:`register_link` (the EoE TAP link).
Keyword options go to the link's factory (for ``ring:``, to both ports).
:func:`iface_link` reads a command line's ``--iface`` argument: an interface
name, or any name with a known scheme (``--iface unix:/run/seg.sock``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pyethercat.errors import LinkError
from pyethercat.link.base import Link

__all__ = ["LinkFactory", "iface_link", "link_schemes", "open_link", "register_link"]

#: Makes a link from the rest of its name (after ``SCHEME:``) and keyword options.
LinkFactory = Callable[..., Link]


def _raw(rest: str, **options: Any) -> Link:
    from pyethercat.link.raw import RawLink

    if not rest:
        raise LinkError("raw link: give an interface name (raw:eth1)")
    return RawLink(rest, **options)


def _udp(rest: str, *, serve: bool = False, **options: Any) -> Link:
    from pyethercat.link.udp import UdpLink, parse_hostport

    if not rest:
        raise LinkError("udp link: give HOST[:PORT] (udp:127.0.0.1:34980)")
    if serve:
        return UdpLink(bind=parse_hostport(rest), **options)
    return UdpLink(peer=rest, **options)


def _unix(rest: str, **options: Any) -> Link:
    from pyethercat.link.unix import UnixLink

    if rest.startswith("fd:"):
        try:
            fd = int(rest[3:], 0)
        except ValueError:
            raise LinkError(f"unix link: bad file descriptor in {rest!r}") from None
        return UnixLink.from_fd(fd, **options)
    if not rest:
        raise LinkError("unix link: give a socket path (unix:/run/segment.sock) or fd:N")
    return UnixLink.connect(rest, **options)


def _ring(rest: str, **options: Any) -> Link:
    from pyethercat.link.redundant import RedundantLink

    a, sep, b = rest.partition(",")
    if not sep or not a.strip() or not b.strip():
        raise LinkError("ring link: give both ports, ring:PORT_A,PORT_B (ring:eth1,eth2)")
    first = open_link(a, **options)
    try:
        second = open_link(b, **options)
    except BaseException:
        first.close()
        raise
    return RedundantLink(first, second)


_SCHEMES: dict[str, LinkFactory] = {"raw": _raw, "udp": _udp, "unix": _unix, "ring": _ring}


def register_link(scheme: str, factory: LinkFactory) -> None:
    """Make ``open_link("SCHEME:...")`` call ``factory(rest, **options)``."""
    if not scheme.isidentifier():
        raise ValueError(f"link scheme {scheme!r} is not a plain name")
    _SCHEMES[scheme] = factory


def link_schemes() -> list[str]:
    """The schemes :func:`open_link` knows."""
    return sorted(_SCHEMES)


def iface_link(iface: str) -> str:
    """The link name for an interface argument: ``iface`` itself when it starts with a
    known scheme (``unix:PATH``, ``udp:HOST:PORT``, ``raw:eth1``, a registered one), else
    ``raw:IFACE``."""
    scheme, sep, _ = iface.strip().partition(":")
    return iface.strip() if sep and scheme in _SCHEMES else f"raw:{iface}"


def open_link(name: str, **options: Any) -> Link:
    """Open the link ``name`` describes (see the module text).

    Raises :class:`~pyethercat.errors.LinkError` for a name no scheme
    takes, and whatever the link itself raises (no such interface, missing
    privileges as :class:`~pyethercat.errors.PermissionError`).
    """
    text = name.strip()
    if not text:
        raise LinkError("empty link name: give raw:IF, udp:HOST[:PORT] or unix:PATH")
    scheme, sep, rest = text.partition(":")
    factory = _SCHEMES.get(scheme) if sep else None
    if factory is None:
        if sep and scheme and "/" not in scheme and not scheme.isdigit():
            raise LinkError(f"unknown link scheme {scheme!r} in {name!r} "
                            f"(known: {', '.join(link_schemes())})")
        return _raw(text, **options)  # a bare interface name
    return factory(rest, **options)
