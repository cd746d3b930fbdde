"""The emergency-stop latch (thesis seed lines 1536-1542, and §2.2.1 for the bumpers).

One implementation, used by the tree's e-stop guard and by the safety layer.

* Latched when an obstacle is closer to the footprint than r_ES (an unknown-as-NaN
  distance counts as close) or a bumper is pressed.
* An obstacle latch releases by itself once the zone has stayed clear for ``hold``
  seconds, or at once on an operator reset while the zone is clear. While the distance is
  unknown (no obstacle estimate) it holds.
* A bumper latch needs an operator reset, and only once the bumper is released (the 4MOB
  platform "will stop all electric motors and engage its brakes until the emergency stop
  state is canceled manually by the operator"); if an obstacle is still inside r_ES at
  that moment it becomes an obstacle latch.

Each :meth:`EStopLatch.update` leaves the transitions it made in :attr:`events`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

LATCHED = "latched"
RELEASED = "released"  # by itself, after the hold
RESET = "reset"  # by the operator
RESET_REFUSED = "reset-refused"  # a bumper is still pressed
OPERATOR = "operator"
"""The name of the operator's e-stop among the "bumpers" of :meth:`EStopLatch.update`."""


@dataclass(frozen=True, slots=True)
class LatchEvent:
    kind: str
    reason: str
    value: float | None = None


@dataclass
class EStopLatch:
    r_es: float
    hold: float
    latched: bool = False
    cause: str | None = None  # "obstacle" or "bumper"
    reason: str = ""
    events: list[LatchEvent] = field(default_factory=list)
    _clear_since: float | None = None
    _reset_before: bool = False

    def update(
        self,
        now: float,
        r_c: float | None,
        bumper: bool | tuple[str, ...],
        reset: bool = False,
    ) -> bool:
        """Advance the latch; True while latched. ``r_c`` None: no obstacle estimate.

        ``bumper`` is a flag or the names of the pressed bumpers (for the reason);
        :data:`OPERATOR` among them is the operator's e-stop (the HUD's button), which
        latches like a bumper: released by an operator reset only.
        """
        self.events = []
        rising = reset and not self._reset_before
        self._reset_before = reset
        pressed = bool(bumper)
        near = r_c is not None and not r_c >= self.r_es  # NaN counts as near
        if pressed or near:
            cause = "bumper" if pressed or self.cause == "bumper" else "obstacle"
            if pressed:
                names = bumper if isinstance(bumper, tuple) else ()
                sides = " and ".join(n for n in names if n != OPERATOR)
                reason = (
                    f"{sides + ' ' if sides else ''}bumper pressed" if sides or not names else ""
                )
                if OPERATOR in names:
                    reason = "operator e-stop" + (f" and {reason}" if reason else "")
                value = None
            else:
                reason, value = f"obstacle at {r_c:.2f} m < r_ES {self.r_es:.2f} m", r_c
            if not self.latched or cause != self.cause:
                self.events.append(LatchEvent(LATCHED, reason, value))
                self.reason = reason
            elif cause == "obstacle":
                self.reason = reason
            self.latched, self.cause = True, cause
            self._clear_since = None
        if not self.latched:
            return False
        if self.cause == "bumper":
            if reset and not pressed:
                if near:
                    self.cause, self._clear_since = "obstacle", None
                    self.events.append(
                        LatchEvent(
                            RESET,
                            "operator reset of the bumper latch; an obstacle is still inside "
                            f"r_ES ({r_c:.2f} m): held until it is clear",
                            r_c,
                        )
                    )
                else:
                    self._release(RESET, "operator reset (bumper released)")
            elif rising and pressed:
                self.events.append(LatchEvent(RESET_REFUSED, "reset refused: a bumper is pressed"))
            return self.latched
        if near or r_c is None:
            self._clear_since = None
            return True
        if reset:
            self._release(RESET, "operator reset (zone clear)", r_c)
            return False
        if self._clear_since is None:
            self._clear_since = now
        if now - self._clear_since >= self.hold or math.isclose(self.hold, 0.0):
            self._release(RELEASED, f"zone clear for {self.hold:g} s (r_c {r_c:.2f} m)", r_c)
        return self.latched

    def _release(self, kind: str, reason: str, value: float | None = None) -> None:
        self.latched, self.cause, self.reason, self._clear_since = False, None, "", None
        self.events.append(LatchEvent(kind, reason, value))
