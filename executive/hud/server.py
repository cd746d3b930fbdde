"""The run's web endpoint: the operator's HUD, its WebSocket, and the command API
(issue 15; ARCHITECTURE §8).

A Starlette application served by uvicorn on a thread of its own, beside the runtime's
loop. Routes:

* ``GET /`` — the HUD (``static/index.html``): top view, progress, controller, alerts,
  inspection results, operator buttons and a virtual joystick; ``GET /static/...`` its
  script and style.
* ``WebSocket /ws`` — the live feed: the scene once (and again when the aircraft's
  placement estimate moves), then a snapshot at the telemetry's rate (12.5 Hz); the
  client sends ``{"type": "claim"}`` / ``{"type": "release"}`` for control and
  ``{"type": "command", "command": ..., ...params}``. One client has control at a time
  (the first to claim it; it is freed when that client leaves): the others view only and
  their commands are refused.
* ``GET /status``, ``POST /command`` — the JSON API of ``walkaround operator``.

Access: every request needs the run's secret, as ``Authorization: Bearer <secret>``, as
``?token=<secret>`` (the URL the terminal prints, also as a QR code), or as the
``walkaround_token`` cookie the HUD page sets (HttpOnly, SameSite=Strict). Anything else
is refused (401), counted in :attr:`HudServer.refused` and logged. The server listens on
the loopback unless told otherwise.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import itertools
import json
import logging
import os
import secrets
import socket
import threading
import time
from collections.abc import Callable, Mapping
from importlib import resources
from pathlib import Path

import uvicorn
from starlette.applications import Starlette
from starlette.requests import HTTPConnection, Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from executive.hud.telemetry import Telemetry
from executive.operator import (
    ENDPOINT_FILE,
    MAX_BODY,
    SECRET_FILE,
    OperatorState,
    write_private,
)

log = logging.getLogger("walkaround.hud")

COOKIE = "walkaround_token"
SEND_PERIOD = 0.02
"""How often (s) a connection looks for a newer snapshot to send."""
STATIC = {"hud.js": "text/javascript", "hud.css": "text/css"}


class HudServer:
    """The web endpoint of one run; ``folder`` receives ``operator.json`` (host, port,
    pid, url) and ``operator.secret`` (mode 0600)."""

    def __init__(
        self,
        state: OperatorState,
        folder: Path,
        status: Callable[[], Mapping[str, object]],
        host: str = "127.0.0.1",
        port: int = 0,
        telemetry: Telemetry | None = None,
    ) -> None:
        self.state = state
        self.status = status
        self.telemetry = telemetry
        self.secret = secrets.token_urlsafe(32)
        self.refused = 0
        self.controller: int | None = None
        """The id of the WebSocket client that has control, or None."""
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._socket = socket.socket(family, socket.SOCK_STREAM)
        self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._socket.bind((host, port))
        self.host, self.port = self._socket.getsockname()[:2]
        app = Starlette(
            routes=[
                Route("/", self._page),
                Route("/static/{name}", self._static),
                Route("/status", self._status),
                Route("/command", self._command, methods=["POST"]),
                WebSocketRoute("/ws", self._feed),
            ]
        )
        config = uvicorn.Config(
            app, log_level="warning", lifespan="off", ws="websockets-sansio", access_log=False
        )
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(
            target=self._server.run, kwargs={"sockets": [self._socket]}, name="hud", daemon=True
        )
        self._thread.start()
        deadline = time.monotonic() + 10.0
        while not self._server.started and self._thread.is_alive():
            if time.monotonic() > deadline:
                raise OSError(f"the HUD did not start on {self.host}:{self.port}")
            time.sleep(0.01)
        if not self._server.started:
            raise OSError(f"the HUD could not start on {self.host}:{self.port}")
        folder.mkdir(parents=True, exist_ok=True)
        self._files = (folder / SECRET_FILE, folder / ENDPOINT_FILE)
        write_private(self._files[0], self.secret + "\n")
        address = {"host": self.host, "port": self.port, "pid": os.getpid(), "url": self.url}
        write_private(self._files[1], json.dumps(address) + "\n")

    @property
    def url(self) -> str:
        """The HUD's address with the token: what the operator opens on the tablet."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/?token={self.secret}"

    def qr(self) -> str:
        """:attr:`url` as a QR code for a terminal (segno's compact text rendering)."""
        import io

        import segno

        out = io.StringIO()
        segno.make(self.url, error="m").terminal(out, compact=True)
        return out.getvalue()

    def close(self) -> None:
        """Stop serving and remove the secret and the address: the run is over."""
        self._server.should_exit = True
        self._thread.join(timeout=5.0)
        with contextlib.suppress(OSError):
            self._socket.close()
        for path in self._files:
            path.unlink(missing_ok=True)

    # -- access --------------------------------------------------------------------------------
    def authorised(self, conn: HTTPConnection) -> bool:
        """The run's secret is in the header, the query or the cookie (else counted)."""
        header = conn.headers.get("authorization", "")
        candidates = (
            header.removeprefix("Bearer ").strip() if header else "",
            conn.query_params.get("token", ""),
            conn.cookies.get(COOKIE, ""),
        )
        for token in candidates:
            if token and hmac.compare_digest(token.encode(), self.secret.encode()):
                return True
        with self._lock:
            self.refused += 1
        client = conn.client.host if conn.client is not None else "?"
        log.warning(
            "refused %s %s from %s: no valid secret", conn.scope["type"], conn.url.path, client
        )
        return False

    @staticmethod
    def _refusal() -> JSONResponse:
        return JSONResponse({"error": "this run's secret is required"}, status_code=401)

    # -- HTTP ----------------------------------------------------------------------------------
    async def _page(self, request: Request) -> Response:
        if not self.authorised(request):
            return HTMLResponse(
                "<h1>walkaround</h1><p>This run's secret is required: open the URL the "
                "terminal printed.</p>",
                status_code=401,
            )
        page = resources.files("executive.hud").joinpath("static/index.html").read_text()
        response = HTMLResponse(page, headers={"Cache-Control": "no-store"})
        token = request.query_params.get("token")
        if token:
            response.set_cookie(COOKIE, token, httponly=True, samesite="strict")
        return response

    async def _static(self, request: Request) -> Response:
        if not self.authorised(request):
            return self._refusal()
        name = request.path_params["name"]
        if name not in STATIC:
            return JSONResponse({"error": f"no {name}"}, status_code=404)
        text = resources.files("executive.hud").joinpath(f"static/{name}").read_text()
        return Response(text, media_type=STATIC[name])

    async def _status(self, request: Request) -> Response:
        if not self.authorised(request):
            return self._refusal()
        return JSONResponse({**self.status(), "operator": self.state.snapshot()})

    async def _command(self, request: Request) -> Response:
        if not self.authorised(request):
            return self._refusal()
        body = await request.body()
        if not 0 < len(body) <= MAX_BODY:
            return JSONResponse({"error": "a JSON body of at most 4 KiB"}, status_code=400)
        try:
            data = json.loads(body)
            answer = self.state.apply(str(data["command"]), data)
        except (ValueError, KeyError, TypeError) as exc:
            return JSONResponse({"error": str(exc)}, status_code=400)
        return JSONResponse({"ok": True, "answer": answer})

    # -- the WebSocket feed ----------------------------------------------------------------------
    async def _feed(self, ws: WebSocket) -> None:
        if not self.authorised(ws):
            await ws.close(code=4401, reason="this run's secret is required")
            return
        await ws.accept()
        me = next(self._ids)
        with self._lock:
            if self.controller is None:
                self.controller = me
        sender = asyncio.create_task(self._send_loop(ws, me))
        try:
            while True:
                message = await ws.receive_text()
                answer = self._on_message(me, message)
                if answer is not None:
                    await ws.send_text(json.dumps(answer))
        except WebSocketDisconnect:
            pass
        finally:
            sender.cancel()
            with self._lock:
                if self.controller == me:
                    self.controller = None

    def _control(self, me: int) -> dict[str, object]:
        with self._lock:
            return {"type": "control", "you": self.controller == me, "held": self.controller}

    def _on_message(self, me: int, message: str) -> dict[str, object] | None:
        """Apply one client message; the answer to send back (None: nothing)."""
        if len(message) > MAX_BODY:
            return {"type": "answer", "ok": False, "text": "message too long"}
        try:
            data = json.loads(message)
            kind = data["type"]
        except (ValueError, KeyError, TypeError):
            return {"type": "answer", "ok": False, "text": "not a JSON message with a type"}
        if kind == "claim":
            with self._lock:
                if self.controller is None:
                    self.controller = me
            return self._control(me)
        if kind == "release":
            with self._lock:
                if self.controller == me:
                    self.controller = None
            return self._control(me)
        if kind != "command":
            return {"type": "answer", "ok": False, "text": f"unknown message type {kind!r}"}
        command = str(data.get("command", ""))
        with self._lock:
            in_control = self.controller == me
        if not in_control:
            self.state.log.append((command, False))
            log.warning("refused %s from HUD client %d: view only", command, me)
            return {
                "type": "answer",
                "ok": False,
                "command": command,
                "text": "view only: another tablet has control",
            }
        try:
            text = self.state.apply(command, data)
        except ValueError as exc:
            return {"type": "answer", "ok": False, "command": command, "text": str(exc)}
        if command == "joystick":
            return None  # a stream: no answer per message
        return {"type": "answer", "ok": True, "command": command, "text": text}

    async def _send_loop(self, ws: WebSocket, me: int) -> None:
        sent_scene = sent_tick = -1
        control: dict[str, object] | None = None
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
            await ws.send_text(json.dumps({"type": "hello", "client": me}))
            while True:
                now_control = self._control(me)
                if now_control != control:
                    control = now_control
                    await ws.send_text(json.dumps(control))
                if self.telemetry is not None:
                    seq, scene = self.telemetry.scene()
                    if scene is not None and seq != sent_scene:
                        sent_scene = seq
                        await ws.send_text(json.dumps(scene))
                    seq, snapshot = self.telemetry.latest()
                    if snapshot is not None and seq != sent_tick:
                        sent_tick = seq
                        await ws.send_text(json.dumps(snapshot))
                await asyncio.sleep(SEND_PERIOD)
