"""Where a master's control socket lives: one name per link, in a private directory.

The directory is ``$PYETHERCAT_RUNTIME_DIR`` if set, else
``$XDG_RUNTIME_DIR/pyethercat``, else ``/run/pyethercat`` for root and
``/tmp/pyethercat-UID`` for anyone else. It is created with mode 0700 and
refused when another user owns it or others may enter it (a socket there
gives control over the segment). A link is named as the link registry
spells it: ``raw:eth0``, ``udp:HOST:PORT``, ``sim:/abs/path/topology.toml``.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from pathlib import Path

from pyethercat.errors import ConfigError

__all__ = ["runtime_dir", "link_spec", "endpoint_path", "DEFAULT_UDP_PORT"]

DEFAULT_UDP_PORT = 34980
_SAFE = re.compile(r"[^A-Za-z0-9._-]")


def runtime_dir(create: bool = True) -> Path:
    """The private directory of control sockets (created when ``create``)."""
    env = os.environ.get("PYETHERCAT_RUNTIME_DIR")
    if env:
        path = Path(env)
    elif os.environ.get("XDG_RUNTIME_DIR"):
        path = Path(os.environ["XDG_RUNTIME_DIR"]) / "pyethercat"
    elif os.geteuid() == 0:
        path = Path("/run/pyethercat")
    else:
        path = Path(f"/tmp/pyethercat-{os.geteuid()}")
    if create:
        try:
            path.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"cannot create the runtime directory {path}: "
                              f"{exc.strerror or exc}") from None
    if path.exists():
        info = path.stat()
        if info.st_uid != os.geteuid() or stat.S_IMODE(info.st_mode) & 0o077:
            raise ConfigError(f"runtime directory {path} is not private (owner uid "
                              f"{info.st_uid}, mode {stat.S_IMODE(info.st_mode):o}): "
                              "it must belong to you with mode 700")
    return path


def link_spec(*, iface: str | None = None, udp: str | None = None,
              sim: str | None = None) -> str:
    """The name of a link: ``raw:IF``, ``udp:HOST:PORT`` or ``sim:/abs/topology.toml``."""
    if iface is not None:
        return f"raw:{iface}"
    if udp is not None:
        host, sep, port = udp.rpartition(":")
        if not sep:
            host, port = udp, str(DEFAULT_UDP_PORT)
        return f"udp:{host}:{port}"
    if sim is not None:
        return f"sim:{os.path.realpath(sim)}"
    raise ConfigError("no link given")


def endpoint_path(spec: str, directory: Path | None = None) -> Path:
    """The control socket of the master on link ``spec``."""
    kind, _, rest = spec.partition(":")
    if kind == "sim" or len(rest) > 60:
        digest = hashlib.sha1(spec.encode()).hexdigest()[:12]
        name = f"{kind}-{_SAFE.sub('_', Path(rest).name)[:40]}-{digest}"
    else:
        name = f"{kind}-{_SAFE.sub('_', rest)}"
    return (directory if directory is not None else runtime_dir()) / f"{name}.sock"
