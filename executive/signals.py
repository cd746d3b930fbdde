"""Signals that end a run safely (SIGINT, SIGTERM, SIGHUP), for every command that moves
a robot, simulated or real: the handler only records the request; the runtime polls it
once per tick, sends the robot a stop and ends the run ``interrupted``."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from executive.runtime import StopRequest

SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
"""Signals that end a run safely; exit status 128 + the signal."""


@contextmanager
def stop_on_signals(stop: StopRequest) -> Iterator[None]:
    """For the body, SIGINT, SIGTERM and SIGHUP set ``stop`` (a second one exits at once:
    the first one's safe ending is not coming; the runtime still sends its stop on the
    way out). A signal that is ignored (nohup) stays ignored."""

    def on_signal(signum: int) -> None:
        if stop:
            raise SystemExit(128 + signum)
        stop.set(f"interrupted by {signal.Signals(signum).name}", signum)

    with routed_signals(on_signal):
        yield


@contextmanager
def routed_signals(on_signal: Callable[[int], None]) -> Iterator[None]:
    """Route SIGINT, SIGTERM and SIGHUP to ``on_signal`` for the body, then restore the
    previous handlers (an ignored signal stays ignored)."""
    previous = {}

    def handler(signum: int, _frame: object) -> None:
        on_signal(signum)

    for name in SIGNALS:
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
