"""A dry-run served live to the HUD: ``walkaround dry-run --live`` (issue 15).

The simulation runs on a thread at ``pace`` times real time (1: the operator's tablet
sees and drives it as it would the robot; the joystick's dead-man is in wall time), the
HUD server on another; the operator's commands reach the runtime through
:class:`executive.operator.OperatorState`, exactly as on the robot.
"""

from __future__ import annotations

import threading
from pathlib import Path
from types import TracebackType

from executive.dryrun import DryRun, dry_run
from executive.hud.server import HudServer
from executive.hud.telemetry import Telemetry
from executive.operator import OperatorState
from executive.runtime import StopRequest
from sim2d.robot import SimRobot
from sim2d.scenario import Scenario


class LiveDryRun:
    """One live dry-run: ``with LiveDryRun(scenario, out) as live: ...`` starts it; the
    exit stops the simulation (if still running) and the server."""

    def __init__(
        self,
        scenario: Scenario,
        out: Path,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        pace: float = 1.0,
        max_time: float | None = None,
        servo: bool | None = None,
        rate_hz: float = 50.0,
        trapped_after: float | None = None,
    ) -> None:
        self.scenario = scenario
        self.state = OperatorState()
        self.sim = SimRobot(scenario)
        self.telemetry = Telemetry.of_operator(scenario.mission, self.state, rate_hz)
        self.server = HudServer(
            self.state,
            out,
            status=lambda: {"t": round(self.sim.time, 2), "simulated": True},
            host=host,
            port=port,
            telemetry=self.telemetry,
        )
        self.pace = pace
        self.max_time = max_time
        self.servo = servo
        self.rate_hz = rate_hz
        self.trapped_after = trapped_after
        self.journal = out / "journal.jsonl"
        self.run: DryRun | None = None
        self.error: BaseException | None = None
        self.stop = StopRequest()
        """Set (e.g. by a signal handler) to end the run at the next tick, safely."""
        self._thread = threading.Thread(target=self._main, name="live dry-run", daemon=True)

    def _main(self) -> None:
        try:
            self.run = dry_run(
                self.scenario,
                rate_hz=self.rate_hz,
                operator=self.state,
                robot=self.sim,
                max_time=self.max_time,
                servo=self.servo,
                ask_operator=True,
                journal_path=self.journal,
                trapped_after=self.trapped_after,
                observers=(self.telemetry.on_tick,),
                pace=self.pace,
                stop=self.stop,
            )
        except BaseException as exc:  # reported by join(); the thread must not die silently
            self.error = exc

    def start(self) -> LiveDryRun:
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> DryRun | None:
        """Wait for the run to end; re-raise what ended it abnormally."""
        self._thread.join(timeout)
        if self.error is not None:
            raise self.error
        return self.run

    def close(self) -> None:
        self.stop.set("the live dry-run was closed")
        self._thread.join(timeout=10.0)
        self.server.close()

    def __enter__(self) -> LiveDryRun:
        return self.start()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
