"""The emergency-stop latch (thesis seed lines 1536-1542, and §2.2.1 for the bumpers).

Latched when an obstacle is closer to the footprint than r_ES or a bumper is pressed.
An obstacle latch releases by itself once the zone has stayed clear for ``hold`` seconds;
a bumper latch needs an operator reset, and only once the bumper is released (the 4MOB
platform "will stop all electric motors and engage its brakes until the emergency stop
state is canceled manually by the operator").
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class EStopLatch:
    r_es: float
    hold: float
    latched: bool = False
    cause: str | None = None  # "obstacle" or "bumper"
    reason: str = ""
    _clear_since: float | None = None

    def update(self, now: float, r_c: float, bumper: bool, reset: bool = False) -> bool:
        """Advance the latch; True while latched."""
        too_close = r_c < self.r_es
        if bumper:
            self.latched, self.cause = True, "bumper"
            self.reason = "bumper pressed"
            self._clear_since = None
            return True
        if too_close:
            if not self.latched:
                self.latched, self.cause = True, "obstacle"
            if self.cause == "obstacle":
                self.reason = f"obstacle at {r_c:.2f} m < r_ES {self.r_es:.2f} m"
            self._clear_since = None
            return True
        if not self.latched:
            return False
        if self.cause == "bumper":
            if reset:
                self._release()
            return self.latched
        if self._clear_since is None:
            self._clear_since = now
        if now - self._clear_since >= self.hold or math.isclose(self.hold, 0.0):
            self._release()
        return self.latched

    def _release(self) -> None:
        self.latched, self.cause, self.reason, self._clear_since = False, None, "", None
