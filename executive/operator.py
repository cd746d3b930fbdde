"""The operator endpoint of a running executive, and its command-line client.

One local endpoint per run (ARCHITECTURE §8): HTTP with JSON bodies, on the loopback
unless the robot file says otherwise. Every request needs the run's secret, generated
per run (``secrets.token_urlsafe``) and written next to the report with owner-only
permissions (``operator.secret``, mode 0600), with the endpoint's address in
``operator.json``; a request without it, or with another, is refused (401) and counted.
``walkaround operator COMMAND --run DIR`` and the web HUD are its clients.

Commands: ``pause`` (the robot holds still, the mission keeps its place), ``resume``,
``take-over`` (the operator has the robot; the mission pauses), ``hand-back``,
``reset-estop`` (release a latched e-stop or bumper once the zone is clear; a one-shot
request), ``abort`` (a safe stop for good; the run ends ``aborted`` with its report).
``GET /status`` answers what the run is doing.
"""

from __future__ import annotations

import hmac
import json
import os
import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from executive.core.records import OperatorRequests

COMMANDS = ("pause", "resume", "take-over", "hand-back", "reset-estop", "abort")
MAX_BODY = 4096
"""Bytes of a request body: a command is a few tens; anything longer is refused."""
ENDPOINT_FILE = "operator.json"
SECRET_FILE = "operator.secret"


@dataclass
class OperatorState:
    """What the operator has asked for, shared between the endpoint's threads and the
    runtime's loop (``__call__`` is the runtime's ``operator`` hook)."""

    paused: bool = False
    taken_over: bool = False
    aborted: bool = False
    _reset_pending: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    log: list[tuple[str, bool]] = field(default_factory=list)
    """Every command received, with whether it was accepted."""
    listeners: list[Callable[[str], None]] = field(default_factory=list)
    """Called with each accepted command (the robot link's reset of the base's latch)."""

    def apply(self, command: str) -> str:
        """Apply ``command``; the answer for the operator. Raises ValueError if unknown."""
        if command not in COMMANDS:
            raise ValueError(f"unknown command '{command}' (one of {', '.join(COMMANDS)})")
        with self._lock:
            if self.aborted and command != "abort":
                self.log.append((command, False))
                return "the mission was aborted: nothing more to do"
            if command == "pause":
                self.paused = True
            elif command == "resume":
                self.paused = False
            elif command == "take-over":
                self.taken_over = True
            elif command == "hand-back":
                self.taken_over = False
            elif command == "reset-estop":
                self._reset_pending = True
            else:
                self.aborted = True
            self.log.append((command, True))
        for listener in self.listeners:
            listener(command)
        return f"{command}: accepted"

    def __call__(self, now: float) -> OperatorRequests:
        with self._lock:
            reset, self._reset_pending = self._reset_pending, False
            return OperatorRequests(
                reset_estop=reset,
                take_over=self.paused or self.taken_over,
                abort=self.aborted,
            )


class OperatorEndpoint:
    """The HTTP endpoint of one run: serves ``state`` with ``status()`` for GET /status.

    ``folder`` receives ``operator.json`` (host, port, pid) and ``operator.secret``.
    """

    def __init__(
        self,
        state: OperatorState,
        folder: Path,
        status: Callable[[], dict[str, object]],
        host: str = "127.0.0.1",
        port: int = 0,
    ) -> None:
        self.state = state
        self.status = status
        self.secret = secrets.token_urlsafe(32)
        self.refused = 0
        self._server = ThreadingHTTPServer((host, port), _handler_for(self))
        self._server.daemon_threads = True
        self.host, self.port = self._server.server_address[:2]
        folder.mkdir(parents=True, exist_ok=True)
        self._files = (folder / SECRET_FILE, folder / ENDPOINT_FILE)
        _write_private(self._files[0], self.secret + "\n")
        _write_private(
            self._files[1],
            json.dumps({"host": self.host, "port": self.port, "pid": os.getpid()}) + "\n",
        )
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="operator endpoint", daemon=True
        )
        self._thread.start()

    def authorised(self, header: str | None) -> bool:
        token = (header or "").removeprefix("Bearer ").strip()
        ok = hmac.compare_digest(token.encode(), self.secret.encode())
        if not ok:
            self.refused += 1
        return ok

    def close(self) -> None:
        """Stop serving and remove the secret and address: the run is over."""
        self._server.shutdown()
        self._server.server_close()
        for path in self._files:
            path.unlink(missing_ok=True)


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to a new file readable by its owner only (never through a link)."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def _handler_for(endpoint: OperatorEndpoint) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "walkaround-operator/1"

        def log_message(self, format: str, *args: object) -> None:
            """Quiet: the run's own log says what the operator did."""

        def _answer(self, status: HTTPStatus, body: dict[str, object]) -> None:
            data = json.dumps(body).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _allowed(self) -> bool:
            if endpoint.authorised(self.headers.get("Authorization")):
                return True
            self._answer(HTTPStatus.UNAUTHORIZED, {"error": "this run's secret is required"})
            return False

        def do_GET(self) -> None:
            if not self._allowed():
                return
            if self.path != "/status":
                self._answer(HTTPStatus.NOT_FOUND, {"error": f"no {self.path}"})
                return
            self._answer(HTTPStatus.OK, endpoint.status())

        def do_POST(self) -> None:
            if not self._allowed():
                return
            if self.path != "/command":
                self._answer(HTTPStatus.NOT_FOUND, {"error": f"no {self.path}"})
                return
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                length = -1
            if not 0 < length <= MAX_BODY:
                self._answer(HTTPStatus.BAD_REQUEST, {"error": "a JSON body of at most 4 KiB"})
                return
            try:
                body = json.loads(self.rfile.read(length))
                answer = endpoint.state.apply(str(body["command"]))
            except (ValueError, KeyError, TypeError) as exc:
                self._answer(HTTPStatus.BAD_REQUEST, {"error": str(exc)})
                return
            self._answer(HTTPStatus.OK, {"ok": True, "answer": answer})

    return Handler


# -- the client ----------------------------------------------------------------------------------
class OperatorError(Exception):
    """The command could not be delivered or was refused; the message says why."""


def send_command(run_folder: Path, command: str, timeout: float = 2.0) -> str:
    """Send ``command`` to the run whose report folder is ``run_folder``."""
    import http.client

    try:
        address = json.loads((run_folder / ENDPOINT_FILE).read_text())
        secret = (run_folder / SECRET_FILE).read_text().strip()
    except (OSError, ValueError) as exc:
        raise OperatorError(f"no running executive in {run_folder} ({exc})") from exc
    conn = http.client.HTTPConnection(address["host"], int(address["port"]), timeout=timeout)
    try:
        if command == "status":
            conn.request("GET", "/status", headers={"Authorization": f"Bearer {secret}"})
        else:
            conn.request(
                "POST",
                "/command",
                body=json.dumps({"command": command}),
                headers={"Authorization": f"Bearer {secret}", "Content-Type": "application/json"},
            )
        response = conn.getresponse()
        body = json.loads(response.read() or b"{}")
    except (OSError, ValueError) as exc:
        raise OperatorError(f"the executive at {address['host']}:{address['port']}: {exc}") from exc
    finally:
        conn.close()
    if response.status != HTTPStatus.OK:
        raise OperatorError(f"refused ({response.status}): {body.get('error', '')}")
    if command == "status":
        return json.dumps(body)
    return str(body.get("answer", ""))
