"""A simulator in a child process: :func:`start_sim_process` and its handle.

``pyethercat sim TOPOLOGY`` runs in a child process (tests, benchmarks, the
``--sim`` option of the command line); :class:`SimProcess` sends it control
commands (``sim.server``'s JSON control channel), reads its stderr and stops
it. The child's link is a socketpair (the master's end is the handle's
``link``), a network interface or a UDP address.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from pyethercat.errors import ConfigError, LinkClosedError, LinkError
from pyethercat.link.base import Link

__all__ = ["READY_TIMEOUT", "SimProcess", "start_sim_process"]


#: How long :func:`start_sim_process` waits for the child to serve. It is up in
#: a second on an idle machine; a loaded one (a CI run, load 10 on 2 CPUs) has
#: been seen to take over 20 s to import and build a segment. A child that dies
#: is noticed at once, so only a hung child waits this long.
READY_TIMEOUT = 120.0


@dataclass
class SimProcess:
    """Handle of a simulator running in a child process (see :func:`start_sim_process`)."""

    process: subprocess.Popen[bytes]
    control_path: str
    link: Link | None = None  # the master's end, for link="unix"
    _tmpdir: tempfile.TemporaryDirectory[str] | None = None
    _sock: socket.socket | None = None
    _buf: bytearray = field(default_factory=bytearray)

    def control(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one control command; returns the answer, raises ConfigError on failure."""
        if self._sock is None:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(5.0)
            sock.connect(self.control_path)
            self._sock = sock
        self._sock.sendall(json.dumps({"cmd": cmd, **args}).encode() + b"\n")
        while b"\n" not in self._buf:
            chunk = self._sock.recv(65536)
            if not chunk:
                raise LinkClosedError("the simulator process closed its control channel")
            self._buf += chunk
        line, _, rest = bytes(self._buf).partition(b"\n")
        self._buf[:] = rest
        answer: dict[str, Any] = json.loads(line)
        if not answer.get("ok"):
            raise ConfigError(f"simulator command {cmd!r} failed: {answer.get('error')}")
        return answer

    def stderr(self) -> str:
        """What the child wrote to stderr so far."""
        if self._tmpdir is None:
            return ""
        try:
            return (Path(self._tmpdir.name) / "stderr.log").read_text(errors="replace")
        except OSError:
            return ""

    def wait_ready(self, timeout: float = READY_TIMEOUT) -> None:
        """Wait until the child answers on its control channel."""
        deadline = time.monotonic() + timeout
        while True:
            if self.process.poll() is not None:
                raise LinkError(
                    f"the simulator process exited with status {self.process.returncode}: "
                    f"{self.stderr().strip()}"
                )
            try:
                self.control("ping")
                return
            except (OSError, LinkClosedError):
                if self._sock is not None:
                    self._sock.close()
                    self._sock = None
                if time.monotonic() > deadline:
                    raise LinkError("the simulator process did not start in time") from None
                time.sleep(0.05)

    def stop(self, timeout: float = 10.0) -> int:
        """End the child (SIGTERM, then SIGKILL after ``timeout``); returns its exit status."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.link is not None:
            self.link.close()
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None
        return int(self.process.returncode)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def start_sim_process(
    topology: str | os.PathLike[str],
    link: str = "unix",
    pcap: str | os.PathLike[str] | None = None,
    ready_timeout: float = READY_TIMEOUT,
    realtime: int = 0,
    ring: bool = False,
    link_b: str | None = None,
    busy_poll_us: float | None = None,
    cpu: int | None = None,
    busy_poll_share: float | None = None,
) -> SimProcess:
    """Run ``pyethercat sim TOPOLOGY`` in a child process and wait until it serves.

    ``link`` is ``"unix"`` (a socketpair; the handle's ``link`` is the master's
    end), ``"iface:NAME"`` (raw interface) or ``"udp:HOST:PORT"``. ``realtime``
    > 0 asks the child to serve under SCHED_FIFO with that priority (``--realtime``;
    needs root or CAP_SYS_NICE, else the child serves at normal priority).
    A ring: ``link_b`` (``"iface:NAME"``, ``"udp:HOST:PORT"``) is master port B;
    with ``link="unix"`` and ``ring`` two socketpairs are made and the
    handle's ``link`` is a :class:`~pyethercat.link.redundant.RedundantLink`.
    ``busy_poll_us``, ``busy_poll_share`` and ``cpu`` are ``--busy-poll``,
    ``--busy-poll-share`` and ``--cpu``.
    """
    tmpdir = tempfile.TemporaryDirectory(prefix="pyecat-sim-")
    control_path = str(Path(tmpdir.name) / "control.sock")
    args = [sys.executable, "-m", "pyethercat", "sim", os.fspath(topology), "--control", control_path]
    if pcap is not None:
        args += ["--pcap", os.fspath(pcap)]
    if realtime:
        args += ["--realtime", str(int(realtime))]
    if busy_poll_us is not None:
        args += ["--busy-poll", str(float(busy_poll_us))]
    if busy_poll_share is not None:
        args += ["--busy-poll-share", str(float(busy_poll_share))]
    if cpu is not None:
        args += ["--cpu", str(int(cpu))]
    pass_fds: tuple[int, ...] = ()
    master_end: Link | None = None
    child_fds: list[int] = []
    if link == "unix":
        from pyethercat.link.unix import UnixLink

        ends: list[Link] = []
        for port in ("A", "B") if ring else ("A",):
            mine, child = UnixLink.pair(f"sim-master-{port}", f"sim-child-{port}", inheritable=True)
            ends.append(mine)
            child_fds.append(child.detach())
            args += ["--fd", str(child_fds[-1])]
        pass_fds = tuple(child_fds)
        if ring:
            from pyethercat.link.redundant import RedundantLink

            master_end = RedundantLink(ends[0], ends[1], name="sim-master")
        else:
            master_end = ends[0]
    elif link.startswith("iface:"):
        args += ["--iface", link.removeprefix("iface:")]
    elif link.startswith("udp:"):
        args += ["--udp", link.removeprefix("udp:")]
    else:
        tmpdir.cleanup()
        raise ConfigError(f"link spec {link!r}: use 'unix', 'iface:NAME' or 'udp:HOST:PORT'")
    if link_b is not None:
        if link_b.startswith("iface:"):
            args += ["--redundant-iface", link_b.removeprefix("iface:")]
        elif link_b.startswith("udp:") and link.startswith("udp:"):
            args += ["--udp", link_b.removeprefix("udp:")]
        else:
            tmpdir.cleanup()
            raise ConfigError(f"link spec {link_b!r} for port B: use 'iface:NAME' (with an "
                              f"iface port A) or 'udp:HOST:PORT' (with a udp port A)")
    # stderr goes to a file: a pipe nobody reads could fill up and stall the child.
    log_path = Path(tmpdir.name) / "stderr.log"
    try:
        with open(log_path, "wb") as log:
            process = subprocess.Popen(
                args, pass_fds=pass_fds, stdout=subprocess.DEVNULL, stderr=log
            )
    finally:
        for fd in child_fds:
            os.close(fd)
    handle = SimProcess(process, control_path, link=master_end, _tmpdir=tmpdir)
    try:
        handle.wait_ready(ready_timeout)
    except BaseException:
        handle.stop()
        raise
    return handle
