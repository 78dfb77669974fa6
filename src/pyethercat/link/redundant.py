"""Two links as the two ports of a ring master (cable redundancy).

A ring: the master's port A feeds the first slave's port 0, port B is
cabled to the last slave's free port. :class:`RedundantLink` holds the two
links (raw interfaces, UDP peers, in-process pairs; any :class:`Link`) and
is one link itself: ``send`` puts a frame on both ports, ``recv`` returns
frames from either, so code written for one port runs unchanged.

The master's scheduler knows more: it asks :meth:`RedundantLink.recv_from`
for the port a frame came in on and sends with :meth:`RedundantLink.send_on`
on the ports its PDU core chooses, which merges the two copies of every
frame into one reply (``pyethercat.master.redundancy``). The link moves
frames and nothing else; it counts them per port (``stats``) and reports
each port's carrier where the medium knows it.

A port that refuses a frame (its interface went down) does not fail the
other: ``send`` raises only when no port took the frame. A port whose peer
has gone for good (a closed socketpair, a deleted interface) is left out of
receiving; ``recv`` raises only when both have gone.
"""

from __future__ import annotations

import contextlib
import select
import time
from dataclasses import dataclass

from pyethercat.errors import EtherCATError, LinkClosedError, LinkError
from pyethercat.link.base import Link

__all__ = ["RedundantPortStats", "RedundantLink"]

#: Blocking waits are cut into slices this long when a port has no descriptor.
_POLL_SLICE = 0.0002


@dataclass
class RedundantPortStats:
    """Frames through one port of a redundant link."""

    sent: int = 0
    received: int = 0
    #: Sends the port refused (interface down, no carrier).
    refused: int = 0
    last_error: str = ""


class RedundantLink(Link):
    """Ports A (``primary``) and B (``secondary``) of a ring, as one link (see the module text)."""

    #: Marks a link whose ports the scheduler may address one by one.
    port_count = 2

    def __init__(self, primary: Link, secondary: Link, name: str | None = None) -> None:
        super().__init__(name or f"{primary.name}+{secondary.name}")
        self.ports: tuple[Link, Link] = (primary, secondary)
        # Direction known only if both ports know it.
        self.sees_own_frames = primary.sees_own_frames or secondary.sees_own_frames
        self.stats = (RedundantPortStats(), RedundantPortStats())
        self._next = 0  # port polled first (fairness when both have frames)
        #: Why a port has gone for good (None: it works).
        self.gone: list[str | None] = [None, None]

    @property
    def primary(self) -> Link:
        return self.ports[0]

    @property
    def secondary(self) -> Link:
        return self.ports[1]

    def port_carrier(self, port: int) -> bool | None:
        """Whether port ``port`` has a link partner (None: the medium cannot tell)."""
        fn = getattr(self.ports[port], "carrier", None)
        if fn is None:
            return None
        try:
            value = fn()
        except EtherCATError:
            return False
        return None if value is None else bool(value)

    def carrier(self) -> bool | None:
        """Carrier on either port (None: neither can tell)."""
        states = [self.port_carrier(p) for p in (0, 1)]
        if any(states):
            return True
        return None if None in states else False

    def send_on(self, port: int, frame: bytes) -> None:
        """Send ``frame`` on port ``port`` (0 = A, 1 = B); raises what that port raises."""
        self._check_open()
        stats = self.stats[port]
        try:
            self.ports[port].send(frame)
        except EtherCATError as exc:
            stats.refused += 1
            stats.last_error = str(exc)
            raise
        stats.sent += 1

    def send(self, frame: bytes) -> None:
        """Send on both ports; raises only when neither took the frame."""
        self._check_open()
        errors: list[EtherCATError] = []
        for port in (0, 1):
            try:
                self.send_on(port, frame)
            except EtherCATError as exc:
                errors.append(exc)
        if len(errors) == 2:
            raise LinkError(f"{self.name}: neither port took the frame: {errors[0]}; {errors[1]}")

    def recv(self, timeout: float | None = None) -> bytes | None:
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, int] | None:
        """One frame and the port it came in on, or None after ``timeout`` seconds."""
        self._check_open()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            got = self._poll()
            if got is not None:
                return got
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            live = [p for p in (0, 1) if self.gone[p] is None]
            fds = [self.ports[p].fileno() for p in live]
            if None in fds:
                # In-process ports: wait a short slice on each in turn.
                step = _POLL_SLICE if left is None else min(_POLL_SLICE, left)
                for port in live:
                    frame = self._recv_port(port, step / len(live))
                    if frame is not None:
                        return self._got(frame, port)
                continue
            with contextlib.suppress(InterruptedError, ValueError):
                select.select([fd for fd in fds if fd is not None], [], [], left)
            self._check_open()

    def _recv_port(self, port: int, timeout: float) -> bytes | None:
        """A frame from one port; a port whose peer has gone is left out from then on."""
        try:
            return self.ports[port].recv(timeout)
        except LinkClosedError as exc:
            self._check_open()
            self.gone[port] = str(exc)
            if all(self.gone):
                raise LinkClosedError(f"{self.name}: both ports have gone: {self.gone[0]}; "
                                      f"{self.gone[1]}") from exc
            return None

    def _poll(self) -> tuple[bytes, int] | None:
        """A frame already waiting on either port (the ports take turns going first)."""
        first = self._next
        for port in (first, 1 - first):
            if self.gone[port] is not None:
                continue
            frame = self._recv_port(port, 0)
            if frame is not None:
                return self._got(frame, port)
        return None

    def _got(self, frame: bytes, port: int) -> tuple[bytes, int]:
        self.stats[port].received += 1
        self._next = 1 - port
        return frame, port

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for p in self.ports:
            p.close()
