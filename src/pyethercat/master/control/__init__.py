"""The master's control socket: other programs reach a running master through it.

One master per wire: while a program holds a master on an interface, the
command line (``pyethercat slaves``, ``upload``...) and later the web
dashboard send typed requests over a local Unix socket
(:mod:`~pyethercat.master.control.protocol`) instead of opening a second
master on the same wire, as IgH's ``ethercat`` tool talks to its kernel
master. The socket lives in a private runtime directory
(:mod:`~pyethercat.master.control.endpoint`) and accepts only the same user
(or root).
"""

from pyethercat.master.control.client import ControlClient, find_master
from pyethercat.master.control.endpoint import endpoint_path, link_spec, runtime_dir
from pyethercat.master.control.server import ControlServer, serve

__all__ = ["ControlClient", "ControlServer", "endpoint_path", "find_master", "link_spec",
           "runtime_dir", "serve"]
