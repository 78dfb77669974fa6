"""The dashboard's ASGI application (Starlette): pages, JSON API, the live WebSocket.

One HTML page (``static/index.html``) with its script and style files; the
pages (Topology, Slaves, Process data, Cycle, DC, Drives, Mailbox) are views
of it chosen by the address's fragment. Live data comes over ``/ws``: the
segment and the history when a browser connects, then one message per poll
of the :class:`~pyethercat.web.hub.Hub`. Everything else is a small JSON API
over the master's control requests. The access rules
(:mod:`pyethercat.web.security`) are applied to every request and every
WebSocket by :class:`_Guard`, before any route runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Awaitable, Callable, MutableMapping
from importlib import resources
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection, Request
from starlette.responses import FileResponse, JSONResponse, RedirectResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.master.control import messages as msg
from pyethercat.master.control.protocol import RemoteError
from pyethercat.master.control.telemetry_ops import FoeFiles, PdoWrite
from pyethercat.web.hub import Client, Hub
from pyethercat.web.security import COOKIE, Access, content_security_policy
from pyethercat.wire.mailbox.datatypes import (
    DataType,
    decode_value,
    encode_value,
    format_value,
    parse_type_name,
    parse_value,
)

__all__ = ["create_app", "STATIC"]

STATIC = Path(str(resources.files("pyethercat.web").joinpath("static")))
Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


def _given_token(conn: HTTPConnection) -> str | None:
    auth = conn.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return conn.cookies.get(COOKIE)


class _Guard:
    """Host check, token check and security headers, for HTTP and WebSocket alike."""

    def __init__(self, app: ASGIApp, access: Access) -> None:
        self.app = app
        self.access = access

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        conn = HTTPConnection(scope)
        access = self.access
        refusal: tuple[int, str] | None = None
        if not access.host_ok(conn.headers.get("host")):
            refusal = (403, "unexpected Host header")
        elif (scope["type"] == "http" and scope["path"] == "/"
              and "token" in conn.query_params and access.token):
            # The printed address: trade the token in the URL for a cookie, then drop it.
            if access.token_ok(conn.query_params["token"]):
                resp = RedirectResponse("/", status_code=303)
                resp.set_cookie(COOKIE, conn.query_params["token"], httponly=True,
                                samesite="strict", path="/")
                await self._send_http(resp, scope, receive, send)
                return
            refusal = (403, "wrong token")
        elif not access.token_ok(_given_token(conn)):
            refusal = (403, "this dashboard needs its token: open the address the command "
                            "printed (…/?token=…) or send 'Authorization: Bearer TOKEN'")
        if refusal is not None:
            if scope["type"] == "websocket":
                await send({"type": "websocket.close", "code": 1008, "reason": refusal[1]})
                return
            await self._send_http(JSONResponse({"error": refusal[1]}, status_code=refusal[0]),
                                  scope, receive, send)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        host = conn.headers.get("host", f"{access.host}:{access.port}")
        csp = content_security_policy(f"ws://{host}")

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [(b"content-security-policy", csp.encode()),
                            (b"x-content-type-options", b"nosniff"),
                            (b"x-frame-options", b"DENY"),
                            (b"referrer-policy", b"no-referrer"),
                            (b"cache-control", b"no-store")]
                message["headers"] = headers
            await send(message)

        await self.app(scope, receive, with_headers)

    async def _send_http(self, resp: Response, scope: Scope, receive: Receive,
                         send: Send) -> None:
        resp.headers["content-security-policy"] = content_security_policy("")
        resp.headers["cache-control"] = "no-store"
        await resp(scope, receive, send)


def _error(exc: BaseException, status: int = 400) -> JSONResponse:
    return JSONResponse({"error": " ".join(str(exc).split())}, status_code=status)


def _int(value: Any, what: str) -> int:
    try:
        return int(str(value), 0)
    except (TypeError, ValueError):
        raise ConfigError(f"{what}: {value!r} is not a number") from None


def create_app(hub: Hub, access: Access) -> ASGIApp:
    """The dashboard application for ``hub``'s master under the rules of ``access``."""
    conn = hub.conn

    async def call(req: Any) -> Any:
        return await run_in_threadpool(conn.call, req)

    async def page(request: Request) -> Response:
        return FileResponse(STATIC / "index.html", media_type="text/html")

    async def segment(request: Request) -> Response:
        try:
            seg = await run_in_threadpool(hub.load_segment)
        except EtherCATError as exc:
            return _error(exc, 502)
        return JSONResponse(seg)

    async def live(request: Request) -> Response:
        try:
            data = await run_in_threadpool(hub.poll_once) if not hub.clients else hub.last
        except EtherCATError as exc:
            return _error(exc, 502)
        return JSONResponse(data)

    def write_refused(request: Request) -> Response | None:
        why = access.write_refusal(_given_token(request))
        if why is not None:
            return JSONResponse({"error": why}, status_code=403)
        origin = request.headers.get("origin")
        host = request.headers.get("host", "")
        if origin is not None and origin != f"http://{host}":
            return JSONResponse({"error": "write from another origin refused"}, status_code=403)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"error": "writes are JSON requests"}, status_code=415)
        return None

    async def write_request(request: Request) -> tuple[dict[str, Any], int] | Response:
        """A write's JSON object and the slave position it names, or the refusal."""
        refused = write_refused(request)
        if refused is not None:
            return refused
        try:
            body = await request.json()
            if not isinstance(body, dict):
                raise ConfigError("the request is not a JSON object")
            return body, _int(body.get("position"), "position")
        except json.JSONDecodeError:
            return _error(ConfigError("the request is not JSON"))
        except (EtherCATError, ValueError) as exc:
            return _error(exc)

    async def sdo_list(request: Request) -> Response:
        try:
            pos = _int(request.query_params.get("position"), "position")
            reply: msg.SdoObjects = await call(msg.SdoList(pos, entries=True))
        except EtherCATError as exc:
            return _error(exc)
        return JSONResponse({"objects": [
            {"index": o.index, "name": o.name, "error": o.error,
             "entries": [{"subindex": e.subindex, "access": e.access_text,
                          "type": _type_name(e.data_type), "bits": e.bit_length,
                          "name": e.name} for e in o.entries]} for o in reply.objects]})

    async def sdo_read(request: Request) -> Response:
        q = request.query_params
        try:
            pos = _int(q.get("position"), "position")
            index = _int(q.get("index"), "index")
            sub = _int(q.get("subindex", "0"), "subindex")
            data: msg.Data = await call(msg.SdoUpload(pos, index, sub))
            typed: msg.EntryType = await call(msg.SdoEntryType(pos, index, sub))
        except EtherCATError as exc:
            return _error(exc)
        text = data.data.hex(" ")
        type_name = None
        if typed.data_type is not None:
            try:
                dtype = DataType(typed.data_type)
                text = format_value(dtype, decode_value(dtype, data.data))
                type_name = dtype.name
            except (ValueError, EtherCATError):
                pass
        return JSONResponse({"hex": data.data.hex(" "), "value": text, "type": type_name,
                             "size": len(data.data)})

    async def sdo_write(request: Request) -> Response:
        got = await write_request(request)
        if isinstance(got, Response):
            return got
        body, pos = got
        try:
            index = _int(body.get("index"), "index")
            sub = _int(body.get("subindex", 0), "subindex")
            text = str(body.get("value", ""))
            if body.get("type"):
                dtype = parse_type_name(str(body["type"]))
            else:
                typed: msg.EntryType = await call(msg.SdoEntryType(pos, index, sub))
                if typed.data_type is None:
                    raise ConfigError("the slave does not describe this entry: give its type")
                dtype = DataType(typed.data_type)
            raw = encode_value(dtype, parse_value(dtype, text))
            await call(msg.SdoDownload(pos, index, sub, raw))
        except (EtherCATError, ValueError) as exc:
            return _error(exc)
        return JSONResponse({"written": raw.hex(" "), "type": dtype.name})

    async def pdo_write(request: Request) -> Response:
        got = await write_request(request)
        if isinstance(got, Response):
            return got
        body, pos = got
        try:
            value = body.get("value")
            if isinstance(value, str):
                value = _int(value, "value") if value.strip() not in ("true", "false") \
                    else value.strip() == "true"
            if not isinstance(value, bool | int | float):
                raise ConfigError(f"value {value!r} is not a number")
            await call(PdoWrite(pos, str(body.get("name", "")), value))
        except (EtherCATError, ValueError) as exc:
            return _error(exc)
        return JSONResponse({"ok": True})

    async def foe_files(request: Request) -> Response:
        q = request.query_params
        try:
            pos = _int(q["position"], "position") if "position" in q else None
            reply = await call(FoeFiles(pos))
        except EtherCATError as exc:
            return _error(exc)
        return JSONResponse({"files": [{"position": f.position, "name": f.name, "size": f.size,
                                        "direction": f.direction, "time": f.time}
                                       for f in reply.files]})

    async def foe_read(request: Request) -> Response:
        try:
            body = await request.json()
            pos = _int(body.get("position"), "position")
            name = str(body.get("name", ""))
            if not name:
                raise ConfigError("give the name of the file to read")
            password = _int(body.get("password", 0) or 0, "password")
            data: msg.Data = await call(msg.FoeRead(pos, name, password, max_size=16 << 20))
        except json.JSONDecodeError:
            return _error(ConfigError("the request is not JSON"))
        except EtherCATError as exc:
            return _error(exc)
        return Response(data.data, media_type="application/octet-stream",
                        headers={"content-disposition": f'attachment; filename="{_safe(name)}"'})

    async def ws(websocket: WebSocket) -> None:
        await websocket.accept()
        client = Client()
        try:
            seg = hub.segment if hub.segment is not None else \
                await run_in_threadpool(hub.load_segment)
            await websocket.send_text(json.dumps({"type": "segment", **seg}))
            await websocket.send_text(json.dumps(hub.history()))
        except (EtherCATError, RemoteError) as exc:
            await websocket.send_text(json.dumps({"type": "error", "text": str(exc)}))
        hub.clients.add(client)

        async def drain() -> None:
            # Nothing is expected from the page; this notices it closing.
            with contextlib.suppress(WebSocketDisconnect):
                while True:
                    await websocket.receive_text()

        reader = asyncio.create_task(drain())
        try:
            while not reader.done():
                get = asyncio.create_task(client.queue.get())
                done, _ = await asyncio.wait({get, reader}, return_when=asyncio.FIRST_COMPLETED)
                if get in done:
                    await websocket.send_text(get.result())
                else:
                    get.cancel()
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass
        finally:
            hub.clients.discard(client)
            reader.cancel()

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        task = asyncio.create_task(hub.run())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    routes = [
        Route("/", page),
        Route("/api/segment", segment),
        Route("/api/live", live),
        Route("/api/sdo/list", sdo_list),
        Route("/api/sdo/read", sdo_read),
        Route("/api/sdo/write", sdo_write, methods=["POST"]),
        Route("/api/pdo/write", pdo_write, methods=["POST"]),
        Route("/api/foe/files", foe_files),
        Route("/api/foe/read", foe_read, methods=["POST"]),
        WebSocketRoute("/ws", ws),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    return _Guard(app, access)


def _type_name(code: int) -> str:
    try:
        return DataType(code).name
    except ValueError:
        return f"0x{code:04X}"


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in name) or "file"
