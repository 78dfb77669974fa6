"""Serving a simulated segment on a link, in this process or in a child process.

:class:`SimServer` takes frames from a :class:`~pyethercat.link.base.Link`,
passes each EtherCAT frame to :meth:`Segment.process` and sends the reply
back. Frames that are not EtherCAT are ignored. Between frames it runs
periodic work (:meth:`Segment.tick` when the segment has one, for watchdogs
and SYNC events) and the commands of a control channel.

A ring: with ``link_b`` the server is the segment's second master port too
(``sim.ring``). A frame arriving on either link enters the segment at that
master port (:meth:`Segment.process_from`) and leaves on the link of the
port it comes out at: in a closed ring, a frame the master sent on A comes
back on B.

Control channel: with ``control=PATH`` the server listens on a Unix stream
socket; each line a client writes is one JSON object, answered by one JSON
line (``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``)::

    {"cmd": "ping"}
    {"cmd": "slaves"}                      -> {"slaves": [{"index", "name", "al_status"}]}
    {"cmd": "break_link", "slave": "di8", "port": 1}  (slave by name or index)
    {"cmd": "restore_link", "slave": "di8", "port": 1}
    {"cmd": "power_off", "slave": "do8"}      {"cmd": "power_on", "slave": "do8"}
    {"cmd": "corrupt", "slave": "di8", "port": 0, "count": 1}
    {"cmd": "crc_rate", "slave": "di8", "port": 0, "rate": 0.001, "seed": 1}
    {"cmd": "port_fault", "port": "A", "broken": true}   (master port A or B of a ring)
    {"cmd": "remove", "slave": "do8"}   {"cmd": "insert", "slave": "do8"[, "device": "builtin:di8"]}
    {"cmd": "drop", "probability": 0.1, "seed": 1}
    {"cmd": "set_inputs", "slave": "di8", "data": "ff"}
    {"cmd": "outputs", "slave": "do8"}                -> {"data": "hex"}
    {"cmd": "stats"}                                  -> {"frames": n, "replies": n, ...}
    {"cmd": "dc"}                 -> {"slaves": [{"drift_ppm", "correction_ppm", "difference_ns",
                                     "sync0_pulses", "last_sync0": [system time, true ns]}]}
    {"cmd": "set_drift", "slave": "di8", "ppm": 20.0}
    {"cmd": "latch", "slave": "di8", "unit": 0, "rising": true}
    {"cmd": "eoe"}               -> {"slaves": [{"index", "name", "netns", "ip", "mac", ...}]}

Commands run in the server's thread between two frames, so they never race
with frame processing.

:func:`start_sim_process` runs ``pyethercat sim`` in a child process (for
tests and for a master that wants a private simulator) and returns a
:class:`SimProcess` handle: ``control(...)`` sends commands, ``stop()``
ends the child. With ``link="unix"`` the child serves one end of a Unix
socketpair and ``handle.link`` is the master's end.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import os
import select
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType
from typing import Any

from pyethercat.errors import ConfigError, EtherCATError, LinkClosedError, LinkDownError, LinkError
from pyethercat.link.base import MAX_FRAME, Link
from pyethercat.realtime import SpinBudget, apply_realtime, quiet_collector
from pyethercat.sim.eoe import eoe_server
from pyethercat.sim.reply_first import serve_reply_first
from pyethercat.sim.segment import Segment

# (their home until the split; the tests, benchmarks and the CLI import them from here too)
from pyethercat.sim.sim_process import READY_TIMEOUT, SimProcess, start_sim_process
from pyethercat.wire.frame import is_ethercat
from pyethercat.wire.registers import AL_STATUS

__all__ = ["READY_TIMEOUT", "ServerStats", "SimProcess", "SimServer", "serving_link", "start_sim_process"]

#: Default period of the segment's periodic work (watchdogs, SYNC), seconds.
DEFAULT_TICK_S = 0.001
#: Control commands that change the walk of frames (cables, power, slaves plugged).
_CHANGES_WALK = frozenset({"break_link", "restore_link", "power_off", "power_on", "port_fault",
                           "remove", "insert"})
#: Default time the serve loop polls for the next frame before blocking, seconds.
DEFAULT_BUSY_POLL_S = 0.0001
#: Idle ticks (no frame, nothing to serve) after which the loop runs a full collection.
_IDLE_COLLECT_TICKS = 1000


@dataclass
class ServerStats:
    """Counters of a running server (also returned by the ``stats`` command)."""

    frames: int = 0  # EtherCAT frames received
    replies: int = 0  # frames sent back
    lost: int = 0  # frames the segment did not return (dropped, destroyed)
    ignored: int = 0  # non-EtherCAT frames
    errors: int = 0  # frames the segment raised on (malformed)
    max_process_us: float = 0.0
    total_process_us: float = 0.0
    last_error: str = ""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-ready), with the mean processing time."""
        mean = self.total_process_us / self.frames if self.frames else 0.0
        return {
            "frames": self.frames,
            "replies": self.replies,
            "lost": self.lost,
            "ignored": self.ignored,
            "errors": self.errors,
            "mean_process_us": round(mean, 1),
            "max_process_us": round(self.max_process_us, 1),
            "last_error": self.last_error,
        }


class SimServer:
    """Answers the frames arriving on ``link`` with ``segment``.

    ``run()`` blocks until :meth:`stop` is called (from another thread or a
    signal handler) or the link closes. ``control`` is an optional Unix socket
    path for the JSON control channel. ``tick_s`` is the period of the
    segment's periodic work.
    """

    def __init__(
        self,
        segment: Any,
        link: Link,
        control: str | os.PathLike[str] | None = None,
        tick_s: float = DEFAULT_TICK_S,
        log: Callable[[str], None] | None = None,
        link_b: Link | None = None,
        busy_poll_s: float = DEFAULT_BUSY_POLL_S,
        busy_poll_share: float | None = None,
    ) -> None:
        self.segment = segment
        self.link = link
        #: The link of master port B (a ring), or None.
        self.link_b = link_b
        self._links = [link] if link_b is None else [link, link_b]
        if link_b is not None:
            if segment.ring is None:
                segment.close_ring()
            segment.attach_port_b()
        self.tick_s = tick_s
        #: Seconds the loop keeps polling the links after a frame before it blocks
        #: again (see :meth:`_busy_poll`); 0: block at once.
        self.busy_poll_s = busy_poll_s if (os.cpu_count() or 1) > 1 else 0.0
        self._next_tick = 0.0
        # One receive buffer for every frame (links receive into it: poll_into).
        self._rx = bytearray(MAX_FRAME + 64)
        self._rx_view = memoryview(self._rx)
        #: Cyclic frames answered before their writes are applied (``sim.reply_first``):
        #: a segment of this package on one master port.
        self._reply_first = link_b is None and isinstance(segment, Segment)
        # The firmware's reactions to a frame (device applications, mailbox handlers)
        # run after its reply went out (Segment.after_frame), before the next frame.
        self._after_frame: Callable[[], None] | None = None
        if isinstance(segment, Segment):
            segment.after_frame.hold = True
            self._after_frame = segment.after_frame.run
        self._t_reply = 0.0
        #: Ticks in a row without a frame or anything else to serve.
        self._idle_ticks = 0
        #: The busy-poll's share of each second (see SpinBudget); None: unlimited.
        self._spin_budget: SpinBudget | None = None
        #: The share asked for (None: SpinBudget.for_this_process decides; 1: no limit).
        self.busy_poll_share = busy_poll_share
        self.stats = ServerStats()
        self._log = log or (lambda _msg: None)
        self._stop = threading.Event()
        # A pipe wakes the select loop when stop() or call() is used from elsewhere.
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._calls: deque[tuple[Callable[[], Any], list[Any], threading.Event]] = deque()
        self._control_path = os.fspath(control) if control is not None else None
        self._control: socket.socket | None = None
        self._clients: dict[int, tuple[socket.socket, bytearray]] = {}
        self._tick = getattr(segment, "tick", None)
        # EoE slaves whose IP side has descriptors (a TAP in a namespace): watched in
        # this loop, so their frames enter the segment between two EtherCAT frames.
        self._eoe = [server for s in getattr(segment, "slaves", ())
                     if (server := eoe_server(getattr(getattr(s, "spec", None), "app", None))) is not None]
        if self._control_path is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self._control_path)
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.bind(self._control_path)
            sock.listen(4)
            sock.setblocking(False)
            self._control = sock

    # --- control from other threads ---------------------------------------------

    def stop(self) -> None:
        """Ask :meth:`run` to return (safe from any thread and from signal handlers)."""
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")

    def call(self, fn: Callable[[], Any], timeout: float = 5.0) -> Any:
        """Run ``fn()`` in the server thread between frames and return its result."""
        done = threading.Event()
        box: list[Any] = []
        self._calls.append((fn, box, done))
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"c")
        if not done.wait(timeout):
            raise TimeoutError("the simulator server did not run the call in time")
        if box and isinstance(box[0], BaseException):
            raise box[0]
        return box[0] if box else None

    # --- the loop ----------------------------------------------------------------

    def run(self) -> None:
        """Serve until stopped or the link closes."""
        # (here, not in __init__: serve() asks for SCHED_FIFO after building the server)
        self._spin_budget = self.spin_budget()
        links = self._links
        fds = [link.fileno() for link in links]
        sel = [fd for fd in fds if fd is not None]
        self._next_tick = time.monotonic() + self.tick_s
        try:
            while not self._stop.is_set():
                readers = self._readers()
                if None in fds:
                    # No descriptor (in-process pair link): poll in short steps.
                    step = min(self.tick_s, 0.0005) / len(links)
                    for port, link in enumerate(links):
                        self._serve_frames(link.recv(step), port)
                    self._run_calls()
                    if readers:
                        ready, _, _ = select.select(list(readers), [], [], 0)
                        for r in ready:
                            readers[r]()
                    self._tick_if_due(time.monotonic())
                    continue
                others = [self._wake_r]
                if self._control is not None:
                    others.append(self._control.fileno())
                others.extend(self._clients)
                others.extend(readers)
                wait = max(0.0, self._next_tick - time.monotonic())
                ready, _, _ = select.select([*sel, *others], [], [], wait)
                if ready:
                    self._idle_ticks = 0
                else:
                    self._idle_ticks += 1
                    if self._idle_ticks == _IDLE_COLLECT_TICKS:
                        # A second without a frame: the full collection the serving went
                        # without, its survivors frozen too.
                        quiet_collector()
                for r in ready:
                    if r in readers:
                        readers[r]()
                served = 0
                for port, fd in enumerate(fds):
                    if fd in ready:
                        served += self._drain(port)
                if self._wake_r in ready:
                    with contextlib.suppress(OSError):
                        os.read(self._wake_r, 4096)
                self._run_calls()
                self._serve_control(ready)
                self._tick_if_due(time.monotonic())
                if served and self.busy_poll_s > 0:
                    self._busy_poll(sel, others)
        except LinkClosedError:
            self._log("link closed by the peer; stopping")
        finally:
            self._close_control()

    def spin_budget(self) -> SpinBudget | None:
        """The busy-poll's budget for this process as it runs now (None: unlimited)."""
        share = self.busy_poll_share
        if share is None:
            return SpinBudget.for_this_process()
        return None if share >= 1.0 else SpinBudget(share)

    def _tick_if_due(self, now: float) -> None:
        if now >= self._next_tick:
            if self._tick is not None:
                self._tick()
            seg = self.segment
            if getattr(seg, "unsettled", False):
                # Compile between frames what the master's configuration changed (at
                # most once a tick), not on the first cyclic frame, which a real ESC
                # answers as fast as any other.
                seg.settle()
            self._next_tick = now + self.tick_s

    def _drain(self, port: int) -> int:
        """Serve every frame waiting on a port's link (one buffer for all); how many."""
        link = self._links[port]
        buf = self._rx
        view = self._rx_view
        served = 0
        try:
            while n := link.poll_into(buf):
                self._serve_frames(view[:n], port)
                served += 1
        except LinkDownError as exc:
            # The interface going down is no reason to stop serving: a segment's
            # cable is plugged in again (the socket works once it is up).
            self.stats.errors += 1
            self.stats.last_error = str(exc)
            self._log(f"{exc}; serving on when it is back")
        return served

    def _busy_poll(self, frame_fds: list[int], others: list[int]) -> None:
        """Poll the links without sleeping for ``busy_poll_s`` after the last frame.

        Waking from a blocking wait costs a round trip some 13 us on a virtual
        machine (measured: a Python echo over a veth pair answers in 8 us when
        it polls, 21 us when it blocks), more than serving a small frame. A
        master that sends its next frame within that time (the next SDO step,
        a cycle at 10 kHz, a round-trip benchmark) is answered from the poll.
        Any other descriptor that becomes ready (control, EoE, a call from
        another thread) ends the poll, so the select loop serves it at once.
        The polling keeps to a share of each second
        (:class:`~pyethercat.realtime.SpinBudget`: below the kernel's real-time
        share under SCHED_FIFO, and 20 % on a virtual machine, whose host takes
        a vCPU that spins long off the CPU for milliseconds): past it the loop
        blocks instead.
        """
        monotonic = time.monotonic
        start = monotonic()
        budget = self._spin_budget
        if budget is not None and not budget.allowed(start):
            return  # (this second's share is spent: block in select)
        try:
            self._poll_frames(frame_fds, others, start)
        finally:
            if budget is not None:
                budget.spent(monotonic() - start)

    def _poll_frames(self, frame_fds: list[int], others: list[int], start: float) -> None:
        poller = select.poll()
        for fd in frame_fds:
            poller.register(fd, select.POLLIN)
        for fd in others:
            poller.register(fd, select.POLLIN)
        window = self.busy_poll_s
        monotonic = time.monotonic
        end = start + window
        stop = self._stop
        while not stop.is_set():
            events = poller.poll(0)
            now = monotonic()
            if events:
                served = 0
                for fd, _ in events:
                    if fd not in frame_fds:
                        return
                    served += self._drain(frame_fds.index(fd))
                if served:
                    end = now + window
            elif now >= end:
                return
            if now >= self._next_tick:
                self._tick_if_due(now)

    def _readers(self) -> dict[int, Callable[[], None]]:
        """Descriptors of EoE endpoints that have room for frames now."""
        if not self._eoe:
            return {}
        return {fd: cb for server in self._eoe for fd, cb in server.readers()}

    def _serve_frames(self, frame: bytes | memoryview | None, port: int = 0) -> None:
        try:
            self._serve_frame(frame, port)
        finally:
            if self._after_frame is not None:
                self._after_frame()

    def _serve_frame(self, frame: bytes | memoryview | None, port: int = 0) -> None:
        if frame is None:
            return
        if not is_ethercat(frame):
            self.stats.ignored += 1
            return
        stats = self.stats
        stats.frames += 1
        t0 = self._t_reply = time.perf_counter()
        out = self.link
        try:
            # A cyclic frame: its reply goes before its writes are applied.
            if self._reply_first and serve_reply_first(self.segment, frame, self._send_first):
                self._count_time(t0)
                return
            if self.link_b is None:
                reply = self.segment.process(frame)
            else:
                got = self.segment.process_from(frame, port)
                reply = None if got is None else got[1]
                if got is not None:
                    out = self._links[got[0]]
        except LinkClosedError:
            raise
        except LinkError as exc:
            # (the reply of a frame answered first: the frame's effects hold)
            stats.errors += 1
            stats.last_error = str(exc)
            self._count_time(t0)
            return
        except EtherCATError as exc:
            # A malformed frame dies in the first slave, as on a real wire.
            stats.errors += 1
            stats.last_error = str(exc)
            reply = None
        self._t_reply = time.perf_counter()
        self._count_time(t0)
        if reply is None:
            stats.lost += 1
            return
        try:
            out.send(reply)
        except LinkClosedError:
            raise
        except LinkError as exc:
            stats.errors += 1
            stats.last_error = str(exc)
            return
        stats.replies += 1

    def _send_first(self, reply: bytes) -> None:
        """Send a reply answered before the frame's writes (``sim.reply_first``)."""
        self._t_reply = time.perf_counter()
        self.link.send(reply)
        self.stats.replies += 1

    def _count_time(self, t0: float) -> None:
        """Processing time of a frame: from its arrival to its reply handed to the link."""
        dt = (self._t_reply - t0) * 1e6
        stats = self.stats
        stats.total_process_us += dt
        if dt > stats.max_process_us:
            stats.max_process_us = dt

    def _run_calls(self) -> None:
        while self._calls:
            fn, box, done = self._calls.popleft()
            try:
                box.append(fn())
            except BaseException as exc:  # handed back to the caller's thread
                box.append(exc)
            done.set()

    # --- control channel -----------------------------------------------------------

    def _serve_control(self, ready: list[int]) -> None:
        if self._control is None:
            return
        if self._control.fileno() in ready:
            with contextlib.suppress(BlockingIOError):
                conn, _ = self._control.accept()
                conn.setblocking(False)
                self._clients[conn.fileno()] = (conn, bytearray())
        for cfd in [c for c in ready if c in self._clients]:
            conn, buf = self._clients[cfd]
            try:
                data = conn.recv(65536)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if not data:
                del self._clients[cfd]
                conn.close()
                continue
            buf += data
            while b"\n" in buf:
                line, _, rest = bytes(buf).partition(b"\n")
                buf[:] = rest
                answer = self.command_line(line)
                with contextlib.suppress(OSError):
                    conn.setblocking(True)
                    conn.sendall(answer + b"\n")
                    conn.setblocking(False)

    def command_line(self, line: bytes) -> bytes:
        """Run one JSON command line, return the JSON answer line (no newline)."""
        try:
            request = json.loads(line)
            if not isinstance(request, dict):
                raise ValueError("a command is a JSON object")
            result = self.command(request)
            answer: dict[str, Any] = {"ok": True, **result}
        except (ValueError, KeyError, TypeError, EtherCATError) as exc:
            answer = {"ok": False, "error": str(exc) or type(exc).__name__}
        return json.dumps(answer).encode()

    def _slave(self, request: dict[str, Any]) -> int:
        ref = request["slave"]
        slaves = self.segment.slaves
        if isinstance(ref, int) and not isinstance(ref, bool):
            if not 0 <= ref < len(slaves):
                raise ValueError(f"no slave {ref} (the segment has {len(slaves)})")
            return ref
        for s in slaves:
            if s.name == ref:
                return int(s.index)
        raise ValueError(f"no slave named {ref!r}")

    def command(self, request: dict[str, Any]) -> dict[str, Any]:
        """Run one control command (a dict, see the module text); returns the answer fields."""
        cmd = request.get("cmd")
        seg = self.segment
        if cmd == "ping":
            return {}
        answer = self._command(cmd, request)
        settle = getattr(seg, "settle", None)
        if cmd in _CHANGES_WALK and settle is not None:
            settle()  # between frames, as a real cable change costs the next frame nothing
        return answer

    def _command(self, cmd: object, request: dict[str, Any]) -> dict[str, Any]:
        seg = self.segment
        if cmd == "slaves":
            return {"slaves": [{"index": s.index, "name": s.name,
                                "al_status": s.u16(AL_STATUS)} for s in seg.slaves]}
        if cmd == "stats":
            return self.stats.as_dict()
        if cmd == "eoe":
            return {"slaves": eoe_status(seg)}
        if cmd in ("break_link", "restore_link"):
            getattr(seg, cmd)(self._slave(request), int(request["port"]))
            return {}
        if cmd in ("power_off", "power_on"):
            getattr(seg, cmd)(self._slave(request))
            return {}
        if cmd == "corrupt":
            seg.corrupt_frames(
                self._slave(request), int(request["port"]), int(request.get("count", 1))
            )
            return {}
        if cmd == "crc_rate":
            seed = request.get("seed")
            seg.crc_error_rate(self._slave(request), int(request["port"]), float(request["rate"]),
                               None if seed is None else int(seed))
            return {}
        if cmd == "port_fault":
            seg.master_port_fault(_master_port(request["port"]), bool(request.get("broken", True)))
            return {}
        if cmd == "remove":
            seg.remove_slave(self._slave(request))
            return {}
        if cmd == "insert":
            index = self._slave(request)
            device = request.get("device")
            seg.insert_slave(index, None if device is None else _device_spec(
                str(device), str(request.get("name", seg.slaves[index].name))))
            return {}
        if cmd == "ring":
            return {"ring": None if seg.ring is None else list(seg.ring)}
        if cmd == "drop":
            seed = request.get("seed")
            seg.drop_probability(float(request["probability"]), None if seed is None else int(seed))
            return {}
        if cmd == "set_inputs":
            _pdi(seg.slaves[self._slave(request)]).set_inputs(bytes.fromhex(str(request["data"])))
            return {}
        if cmd == "outputs":
            return {"data": _pdi(seg.slaves[self._slave(request)]).outputs().hex()}
        if cmd == "dc":
            return {"slaves": seg.dc_report(), "now_ns": seg.clock.now_ns()}
        if cmd == "set_drift":
            seg.set_drift(self._slave(request), float(request["ppm"]))
            return {}
        if cmd == "latch":
            seg.latch_input(self._slave(request), int(request.get("unit", 0)),
                            bool(request.get("rising", True)))
            return {}
        if cmd == "emergency":
            # a CoE device's server sends an emergency through its mailbox
            from pyethercat.sim.coe import coe_server

            try:
                coe = coe_server(seg.slaves[self._slave(request)].spec.app)
            except ValueError:
                raise ValueError("that slave has no CoE emergency") from None
            sent = coe.emergency(int(request["code"]), int(request.get("register", 0)),
                                 bytes.fromhex(str(request.get("data", ""))))
            return {"sent": bool(sent)}
        raise ValueError(f"unknown command {cmd!r}")

    def _close_control(self) -> None:
        for conn, _ in self._clients.values():
            conn.close()
        self._clients.clear()
        if self._control is not None:
            self._control.close()
            self._control = None
            if self._control_path is not None:
                with contextlib.suppress(OSError):
                    os.unlink(self._control_path)

    def close(self) -> None:
        """Release the wake-up pipe and the control socket (the link is the caller's)."""
        if self._after_frame is not None:
            # The segment outlives the server: its frames' work is theirs again.
            self.segment.after_frame.hold = False
            self._after_frame()
        self._close_control()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)


def _master_port(value: Any) -> int:
    """Master port A/B (or 0/1) of a control command."""
    text = str(value).strip().upper()
    if text in ("A", "0"):
        return 0
    if text in ("B", "1"):
        return 1
    raise ValueError(f"master port {value!r}: use A or B")


def _device_spec(device: str, name: str) -> Any:
    """A slave spec for a device named as in a topology file (``builtin:KEY``)."""
    from pyethercat.sim.topology import device_spec

    return device_spec(device, name)


def _pdi(slave: Any) -> Any:
    """The PDI side of a segment slave."""
    return slave.esc.pdi


# --- links from a command-line spec ---------------------------------------------------


def serving_link(
    iface: str | None = None,
    udp: str | None = None,
    fd: int | None = None,
    pcap: str | os.PathLike[str] | None = None,
) -> Link:
    """The link a simulator serves on, opened by :func:`pyethercat.link.open_link`: a
    network interface (raw socket), a UDP address to bind (the segment answers whoever
    sends; a master's ``udp:`` link sends to it instead), or an inherited socket fd.

    With ``pcap`` every frame in and out is recorded to that file.
    """
    from pyethercat.link.registry import open_link

    given = [x for x in (iface, udp, fd) if x is not None]
    if len(given) != 1:
        raise ConfigError("serve on exactly one of an interface, a UDP address or a socket fd")
    if iface is not None:
        link = open_link(f"raw:{iface}")
    elif udp is not None:
        link = open_link(f"udp:{udp}", serve=True)
    else:
        link = open_link(f"unix:fd:{fd}")
    if pcap is not None:
        from pyethercat.link.capture import CaptureLink

        link = CaptureLink(link, pcap, flush=True)
    return link


def serve(
    topology: str | os.PathLike[str],
    link: Link,
    control: str | os.PathLike[str] | None = None,
    log: Callable[[str], None] | None = None,
    install_signals: bool = True,
    realtime: int = 0,
    link_b: Link | None = None,
    busy_poll_s: float = DEFAULT_BUSY_POLL_S,
    cpu: int | None = None,
    busy_poll_share: float | None = None,
) -> ServerStats:
    """Load ``topology``, serve it on ``link`` with a wall clock until SIGINT/SIGTERM.

    ``link_b``: master port B of a ring (see :class:`SimServer`).

    ``realtime`` > 0 serves under SCHED_FIFO with that priority where the
    process may; otherwise it is logged and ignored. A real ESC answers within
    microseconds; a simulator that the scheduler leaves waiting for
    milliseconds on a loaded machine makes masters with short frame timeouts
    (SOEM: 2 ms per mailbox read) give frames up and retry.
    ``cpu`` pins the process to that CPU; ``busy_poll_s`` is how long the loop
    polls for the next frame before it blocks and ``busy_poll_share`` the share
    of each second it may poll (see :class:`SimServer`).
    """
    from pyethercat.clock import WallClock
    from pyethercat.sim.topology import close_eoe, load_topology

    segment = load_topology(os.fspath(topology)).build(clock=WallClock())
    try:
        server = SimServer(segment, link, control=control, log=log, link_b=link_b,
                           busy_poll_s=busy_poll_s, busy_poll_share=busy_poll_share)
    except BaseException:
        close_eoe(segment)
        raise
    # Everything built so far lives as long as the server: out of the collector's
    # generations, and no full collection while serving (it stalled replies for 15-25 ms;
    # see quiet_collector), only when the link has been idle a second (run()).
    quiet_collector()
    if realtime or cpu is not None:
        if realtime and not 1 <= realtime <= 99:
            raise ConfigError(f"real-time priority {realtime}: use 1..99")
        got = apply_realtime(realtime, cpu)
        if log is not None:
            for why in got.missing:
                log(f"serving without it: {why}")
    previous: dict[int, Any] = {}

    def on_signal(signum: int, frame: FrameType | None) -> None:
        server.stop()

    if install_signals and threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[int(sig)] = signal.signal(sig, on_signal)
    try:
        if log is not None:
            ring = segment.ring or (0, 0)
            where = link.name if link_b is None else (
                f"{link.name} (port A) and {link_b.name} (port B, ring at slave "
                f"{ring[0]} port {ring[1]})")
            log(f"serving {len(segment.slaves)} simulated slaves from {topology} on {where}")
            for line in eoe_lines(segment):
                log(line)
        server.run()
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        server.close()
        close_eoe(segment)
    return server.stats


def eoe_status(segment: Any) -> list[dict[str, Any]]:
    """The EoE slaves of a segment: namespace, address and frame counters."""
    out: list[dict[str, Any]] = []
    for s in segment.slaves:
        server = eoe_server(s.spec.app)
        if server is None:
            continue
        p = server.endpoint.parameters()
        out.append({"index": s.index, "name": s.name,
                    "netns": getattr(server.endpoint, "netns", None),
                    "ip": str(p.ip) if p.ip is not None else None,
                    "prefix": ipaddress.IPv4Network(f"0.0.0.0/{p.subnet}").prefixlen
                    if p.subnet is not None else None,
                    "mac": p.mac.hex(":") if p.mac else None,
                    "frames_in": server.receiver.stats.frames,
                    "frames_out": server.sender.stats.frames,
                    "dropped_in": server.receiver.stats.dropped,
                    "dropped_out": server.sender.stats.dropped})
    return out


def eoe_lines(segment: Any) -> list[str]:
    """One line per EoE slave: its name, IP side (namespace) and address."""
    out: list[str] = []
    for s in segment.slaves:
        server = eoe_server(s.spec.app)
        if server is None:
            continue
        p = server.endpoint.parameters()
        where = getattr(server.endpoint, "netns", None)
        side = f"namespace {where}" if where else "echo stack"
        addr = f"{p.ip}/{p.subnet}" if p.ip is not None else "no address yet"
        out.append(f"EoE slave {s.index} {s.name}: {side}, {addr}")
    return out
