"""The dashboard application without a browser: access rules, headers, the page's own files.

A real master on the in-process simulated demo segment (pair link, virtual
time) is served through :class:`DirectConnection`; Starlette's test client
speaks HTTP and WebSocket to the application.
"""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")

from starlette.testclient import TestClient  # noqa: E402
from starlette.websockets import WebSocketDisconnect  # noqa: E402

from pyethercat.clock import VirtualClock  # noqa: E402
from pyethercat.errors import ConfigError  # noqa: E402
from pyethercat.link.pair import PairLink  # noqa: E402
from pyethercat.master.control.handlers import MasterContext  # noqa: E402
from pyethercat.master.master import Master  # noqa: E402
from pyethercat.web.app import STATIC, create_app  # noqa: E402
from pyethercat.web.hub import Hub  # noqa: E402
from pyethercat.web.security import Access, check_bind, parse_bind  # noqa: E402
from pyethercat.web.source import DirectConnection  # noqa: E402

DEMO = Path(__file__).resolve().parents[2] / "examples" / "demo.toml"
HOST = {"host": "127.0.0.1:8080"}


@pytest.fixture(scope="module")
def master() -> Master:
    from pyethercat.sim.topology import load_topology

    seg = load_topology(DEMO).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    m.configure()
    return m


def _client(master: Master, **access: object) -> TestClient:
    conn = DirectConnection(MasterContext(master, "sim:demo"))
    acc = Access("127.0.0.1", 8080, **access)  # type: ignore[arg-type]
    return TestClient(create_app(Hub(conn, writable=acc.writable), acc),
                      base_url="http://127.0.0.1:8080")


def test_read_only_loopback_serves_reads_and_refuses_writes(master: Master) -> None:
    with _client(master) as c:
        page = c.get("/")
        assert page.status_code == 200
        csp = page.headers["content-security-policy"]
        assert "script-src 'self'" in csp and "unsafe-inline" not in csp and "unsafe-eval" not in csp
        assert page.headers["x-frame-options"] == "DENY"
        seg = c.get("/api/segment").json()
        assert [s["name"][:7] for s in seg["slaves"]] == ["PEC-CU4", "PEC-DO8", "PEC-DI8",
                                                          "PEC-DO8", "PEC-DI2", "PEC-AI2"]
        assert seg["writable"] is False
        live = c.get("/api/live").json()
        assert [s["state"] for s in live["slaves"]] == ["PREOP"] * 6 or live["slaves"]
        w = c.post("/api/pdo/write", json={"position": 3, "name": "Channel 1.Output", "value": 1})
        assert w.status_code == 403 and "read-only" in w.json()["error"]
        assert c.post("/api/sdo/write", json={"position": 0, "index": 0x1000, "value": "1"}
                      ).status_code == 403


def test_a_token_guards_every_request_and_the_websocket(master: Master) -> None:
    with _client(master, token="s3cret", writable=True) as c:
        assert c.get("/").status_code == 403
        assert c.get("/static/app.js").status_code == 403
        assert c.get("/api/live").status_code == 403
        with pytest.raises(WebSocketDisconnect) as refused, c.websocket_connect("/ws", headers=HOST):
            pass
        assert refused.value.code == 1008
        # Opening the printed address trades the token for an HttpOnly cookie.
        r = c.get("/?token=s3cret", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/"
        cookie = r.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie.replace("Strict", "strict")
        assert c.get("/api/live").status_code == 200  # the cookie now rides along
        with c.websocket_connect("/ws", headers={**HOST, "cookie": "pyecat_token=s3cret"}) as ws:
            first = json.loads(ws.receive_text())
            assert first["type"] == "segment" and len(first["slaves"]) == 6
            assert json.loads(ws.receive_text())["type"] == "history"
            live = json.loads(ws.receive_text())
            assert live["type"] == "live" and len(live["slaves"]) == 6
        # A write from another origin, or as a form, is refused even with the cookie.
        body = {"position": 3, "name": "Channel 1.Output", "value": 1}
        assert c.post("/api/pdo/write", json=body,
                      headers={"origin": "http://evil.example"}).status_code == 403
        assert c.post("/api/pdo/write", content="position=3",
                      headers={"content-type": "application/x-www-form-urlencoded"}
                      ).status_code == 415
    with _client(master, token="s3cret", writable=True) as c:
        ok = c.post("/api/pdo/write", json=body, headers={"authorization": "Bearer s3cret"})
        assert ok.status_code == 200, ok.text
        assert master.slaves[3].outputs["Channel 1.Output"] is True
        assert c.post("/api/pdo/write", json=body,
                      headers={"authorization": "Bearer nope"}).status_code == 403


def test_a_write_that_is_no_json_object_is_refused_in_one_line(master: Master) -> None:
    token = {"authorization": "Bearer s3cret"}
    before = master.slaves[3].outputs["Channel 1.Output"]
    with _client(master, token="s3cret", writable=True) as c:
        for path in ("/api/pdo/write", "/api/sdo/write"):
            listed = c.post(path, json=[3, "Channel 1.Output", 1], headers=token)
            assert listed.status_code == 400 and listed.json() == {
                "error": "the request is not a JSON object"}
            broken = c.post(path, content="{position: 3",
                            headers={"content-type": "application/json", **token})
            assert broken.status_code == 400 and broken.json() == {
                "error": "the request is not JSON"}
        assert master.slaves[3].outputs["Channel 1.Output"] == before


def test_a_foreign_host_header_is_refused(master: Master) -> None:
    """A page that rebinds its own name to 127.0.0.1 cannot read the dashboard."""
    with _client(master) as c:
        assert c.get("/api/segment", headers={"host": "evil.example:8080"}).status_code == 403
        assert c.get("/api/segment", headers={"host": "localhost:8080"}).status_code == 200


def test_bind_rules() -> None:
    assert parse_bind("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_bind(":0") == ("127.0.0.1", 0)
    assert parse_bind("[::1]:9000") == ("::1", 9000)
    assert check_bind("127.0.0.1", None) is None
    assert check_bind("::1", None) is None
    with pytest.raises(ConfigError, match="without a token"):
        check_bind("0.0.0.0", None)
    with pytest.raises(ConfigError, match="without a token"):
        check_bind("192.168.1.20", None)
    assert check_bind("0.0.0.0", "t") == "t"
    assert check_bind("0.0.0.0", None, generate=True)
    with pytest.raises(ConfigError):
        parse_bind("host:http")


class _Inline(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.problems: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        names = {k for k, _ in attrs}
        if tag == "script" and "src" not in names:
            self.problems.append("inline <script>")
        if tag == "style":
            self.problems.append("<style> element")
        self.problems += [f"{tag} {k}=" for k in names if k == "style" or k.startswith("on")]
        for k, v in attrs:
            if v and (v.startswith("http://") or v.startswith("https://")):
                self.problems.append(f"external {k}={v}")


def test_the_page_has_no_inline_code_and_fetches_nothing_from_outside() -> None:
    parser = _Inline()
    parser.feed((STATIC / "index.html").read_text())
    assert parser.problems == []
    script = (STATIC / "app.js").read_text()
    assert not re.search(r"https?://(?!www\.w3\.org/2000/svg)", script)
    assert "innerHTML" not in script and "eval(" not in script
    assert "MIT License" in (STATIC / "LICENSE-uPlot.txt").read_text()
    assert (STATIC / "uplot.iife.min.js").stat().st_size > 40_000


def test_a_rescan_sends_the_segment_again_and_a_slow_browser_keeps_it(master: Master) -> None:
    import asyncio

    from pyethercat.web.hub import Client
    from pyethercat.web.model import LiveModel

    hub = Hub(DirectConnection(MasterContext(master, "sim:demo")), rate=20.0)
    hub.load_segment()
    # The segment as the hub knew it before the master scanned again (one slave fewer).
    hub._model = LiveModel(master.slaves[:-1], None)
    client = Client()
    hub.clients.add(client)

    async def one_round() -> list[str]:
        task = asyncio.create_task(hub.run())
        got = [await asyncio.wait_for(client.queue.get(), 30.0) for _ in range(2)]
        task.cancel()
        return got

    first, second = asyncio.run(one_round())
    seg, live = json.loads(first), json.loads(second)
    assert seg["type"] == "segment" and len(seg["slaves"]) == len(master.slaves)
    assert live["type"] == "live" and len(live["slaves"]) == len(master.slaves)
    assert hub.rescanned is False

    # A browser that reads nothing loses live snapshots, never the segment.
    slow = Client()
    slow.offer(first)
    for _ in range(5):
        slow.offer(second)
    waiting = [slow.queue.get_nowait() for _ in range(slow.queue.qsize())]
    assert waiting == [first, second] and slow.dropped == 4


def test_a_cut_cable_carries_the_push_that_first_showed_it() -> None:
    """The mark of a broken cable names the first snapshot that showed it (its time and
    push number) for as long as it stays broken, and goes with the cut."""
    from pyethercat.master.telemetry import Telemetry
    from pyethercat.sim.topology import load_topology
    from pyethercat.web.model import LiveModel

    seg = load_topology(DEMO).build()
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())
    m.scan()
    t = Telemetry(m, max_rate=0, register_rate=0)  # a fresh snapshot and reading each time
    model = LiveModel(m.slaves, None)

    def di8_to_do8(push: int) -> dict[str, object]:
        live = model.live(t.snapshot(), push)
        assert live["push"] == push
        (link,) = [x for x in live["links"] if x["to"] == 3]  # the di8's port 1 -> the do8
        return link

    assert di8_to_do8(1)["broken"] is False and di8_to_do8(2)["since_push"] is None
    seg.break_link(1, 1)  # file index 1: the di8
    first = di8_to_do8(3)
    later = di8_to_do8(4)
    assert first["broken"] and later["broken"]
    assert first["since_push"] == later["since_push"] == 3
    assert first["since"] == later["since"] is not None
    seg.restore_link(1, 1)
    assert di8_to_do8(5)["since"] is None
