"""Hardware in the loop for the tests: ``walkaround sim-robot`` and ``walkaround run`` as
real processes on this machine's loopback (TCP) and a private UDP multicast port (CAN)."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

from executive.hil import TRUTH_FILE, TruthLog, judge_hil
from executive.robotlink.canbase import DEFAULT_BASE_TIMEOUT
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS, wait_until

LAB_MISSION = MISSIONS / "lab" / "visual-servoing.xml"
LAB_CLEAR = MISSIONS / "lab" / "scenarios" / "clear-apron.xml"
REPO = Path(__file__).resolve().parent.parent
MISSED_DEADLINES = 250
"""The rig's two real-time processes share this machine's two cores with the other pytest
worker (and the executive's own worker threads: registration, planner): stretches of
ticks over 20 ms happen that a robot's dedicated computer would not see. These tests are
about the wires; the overrun policy itself is tested in tests/test_run_faults.py. Here the
bound only catches an executive that has stopped keeping time at all: 250 ticks, five
seconds. With 50 (one second), a local CI run failed the 40 m track when every tick of a
second took 21-34 ms while the other worker dry-ran a full A320 mission (ticks 12.6 ms
on average, 36.6 ms at the 99th percentile in that run); the same test passes alone."""


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


STRICT_BASE_TIMEOUT_MS = 1000.0 * DEFAULT_BASE_TIMEOUT
"""The executive's base timeout of a real robot file (the DBC's TimeoutMs of
BASE_HEARTBEAT): for the test whose subject is the executive's side of a lost link."""

STALL_TOLERANT_BASE_TIMEOUT_MS = 300.0
"""The executive's base timeout for every other rig. This shared 2-core VM sometimes
stops *both* rig processes at once for 100-130 ms (a CI run's CAN log: neither the
executive's heartbeat nor the base's went out for 106 and 129 ms, then each sent what
it owed in a burst), which a real base, a microcontroller of its own, never does. The
base's own watchdog stays within the issue's bound in every rig
(:data:`STALL_TOLERANT_WATCHDOG_MS`), so a killed executive is still braked in time."""


STALL_TOLERANT_WATCHDOG_MS = 120.0
"""The base's watchdog in every rig: the issue's bound (a killed executive braked within
0.15 s, ``tests/test_hil.py::BRAKE_WITHIN``) less 30 ms for the base's own check, not
the 100 ms default. With 100 ms, the 100-130 ms stalls of this shared VM above made the
base brake three times within 10 s in a resumed run that had finished its checkpoints
(a CI run: gaps of 103-132 ms at 643.3, 648.1 and 649.2 s), and the executive's link
rule rightly called that a lost link; a robot's dedicated computer does not stall so.
Most of those stalls stay under 120 ms."""


def robot_file(folder: Path, base_timeout_ms: float) -> Path:
    """A robot file like missions/robots/hil-localhost.xml on ports nobody else uses, the
    executive's base timeout ``base_timeout_ms``."""
    path = folder / "robot.xml"
    path.write_text(
        f"""<?xml version="1.0" encoding="UTF-8"?>
<robot xmlns="urn:walkaround:robot:1" id="hil-test">
  <can interface="udp_multicast" channel="239.74.163.2" port="{free_port(socket.SOCK_DGRAM)}"
       watchdog-ms="{STALL_TOLERANT_WATCHDOG_MS:g}" base-timeout-ms="{base_timeout_ms:g}"/>
  <ptu unit="front" index="0"/>
  <ptu unit="rear" index="1"/>
  <ptu unit="ptz" index="2"/>
  <laser id="front" host="127.0.0.1" port="{free_port()}"/>
  <laser id="rear" host="127.0.0.1" port="{free_port()}"/>
  <gps url="socket://127.0.0.1:{free_port()}" latitude-deg="43.6293" longitude-deg="1.3638"/>
  <detections endpoint="tcp://127.0.0.1:{free_port()}"/>
</robot>
"""
    )
    return path


REALTIME_BOOST = 10
"""The rig's processes run this many niceness steps above the test worker (down to -20)
where the OS lets the test (root on CI), as a robot's executive and base firmware would
run above the rest: the test is of the wires, not of a scheduler that starves them for
the other test worker. Relative, not absolute: a CI whose processes all start at
niceness -10 gave an absolute -10 no edge over the other worker. (A stall of the whole
VM no priority helps against: :data:`STALL_TOLERANT_BASE_TIMEOUT_MS`.)"""


def walkaround(*args: object, **kwargs: object) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "executive.cli", *map(str, args)],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        **kwargs,  # type: ignore[arg-type]
    )
    with contextlib.suppress(PermissionError):  # not root: the default priority
        nice = max(-20, os.getpriority(os.PRIO_PROCESS, 0) - REALTIME_BOOST)
        os.setpriority(os.PRIO_PROCESS, proc.pid, nice)
    return proc


class Hil:
    """One simulator and the runs against it, in ``folder``."""

    def __init__(
        self,
        folder: Path,
        scenario: Path = LAB_CLEAR,
        max_time: float = 400,
        base_timeout_ms: float = STALL_TOLERANT_BASE_TIMEOUT_MS,
    ) -> None:
        self.folder = folder
        self.scenario = scenario
        self.robot = robot_file(folder, base_timeout_ms)
        self.sim_out = folder / "sim"
        self.sim = walkaround(
            "sim-robot", scenario, "--robot", self.robot, "--out", self.sim_out,
            "--max-time", max_time,
        )  # fmt: skip
        self.run_out = folder / "run"
        self.runs: list[subprocess.Popen] = []

    def start_run(self, mission: Path = LAB_MISSION, *extra: object) -> subprocess.Popen:
        run = walkaround(
            "run", mission, "--robot", self.robot, "--out", self.run_out, "--quiet",
            "--max-missed-deadlines", MISSED_DEADLINES, *extra,
        )  # fmt: skip
        self.runs.append(run)
        return run

    def finish(self, proc: subprocess.Popen, timeout: float) -> tuple[int, str]:
        out, _ = proc.communicate(timeout=timeout)
        return proc.returncode, out

    def metrics(self) -> dict:
        return json.loads((self.run_out / "metrics.json").read_text())

    def truth(self) -> TruthLog:
        return TruthLog.read(self.sim_out / TRUTH_FILE)

    def judged(self) -> list:
        return judge_hil(load_scenario(self.scenario), self.truth(), self.metrics())

    def wait_for(self, predicate, timeout: float, what: str) -> None:
        wait_until(predicate, timeout, what)

    def journal_completed(self) -> list[str]:
        path = self.run_out / "journal.jsonl"
        if not path.exists():
            return []
        done = []
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if record.get("event") == "checkpoint-done":
                done.append(record["checkpoint"])
        return done

    def stop_sim(self) -> str:
        if self.sim.poll() is None:
            self.sim.send_signal(2)
        out, _ = self.sim.communicate(timeout=30)
        return out

    def close(self) -> None:
        for proc in (*self.runs, self.sim):
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
