"""Building small scenarios around the shipped missions for sim2d tests."""

import math
import shutil
from pathlib import Path

import numpy as np

from executive.core.frames import Pose2, wrap_angle
from executive.core.records import VelocityCommand
from executive.runtime import StopRequest, TickHook
from sim2d.robot import SimRobot
from sim2d.scenario import Scenario, load_scenario
from tests.conftest import MISSIONS

NO_NOISE = (
    '<noise laser-range="0" pixel="0" camera-dropout="0" wheel="0" imu-rate="0" imu-bias="0"'
    ' gps="0"/>'
)
NO_SLIP = '<slip longitudinal="0" turn="0" lateral="0"/>'


def scenario_file(
    tmp_path: Path,
    body: str = "",
    *,
    mission_type: str = "a320",
    mission: str = "preflight.xml",
    seed: int = 1,
    name: str = "test.xml",
) -> Path:
    """A scenario in a private copy of one mission folder; ``body`` is its inner XML."""
    lib = tmp_path / "lib"
    if not (lib / mission_type).exists():
        shutil.copytree(MISSIONS / mission_type, lib / mission_type)
    folder = lib / mission_type / "scenarios"
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<scenario xmlns="urn:walkaround:scenario:1" id="t" mission="../{mission}" '
        f'seed="{seed}">\n{body}\n</scenario>\n',
        encoding="utf-8",
    )
    return path


def make_scenario(tmp_path: Path, body: str = "", **kwargs) -> Scenario:
    return load_scenario(scenario_file(tmp_path, body, **kwargs))


def start(x: float, y: float, heading_deg: float) -> str:
    return f'<start x="{x}" y="{y}" heading-deg="{heading_deg}"/>'


def drive(robot: SimRobot, v: float, omega: float, seconds: float, rate: float = 50.0) -> None:
    """Send the same command every control period for ``seconds``."""
    for _ in range(round(seconds * rate)):
        robot.send(VelocityCommand(v, omega))
        robot.advance(1.0 / rate)


def odometry_run(robot: SimRobot, v: float, omega: float, seconds: float) -> tuple[Pose2, Pose2]:
    """Drive and dead-reckon from the wheel speeds (thesis eq. 2.1, 2.2); (odometry, truth)."""
    track = robot.scenario.mission.platform.track
    pose = robot.truth.robot
    x, y, th = pose.x, pose.y, pose.theta
    last = robot.read().wheels
    rate = 50.0
    for _ in range(round(seconds * rate)):
        robot.send(VelocityCommand(v, omega))
        robot.advance(1.0 / rate)
        wheels = robot.read().wheels
        if wheels is None or last is None or wheels.stamp == last.stamp:
            continue
        dt = wheels.stamp - last.stamp
        v_odo = (wheels.right + wheels.left) / 2.0  # eq. 2.1
        w_odo = (wheels.right - wheels.left) / (2.0 * track / 2.0)  # eq. 2.2, d = track / 2
        x += v_odo * math.cos(th) * dt
        y += v_odo * math.sin(th) * dt
        th = wrap_angle(th + w_odo * dt)
        last = wheels
    return Pose2(x, y, th), robot.truth.robot


def heading_error(a: Pose2, b: Pose2) -> float:
    return abs(wrap_angle(a.theta - b.theta))


def position_error(a: Pose2, b: Pose2) -> float:
    return float(np.hypot(a.x - b.x, a.y - b.y))


SERVO_POSITION, SERVO_HEADING_DEG = 0.02, 0.5
"""Issue 13's bar for a checkpoint finished by visual servoing (m, deg)."""


def assert_finished_by_servoing(run, first: int | None = None) -> list[str]:
    """Every checkpoint of ``run`` (the ``first`` ones of a run stopped early) with a servo
    target that a camera sees with two points or more from the checkpoint was finished by
    visual servoing (the last controller before its inspection, correct camera angle aside)
    within 2 cm and 0.5 deg of its true pose; the one-point (bearing-only) targets, which the
    compiler warns about, are metric. Returns the ids of the servoed checkpoints."""
    controllers = [e.detail["to"] for e in run.result.events if e.kind == "controller"]
    return assert_servoed(
        run.scenario.mission.checkpoints[:first], run.checkpoints, run.warnings, controllers
    )


def assert_servoed(checkpoints, outcomes, warnings: list[str], controllers: list[str]) -> list[str]:
    """:func:`assert_finished_by_servoing` on its parts: the mission's ``checkpoints``,
    their ``outcomes`` (``position_error``, ``heading_error_deg``: a run's or a report's,
    in the same order; may be fewer), the compiler's ``warnings`` and the names of the
    controllers switched to, in order (also the report's ``events.jsonl``)."""
    assert not [w for w in warnings if "servo-metric" in w], warnings
    bearing_only = {
        cp.id
        for cp in checkpoints
        if any(f"checkpoint '{cp.id}'" in w and "servo-bearing-only" in w for w in warnings)
    }
    servoed = []
    for cp, outcome in zip(checkpoints, outcomes, strict=False):
        if cp.target is None or cp.id in bearing_only:
            continue
        inspect = controllers.index(f"inspect {cp.id}")
        before = [n for n in controllers[:inspect] if not n.startswith("correct ")]
        assert before[-1].startswith("visual servoing ("), (cp.id, before[-3:])
        assert outcome.position_error <= SERVO_POSITION, (cp.id, outcome)
        assert outcome.heading_error_deg <= SERVO_HEADING_DEG, (cp.id, outcome)
        servoed.append(cp.id)
    return servoed


def stop_once_done(count: int) -> tuple[StopRequest, TickHook]:
    """A stop request and the tick observer that sets it once ``count`` checkpoints are
    done (``Runtime.completed``): for a test whose subject lies in a mission's first
    checkpoints. After the run, the request is truthy only if that many were done."""
    stop = StopRequest()

    def observe(t, frame, sent, rt) -> None:
        if len(rt.completed) >= count:
            stop.set(f"{count} checkpoints done")

    return stop, observe
