"""The operator's side of a running executive: what they ask for, and the command-line
client of the run's endpoint.

One endpoint per run (ARCHITECTURE §8), served by the web HUD (:mod:`executive.hud`):
HTTP with JSON bodies and a WebSocket, on the loopback unless the robot file says
otherwise. Every request needs the run's secret, generated per run
(``secrets.token_urlsafe``) and written next to the report with owner-only permissions
(``operator.secret``, mode 0600), with the endpoint's address in ``operator.json``; a
request without it, or with another, is refused (401), counted and logged.
``walkaround operator COMMAND --run DIR`` and the HUD are its clients.

Commands: ``pause`` (the robot holds still, the mission keeps its place), ``resume``,
``take-over`` (the operator has the robot: the joystick drives it, or it follows the
person they designate; the mission pauses), ``hand-back``, ``estop`` (the operator's
e-stop: latched until ``reset-estop``), ``reset-estop`` (release a latched e-stop or
bumper once the zone is clear; a one-shot request), ``abort`` (the mission ends: the robot
drives back to the handover point P on its own, a take-over or pause still pre-empts
it, and the run ends ``aborted`` with its report; the e-stop is the way to stop it where
it is); with parameters: ``joystick`` (``v``, ``omega``:
a dead-man stream, stale after :data:`DEADMAN_S`), ``follow`` (``x``, ``y`` in A and
optional ``distance``: follow the person there), ``answer`` (``choice``: the answer to
the question the run asked, e.g. when trapped). ``GET /status`` answers what the run is
doing.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path

from executive.core.records import FollowRequest, JoystickCommand, OperatorRequests

COMMANDS = (
    "pause",
    "resume",
    "take-over",
    "hand-back",
    "estop",
    "reset-estop",
    "abort",
    "joystick",
    "follow",
    "answer",
)
MAX_BODY = 4096
"""Bytes of a request body: a command is a few tens; anything longer is refused."""
ENDPOINT_FILE = "operator.json"
SECRET_FILE = "operator.secret"
DEADMAN_S = 0.3
"""A joystick command older than this (wall clock) no longer drives: the tablet's stream
must keep coming (the HUD sends 10 per second while the stick is held)."""
JOYSTICK_LIMITS = (1.0, 1.0)
"""The joystick's speed (m/s) and turn rate (rad/s) accepted at most; the tree and the
safety layer limit them further to the mission's and the platform's."""


@dataclass(frozen=True)
class Question:
    """A question the run asks the operator (the thesis's "operator asked for help")."""

    id: int
    text: str
    choices: tuple[str, ...]
    asked_at: float


@dataclass
class OperatorState:
    """What the operator has asked for, shared between the endpoint's threads and the
    runtime's loop (``__call__`` is the runtime's ``operator`` hook)."""

    paused: bool = False
    taken_over: bool = False
    aborted: bool = False
    _reset_pending: bool = False
    _estop_pending: bool = False
    _answer: str | None = None
    _joystick: tuple[float, float, float] | None = None  # (wall time, v, omega)
    _follow: tuple[float, float, float] | None = None  # (x, y, distance) in A
    _follow_new: bool = False
    question: Question | None = None
    _questions: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    log: list[tuple[str, bool]] = field(default_factory=list)
    """Every command received, with whether it was accepted."""
    listeners: list[Callable[[str], None]] = field(default_factory=list)
    """Called with each accepted command (the robot link's reset of the base's latch)."""
    wall: Callable[[], float] = time.monotonic

    def apply(self, command: str, params: Mapping[str, object] | None = None) -> str:
        """Apply ``command`` with its ``params``; the answer for the operator. Raises
        ValueError if unknown or its parameters are not valid."""
        if command not in COMMANDS:
            raise ValueError(f"unknown command '{command}' (one of {', '.join(COMMANDS)})")
        params = params or {}
        parsed = _parse(command, params)
        with self._lock:
            if command == "pause":
                self.paused = True
            elif command == "resume":
                self.paused = False
            elif command == "take-over":
                self.taken_over = True
            elif command == "hand-back":
                self.taken_over = False
                self._joystick = None
                self._follow = None
            elif command == "estop":
                self._estop_pending = True
            elif command == "reset-estop":
                self._reset_pending = True
            elif command == "joystick":
                v, omega = parsed
                self._joystick = (self.wall(), v, omega)
            elif command == "follow":
                self._follow = parsed
                self._follow_new = True
                self.taken_over = True
            elif command == "answer":
                (choice,) = parsed
                question = self.question
                if question is None:
                    self.log.append((command, False))
                    return "no question is pending"
                if choice not in question.choices:
                    self.log.append((command, False))
                    return f"'{choice}' is not one of {', '.join(question.choices)}"
                self._answer = choice
                self.question = None
                if choice == "take-over":
                    self.taken_over = True
            else:  # abort: the robot returns to the handover point on its own
                self.aborted = True
                self.paused = self.taken_over = False
                self._joystick = self._follow = None
            if command != "joystick":  # a stream of 10 a second: not a log line each
                self.log.append((command, True))
        for listener in self.listeners:
            listener(command)
        return f"{command}: accepted"

    def ask(self, text: str, choices: tuple[str, ...]) -> Question:
        """Post a question for the operator (replaces an unanswered one)."""
        with self._lock:
            self._questions += 1
            self.question = Question(self._questions, text, choices, self.wall())
            self._answer = None
            return self.question

    def withdraw(self) -> None:
        """The question is no longer asked (the run went on without an answer)."""
        with self._lock:
            self.question = None

    def snapshot(self) -> dict[str, object]:
        """The operator side of the run, for the HUD."""
        with self._lock:
            q = self.question
            return {
                "paused": self.paused,
                "taken_over": self.taken_over,
                "aborted": self.aborted,
                "following": self._follow is not None,
                "joystick": self._joystick is not None
                and self.wall() - self._joystick[0] <= DEADMAN_S,
                "question": None
                if q is None
                else {"id": q.id, "text": q.text, "choices": list(q.choices)},
            }

    def __call__(self, now: float) -> OperatorRequests:
        with self._lock:
            reset, self._reset_pending = self._reset_pending, False
            estop, self._estop_pending = self._estop_pending, False
            answer, self._answer = self._answer, None
            joystick = None
            if self._joystick is not None and self.wall() - self._joystick[0] <= DEADMAN_S:
                joystick = JoystickCommand(now, self._joystick[1], self._joystick[2])
            follow = None
            if self._follow is not None:
                x, y, distance = self._follow
                follow = FollowRequest(now, x, y, distance)
            return OperatorRequests(
                reset_estop=reset,
                take_over=self.paused or self.taken_over,
                abort=self.aborted,
                estop=estop,
                joystick=joystick,
                follow=follow,
                answer=answer,
            )


def _number(params: Mapping[str, object], key: str, low: float, high: float) -> float:
    value = params.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"'{key}' must be a number")
    value = float(value)
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"'{key}' must be within [{low:g}, {high:g}], got {value:g}")
    return value


def _parse(command: str, params: Mapping[str, object]) -> tuple:
    """The parameters of ``command``, checked (ValueError says what is wrong)."""
    if command == "joystick":
        v_max, w_max = JOYSTICK_LIMITS
        return (_number(params, "v", -v_max, v_max), _number(params, "omega", -w_max, w_max))
    if command == "follow":
        distance = params.get("distance", 1.5)
        return (
            _number(params, "x", -1e4, 1e4),
            _number(params, "y", -1e4, 1e4),
            _number({"distance": distance}, "distance", 0.5, 10.0),
        )
    if command == "answer":
        choice = params.get("choice")
        if not isinstance(choice, str) or not choice:
            raise ValueError("'choice' must be a non-empty string")
        return (choice,)
    return ()


def write_private(path: Path, text: str) -> None:
    """Write ``text`` to a new file readable by its owner only (never through a link)."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


# -- the client ----------------------------------------------------------------------------------
class OperatorError(Exception):
    """The command could not be delivered or was refused; the message says why."""


def send_command(
    run_folder: Path,
    command: str,
    timeout: float = 2.0,
    params: Mapping[str, object] | None = None,
) -> str:
    """Send ``command`` (with its ``params``) to the run whose report folder is
    ``run_folder``."""
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
                body=json.dumps({**(params or {}), "command": command}),
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
