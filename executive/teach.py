"""``walkaround teach``: teach a route under a hangar ceiling in sim2d (issue 17, seed 002
§2.2-2.3).

The simulated robot is driven along a scripted path (a path file of waypoints, joined by
straight lines and circular turns of ``--turn-radius``) as an operator would drive it: by
looking at the robot, i.e. steering on its *true* pose along the densely sampled path
(the VNHV law of :mod:`behaviours.laws.routes` with a key every few centimetres). While
it drives, every upward image (:attr:`SensorFrame.ceiling`) is added to a
:class:`~behaviours.laws.ceiling_landmarks.CeilingMapper` (eq. 4; the first image placed
at the robot's known start pose, so M = A; the next ones with the previous fix moved by
wheel odometry, eq. 2.1-2.2, as the prior); each image's fix and the landmarks it shows
(those it matched and those it created) make the recording from which
:func:`~behaviours.laws.routes.select_key_images` keeps the key images (§2.3). Written
to ``--out``: ``mosaic.npz`` (:mod:`behaviours.laws.mosaic`), ``route.xml``
(``schemas/route.xsd``; validated as written), ``keys/<id>.png`` (not with
``--no-key-images``) and ``taught-path.csv``, the simulator's true trajectory of the
teaching run (t, x, y, theta in A), the ground truth a repeat is judged against.

The path file: one waypoint ``x y`` (metres in A) per line; ``#`` starts a comment. The
path starts at the scenario's start pose; its first leg leaves in the start heading's
direction only if the first waypoint lies that way (otherwise the taught path is what
the robot drove to join the leg). Exit codes: 0 taught, 1 the teaching failed (the robot
could not be mapped, too sparse a recording), 2 bad input.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from behaviours.laws.ceiling_landmarks import CeilingMapper, law_camera_for
from behaviours.laws.mosaic import save_mosaic
from behaviours.laws.routes import (
    KeyImageRules,
    RecordedImage,
    RouteFollower,
    SparseRecordingError,
    gains_for_settling_distance,
    select_key_images,
)
from executive.core.files import read_regular
from executive.core.frames import Pose2, wrap_angle
from executive.core.model import KeyImage, TaughtRoute
from executive.core.problems import InvalidInputError, Problem, SourceLocation
from executive.core.records import CeilingImage, SensorFrame, VelocityCommand
from executive.core.taught_route import (
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_SETTLING_DISTANCE,
    load_route,
    route_xml,
)
from executive.core.xmlreader import display_path
from sim2d.ceiling import upward_camera_for
from sim2d.robot import SimRobot
from sim2d.scenario import Scenario

__all__ = [
    "TeachError",
    "TeachRun",
    "add_teach_command",
    "fillet_path",
    "read_path_file",
    "teach",
    "write_taught",
]

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2
PATH_STEP = 0.05
"""Metres between the scripted path's poses (the teacher's dense keys)."""
MAX_PATH_BYTES = 1_000_000
MAX_WAYPOINTS = 10_000
RATE_HZ = 50.0


class TeachError(RuntimeError):
    """The teaching run could not make a route (mapping lost, too sparse a recording)."""


# -- the scripted path ------------------------------------------------------------------------
def read_path_file(path: Path | str) -> list[tuple[float, float]]:
    """The waypoints of a path file (module doc); InvalidInputError with file:line."""
    name = display_path(Path(path))
    try:
        raw = read_regular(path, MAX_PATH_BYTES)
    except Exception as exc:  # unreadable: one problem, the reason
        raise InvalidInputError([Problem(SourceLocation(name), "path-file", str(exc))]) from None
    problems, points = [], []
    for number, line in enumerate(raw.decode("utf-8", errors="replace").splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        words = text.replace(",", " ").split()
        try:
            x, y = (float(w) for w in words)
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError
        except ValueError:
            problems.append(
                Problem(
                    SourceLocation(name, number, 1),
                    "path-waypoint",
                    f"expected a waypoint 'x y' (two finite numbers, metres), found '{text}'",
                )
            )
            continue
        points.append((x, y))
    if not problems and not points:
        problems.append(Problem(SourceLocation(name), "path-empty", "the path has no waypoint"))
    if len(points) > MAX_WAYPOINTS:
        problems.append(
            Problem(SourceLocation(name), "path-size", f"more than {MAX_WAYPOINTS} waypoints")
        )
    if problems:
        raise InvalidInputError(problems)
    return points


def fillet_path(
    start: Pose2, waypoints: Sequence[tuple[float, float]], radius: float, step: float = PATH_STEP
) -> list[Pose2]:
    """Poses every ``step`` m along the polyline start -> waypoints with each corner
    replaced by a circular arc of ``radius`` tangent to both legs (headings along the
    path). ValueError when two corners' arcs would overlap on a leg."""
    points = [(start.x, start.y), *waypoints]
    points = [p for k, p in enumerate(points) if k == 0 or math.dist(p, points[k - 1]) > 1e-6]
    if len(points) < 2:
        raise ValueError("the path needs a waypoint away from the start")
    headings = [math.atan2(b[1] - a[1], b[0] - a[0]) for a, b in itertools.pairwise(points)]
    turns = [wrap_angle(h2 - h1) for h1, h2 in itertools.pairwise(headings)]
    cut = [radius * math.tan(abs(t) / 2.0) for t in turns]  # tangent length at each corner
    pieces: list[tuple[float, float]] = []  # (length, curvature)
    for k in range(len(headings)):
        leg = math.dist(points[k], points[k + 1])
        used = (cut[k - 1] if k > 0 else 0.0) + (cut[k] if k < len(turns) else 0.0)
        if used > leg + 1e-9:
            raise ValueError(
                f"leg {k + 1} ({leg:.2f} m) is too short for turns of radius {radius:g} m "
                f"at both ends ({used:.2f} m needed)"
            )
        pieces.append((leg - used, 0.0))
        if k < len(turns) and abs(turns[k]) > 1e-9:
            pieces.append((radius * abs(turns[k]), math.copysign(1.0 / radius, turns[k])))
    x, y, th = start.x, start.y, headings[0]
    out = [Pose2(x, y, th)]
    for length, kappa in pieces:
        n = max(1, math.ceil(length / step))
        h = length / n
        for _ in range(n):
            if kappa == 0.0:
                x, y = x + h * math.cos(th), y + h * math.sin(th)
            else:
                th2 = th + kappa * h
                x += (math.sin(th2) - math.sin(th)) / kappa
                y -= (math.cos(th2) - math.cos(th)) / kappa
                th = th2
            out.append(Pose2(x, y, wrap_angle(th)))
    return out


# -- teaching -------------------------------------------------------------------------------
@dataclass
class TeachRun:
    """What a teaching run produced: the mapper (the mosaic), the recording (fix and
    landmarks of each image placed), the images, the key images chosen, the robot's true
    trajectory (t, x, y, theta) and the counts of images placed and not placed."""

    mapper: CeilingMapper
    ceiling_height: float
    recording: list[RecordedImage]
    images: list[np.ndarray]
    keys: tuple[int, ...] = ()
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)
    unplaced: int = 0

    def route(
        self, route_id: str, speed: float, settling: float, rules: KeyImageRules
    ) -> TaughtRoute:
        """The taught route of the key images (poses in M = A)."""
        keys = tuple(
            KeyImage(
                f"k{n:03d}",
                self.recording[i].pose_m,
                self.recording[i].landmarks,
                Path("keys") / f"k{n:03d}.png",
            )
            for n, i in enumerate(self.keys)
        )
        return TaughtRoute(
            id=route_id,
            mosaic=Path("mosaic.npz"),
            ceiling_height=self.ceiling_height,
            speed=speed,
            settling_distance=settling,
            max_heading_change=rules.max_heading_change,
            keys=keys,
        )


class _Odometry:
    """Dead reckoning from the wheel speeds (thesis eq. 2.1, 2.2)."""

    def __init__(self, track: float, pose: Pose2) -> None:
        self.track = track
        self.pose = pose
        self._stamp: float | None = None

    def update(self, frame: SensorFrame) -> None:
        wheels = frame.wheels
        if wheels is None or wheels.stamp == self._stamp:
            return
        if self._stamp is not None:
            dt = wheels.stamp - self._stamp
            v = 0.5 * (wheels.right + wheels.left)
            w = (wheels.right - wheels.left) / self.track
            self.pose = self.pose @ Pose2(v * dt, 0.0, w * dt)
        self._stamp = wheels.stamp


def teach(
    scenario: Scenario,
    waypoints: Sequence[tuple[float, float]],
    *,
    speed: float = 0.5,
    turn_radius: float = 2.0,
    rules: KeyImageRules | None = None,
    settling: float = 0.6,
    robot: SimRobot | None = None,
) -> TeachRun:
    """Drive ``scenario``'s robot along the path (module doc), map the ceiling and
    choose the key images. ``speed`` < 0 teaches driving backwards (the robot faces
    away from the way it goes). Raises TeachError when no route can be made."""
    rules = rules or KeyImageRules()
    mission = scenario.mission
    spec = mission.platform.ceiling_camera
    if spec is None or scenario.ceiling is None:
        raise TeachError("teaching needs the platform's <ceiling-camera> and a <ceiling>")
    robot = robot or SimRobot(scenario)
    start = robot.truth.robot
    travel = start if speed > 0.0 else Pose2(start.x, start.y, wrap_angle(start.theta + math.pi))
    dense = fillet_path(travel, waypoints, turn_radius)
    if speed < 0.0:
        dense = [Pose2(p.x, p.y, wrap_angle(p.theta + math.pi)) for p in dense]
    platform = mission.platform
    # the operator slows down in the turns so that successive images turn by at most half
    # rule 2's threshold (V lowered by limit_speed: the path does not change)
    omega_max = min(platform.max_angular_speed, 0.5 * rules.max_heading_change * spec.rate_hz)
    driver = RouteFollower(
        dense,
        speed,
        gains_for_settling_distance(settling),
        omega_max=omega_max,
        deceleration=platform.max_acceleration,
    )
    height = scenario.ceiling.spec.height
    camera = upward_camera_for(spec)
    mapper = CeilingMapper(
        law_camera_for(camera, height), (camera.image_width_px, camera.image_height_px)
    )
    run = TeachRun(mapper, height, [], [])
    odometry = _Odometry(platform.track, start)
    last_image: CeilingImage | None = None
    anchor: tuple[Pose2, Pose2] | None = None  # (fix, odometry) at the last placed image
    limit = 4.0 * (len(dense) * PATH_STEP / abs(speed)) + 60.0
    t = 0.0
    while t < limit:
        frame = robot.read()
        odometry.update(frame)
        image = frame.ceiling
        if image is not None and image is not last_image:
            last_image = image
            prior = start if anchor is None else anchor[0] @ (anchor[1].inverse() @ odometry.pose)
            before = set(mapper.landmarks)
            fix = mapper.add_image(image.image, prior)
            if fix is None:
                run.unplaced += 1
            else:
                anchor = (fix.pose, odometry.pose)
                seen = frozenset(fix.used) | (set(mapper.landmarks) - before)
                run.recording.append(RecordedImage(fix.pose, frozenset(seen)))
                run.images.append(image.image)
        truth = robot.truth.robot
        run.truth.append((t, truth.x, truth.y, truth.theta))
        step = driver.step(truth)
        if step.done:
            robot.send(VelocityCommand.stop())
            break
        robot.send(VelocityCommand(step.v, step.omega))
        robot.advance(1.0 / RATE_HZ)
        t += 1.0 / RATE_HZ
    else:
        raise TeachError(f"the robot did not reach the path's end in {limit:.0f} s")
    if len(run.recording) < 2:
        raise TeachError(f"only {len(run.recording)} image(s) could be placed in the mosaic")
    try:
        run.keys = select_key_images(run.recording, rules)
    except SparseRecordingError as exc:
        raise TeachError(f"too sparse a recording: {exc}") from None
    return run


def write_taught(
    out: Path,
    run: TeachRun,
    route_id: str,
    speed: float,
    settling_distance: float = DEFAULT_SETTLING_DISTANCE,
    rules: KeyImageRules | None = None,
    key_images: bool = True,
) -> TaughtRoute:
    """Write ``mosaic.npz``, ``keys/*.png`` (unless not ``key_images``: the images are
    for people, the repeat needs only the key poses and landmarks; 640x480 PNGs of a
    ceiling are ~170 kB each) and ``route.xml`` in ``out``; returns the route as loaded
    back (so it validates)."""
    rules = rules or KeyImageRules()
    route = run.route(route_id, speed, settling_distance, rules)
    out.mkdir(parents=True, exist_ok=True)
    save_mosaic(out / "mosaic.npz", run.mapper, ceiling_height=run.ceiling_height)
    images: dict[str, str] = {}
    if key_images:
        (out / "keys").mkdir(exist_ok=True)
        for key, index in zip(route.keys, run.keys, strict=True):
            assert key.image is not None
            if not cv2.imwrite(str(out / key.image), run.images[index]):
                raise OSError(f"could not write {out / key.image}")
        images = {k.id: str(k.image) for k in route.keys if k.image is not None}
    (out / "route.xml").write_text(route_xml(route, "mosaic.npz", images), encoding="utf-8")
    truth = "t,x,y,theta\n" + "".join(
        f"{t:.3f},{x:.5f},{y:.5f},{th:.6f}\n" for t, x, y, th in run.truth
    )
    (out / "taught-path.csv").write_text(truth, encoding="utf-8")
    return load_route(out / "route.xml", out)


# -- command line ---------------------------------------------------------------------------------
def add_teach_command(sub: argparse._SubParsersAction) -> None:
    """The ``teach`` subcommand of the ``walkaround`` parser."""
    teach_cmd = sub.add_parser(
        "teach",
        help="teach a route under a hangar ceiling in sim2d (mosaic + key images + route file)",
        description="Drive the scenario's robot along a scripted path (a file of 'x y' "
        "waypoints in A joined by turns of --turn-radius), map the ceiling from its upward "
        "images (seed 002 eq. 4), choose the key images (§2.3: a common landmark and a "
        "heading change below the threshold between successive ones) and write "
        "OUT/mosaic.npz, OUT/route.xml and OUT/keys/*.png. A mission's <approach> names the "
        "route with <taught-route file=.../>. Exit 0 taught, 1 the teaching failed, 2 bad "
        "input.",
    )
    teach_cmd.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario XML")
    teach_cmd.add_argument("--path", type=Path, required=True, help="waypoint file ('x y' lines)")
    teach_cmd.add_argument("--out", type=Path, required=True, help="output folder")
    teach_cmd.add_argument("--id", default="taught-route", help="the route's id")
    teach_cmd.add_argument(
        "--speed",
        type=float,
        default=0.5,
        help="V, m/s, non-zero, -5 to 5: negative teaches backwards (default 0.5)",
    )
    teach_cmd.add_argument(
        "--turn-radius", type=float, default=2.0, help="metres, more than 0 (default 2)"
    )
    teach_cmd.add_argument(
        "--max-heading-change-deg",
        type=float,
        default=DEFAULT_MAX_HEADING_CHANGE_DEG,
        help="rule 2's threshold between key images, degrees, more than 0, at most 80 (default 10)",
    )
    teach_cmd.add_argument(
        "--settling-distance",
        type=float,
        default=DEFAULT_SETTLING_DISTANCE,
        help="the repeat law's settling distance written in the route, m, 0.1 to 50 (default 1.5)",
    )
    teach_cmd.add_argument(
        "--no-key-images",
        action="store_true",
        help="write no keys/*.png (the route file then names none; the repeat does not need them)",
    )
    teach_cmd.set_defaults(handler=cmd_teach)


def _bad(message: str) -> int:
    print(f"walkaround teach: {message}", file=sys.stderr)
    return EXIT_BAD_INPUT


def cmd_teach(args: argparse.Namespace) -> int:
    from executive.cli import check_any
    from executive.core.files import output_dir_problem
    from sim2d.scenario import load_scenario

    if not (math.isfinite(args.speed) and 0.0 < abs(args.speed) <= 5.0):
        return _bad(f"--speed {args.speed:g}: must be non-zero, at most 5 m/s either way")
    if not (math.isfinite(args.turn_radius) and args.turn_radius > 0.0):
        return _bad(f"--turn-radius {args.turn_radius:g}: must be > 0")
    if not 0.0 < args.max_heading_change_deg <= 80.0:
        return _bad("--max-heading-change-deg: must be in (0, 80]")
    if not 0.1 <= args.settling_distance <= 50.0:
        return _bad("--settling-distance: must be in [0.1, 50] m")
    problem = output_dir_problem(args.out)
    if problem:
        return _bad(problem)
    problems = check_any(args.scenario)
    try:
        waypoints = read_path_file(args.path)
    except InvalidInputError as exc:
        problems += list(exc.problems)
    if problems:
        for p in problems:
            print(f"{p.where}: error: {p.message} [{p.code}]", file=sys.stderr)
        return EXIT_BAD_INPUT
    scenario = load_scenario(args.scenario)
    if scenario.mission.platform.ceiling_camera is None or scenario.ceiling is None:
        return _bad(
            f"{args.scenario}: teaching needs the platform's <ceiling-camera> (mission) and a "
            "<ceiling> (scenario)"
        )
    rules = KeyImageRules(math.radians(args.max_heading_change_deg))
    try:
        start = scenario.start
        fillet_path(start, waypoints, args.turn_radius)
    except ValueError as exc:
        return _bad(f"{args.path}: {exc}")
    try:
        run = teach(
            scenario, waypoints, speed=args.speed, turn_radius=args.turn_radius, rules=rules
        )
    except TeachError as exc:
        print(f"walkaround teach: failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    args.out.mkdir(parents=True, exist_ok=True)
    route = write_taught(
        args.out,
        run,
        args.id,
        args.speed,
        args.settling_distance,
        rules,
        key_images=not args.no_key_images,
    )
    print(
        f"taught route '{route.id}': {len(run.recording)} images placed "
        f"({run.unplaced} not), {len(run.mapper.landmarks)} landmarks, {len(route.keys)} key "
        f"images over {route.length:.1f} m -> {args.out / 'route.xml'}"
    )
    return EXIT_OK
