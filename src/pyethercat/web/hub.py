"""The dashboard's one reader of the master: polls telemetry and fans it out to the browsers.

However many browsers are open, one task asks the master for a snapshot
``rate`` times a second (at most 20, and only while a browser listens),
decodes it (:class:`~pyethercat.web.model.LiveModel`) and hands the same
message to every connected client. Each client has a queue of two: a slow
browser skips messages instead of holding up the others or the master.
Live messages are numbered (``push``, the hub's poll count) and the segment
message says the poll rate (``rate``), so a reader can count in pushes
(a cut cable is marked with the push that first showed it).

The hub also keeps the last ``history`` seconds of the series the charts
draw (cycle timing, working-counter errors, DC differences, drive position
and following error) and the event log, so a page opened later starts
with them.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from collections import deque
from typing import Any

from pyethercat.errors import EtherCATError
from pyethercat.master.control import messages as msg
from pyethercat.master.control.snapshot import rebuild
from pyethercat.master.control.telemetry_ops import TelemetryRequest
from pyethercat.master.telemetry import MAX_RATE
from pyethercat.web.model import LiveModel, describe_segment
from pyethercat.web.source import MasterConnection

__all__ = ["Hub", "Client"]

_EVENTS = 500
_SEGMENT = '{"type": "segment"'


class Client:
    """One browser's WebSocket: the newest messages, at most two waiting."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=2)
        self.dropped = 0

    def offer(self, text: str) -> None:
        if self.queue.full():
            # A slow browser loses the oldest live snapshot, not a segment message
            # (the static part it draws the pages from); of two segments the newer counts.
            waiting: list[str] = []
            while not self.queue.empty():
                waiting.append(self.queue.get_nowait())
            drop = next((i for i, t in enumerate(waiting) if not t.startswith(_SEGMENT)), 0)
            del waiting[drop]
            self.dropped += 1
            for t in waiting:
                self.queue.put_nowait(t)
        self.queue.put_nowait(text)


class Hub:
    """Polls the master for the dashboard (see the module text)."""

    def __init__(self, conn: MasterConnection, *, rate: float = 10.0, history: float = 60.0,
                 writable: bool = False) -> None:
        self.conn = conn
        self.rate = max(0.5, min(rate, MAX_RATE))
        self.points = max(10, int(history * self.rate))
        self.writable = writable
        self.clients: set[Client] = set()
        self.segment: dict[str, Any] | None = None
        self._model: LiveModel | None = None
        self._seq = 0
        self._lock = threading.Lock()
        self.events: deque[dict[str, Any]] = deque(maxlen=_EVENTS)
        self.series: dict[str, deque[Any]] = {}
        self.last: dict[str, Any] | None = None
        self.error = ""
        #: Snapshots asked for (the benchmark and the tests read it).
        self.polls = 0
        self._last_cycle: tuple[int, int, int] | None = None
        #: The segment was loaded again after a rescan and the browsers have not had it yet.
        self.rescanned = False

    # -- the static part --------------------------------------------------------------------

    def load_segment(self) -> dict[str, Any]:
        """Ask the master for its slaves and configuration (blocking: call from a thread)."""
        slaves_reply: msg.SlaveList = self.conn.call(msg.ListSlaves())
        slaves, _consistent = rebuild(slaves_reply.slaves)
        cfg_reply: msg.ConfigReply = self.conn.call(msg.GetConfig(compute=False))
        snap = self.conn.call(TelemetryRequest(registers=False))
        with self._lock:
            self._model = LiveModel(slaves, cfg_reply.config)
            self.segment = describe_segment(self.conn.link, slaves, cfg_reply.config,
                                            writable=self.writable, redundant=snap.redundant)
            self.segment["rate"] = self.rate
        return self.segment

    # -- polling ------------------------------------------------------------------------

    def poll_once(self) -> dict[str, Any]:
        """One snapshot, decoded and added to the history (blocking: call from a thread)."""
        if self._model is None:
            self.load_segment()
        snap = self.conn.call(TelemetryRequest(since=self._seq))
        self.polls += 1
        model = self._model
        if model is None or len(snap.slaves) != len(model.slaves):
            # The master scanned again: the static part changed (run() sends it to the
            # browsers before this snapshot).
            self.load_segment()
            self.rescanned = True
            model = self._model
            assert model is not None
            if len(snap.slaves) != len(model.slaves):
                snap = self.conn.call(TelemetryRequest(since=self._seq))
        with self._lock:
            live = model.live(snap, self.polls)
            self._seq = max(self._seq, max((e.seq for e in snap.events), default=0))
            for e in live["events"]:
                self.events.append(e)
            self._record(live)
            self.last = live
        return live

    def _series(self, name: str) -> deque[Any]:
        s = self.series.get(name)
        if s is None:
            s = self.series[name] = deque(maxlen=self.points)
        return s

    def _record(self, live: dict[str, Any]) -> None:
        t = round(live["time"], 3)
        c = live["cycle"]
        prev = self._last_cycle
        now = (c["late"], c["wkc_errors"], c["lost_frames"])
        delta = [max(0, a - b) for a, b in zip(now, prev, strict=True)] if prev else [0, 0, 0]
        self._last_cycle = now
        self._series("cycle").append([t, c["period_mean_us"], c["jitter_p99_us"],
                                      c["jitter_max_us"], c["rtt_p50_us"], c["rtt_p99_us"],
                                      *delta])
        self._series("dc").append([t] + [s["dc_difference_ns"] for s in live["slaves"]])
        for d in live["drives"]:
            self._series(f"drive{d['position']}").append(
                [t, d["position_actual"], d["following_error"], d["velocity"]])

    def history(self) -> dict[str, Any]:
        with self._lock:
            return {"type": "history", "series": {k: list(v) for k, v in self.series.items()},
                    "events": list(self.events)}

    async def run(self) -> None:
        """Poll while somebody listens; fan the messages out (runs until cancelled)."""
        period = 1.0 / self.rate
        while True:
            started = time.monotonic()
            if self.clients:
                try:
                    live = await asyncio.to_thread(self.poll_once)
                    self.error = ""
                    texts = [json.dumps({"type": "live", **live}, default=_json_default)]
                    if self.rescanned and self.segment is not None:
                        self.rescanned = False
                        texts.insert(0, json.dumps({"type": "segment", **self.segment}))
                except (EtherCATError, OSError) as exc:
                    self.error = str(exc)
                    texts = [json.dumps({"type": "error", "text": self.error})]
                for c in list(self.clients):
                    for text in texts:
                        c.offer(text)
            await asyncio.sleep(max(0.0, period - (time.monotonic() - started)))


def _json_default(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, float) and math.isnan(value):
        return None
    raise TypeError(f"cannot encode {type(value).__name__}")
