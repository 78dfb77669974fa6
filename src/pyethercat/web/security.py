"""The dashboard's rules of access: where it listens, who may read, who may write.

- It listens on 127.0.0.1 unless told otherwise; another address needs a
  token (:func:`check_bind`), given with ``--token`` or generated and printed.
- With a token every request and every WebSocket must carry it: the
  ``Authorization: Bearer`` header, or the cookie the page sets when it is
  opened once as ``/?token=...`` (the address the command prints). The
  token never appears in a page or a script.
- Writes (outputs, SDO downloads) need the token *and* the server started
  with writes allowed; without either they are refused with 403. A write
  must also come from the dashboard's own origin (``Origin`` header) as
  JSON, so another site cannot make the browser send one.
- The ``Host`` header must name the address the server listens on (or
  localhost), so a page of another site that rebinds its name to 127.0.0.1
  cannot read the dashboard.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from dataclasses import dataclass, field

from pyethercat.errors import ConfigError

__all__ = ["Access", "parse_bind", "check_bind", "is_loopback", "new_token", "COOKIE",
           "content_security_policy"]

COOKIE = "pyecat_token"
DEFAULT_BIND = "127.0.0.1:8080"


def parse_bind(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[V6]:PORT``, ``HOST`` (port 8080) or ``:PORT`` (127.0.0.1)."""
    text = text.strip()
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else "8080"
    elif text.count(":") == 1:
        host, _, port_text = text.partition(":")
    elif ":" in text:
        raise ConfigError(f"--bind {text}: write an IPv6 address in brackets, [::1]:8080")
    else:
        host, port_text = text, "8080"
    host = host or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise ConfigError(f"--bind {text}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ConfigError(f"--bind {text}: port {port} is out of range 0-65535")
    return host, port


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (or ``localhost``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    return secrets.token_urlsafe(24)


def check_bind(host: str, token: str | None, *, generate: bool = False) -> str | None:
    """The token to use for listening on ``host``: a non-loopback address needs one.

    ``generate``: make one when none was given (the command prints it) instead
    of refusing.
    """
    if is_loopback(host) or token:
        return token
    if generate:
        return new_token()
    raise ConfigError(f"--bind {host}: the dashboard would be reachable from the network "
                      "without a token; give --token TOKEN (or --token generate)")


def content_security_policy(ws_origin: str) -> str:
    """Scripts, styles and data only from the dashboard itself; no inline code at all."""
    return ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
            f"connect-src 'self' {ws_origin}; font-src 'self'; base-uri 'none'; "
            "form-action 'self'; frame-ancestors 'none'")


@dataclass
class Access:
    """The rules one server applies (see the module text)."""

    host: str
    port: int
    token: str | None = None
    writable: bool = False
    allowed_hosts: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        names = {self.host, "localhost", "127.0.0.1", "[::1]", "::1"} if is_loopback(self.host) \
            else {self.host}
        if self.host in ("0.0.0.0", "::"):
            names = set()  # any address of this host: the token guards it
        self.allowed_hosts = names

    def host_ok(self, host_header: str | None) -> bool:
        if not self.allowed_hosts:
            return True
        if not host_header:
            return False
        name = host_header
        if name.startswith("["):
            name = name[:name.index("]") + 1] if "]" in name else name
        else:
            name = name.rsplit(":", 1)[0] if name.count(":") == 1 else name
        return name in self.allowed_hosts

    def token_ok(self, given: str | None) -> bool:
        """The request carries the token (always true when the server has none)."""
        token = self.token
        if not token:
            return True
        return given is not None and hmac.compare_digest(given.encode(), token.encode())

    def write_refusal(self, given: str | None) -> str | None:
        """Why a write is refused (None: allowed)."""
        if not self.writable:
            return ("this dashboard is read-only: start it with --allow-writes (and a token) "
                    "to change outputs or objects")
        token = self.token
        if not token or not given or not hmac.compare_digest(given.encode(), token.encode()):
            return "writes need the dashboard's token"
        return None
