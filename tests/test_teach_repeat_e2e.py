"""Teach and repeat under a hangar ceiling, end to end in sim2d (issue 17, seed 002).

``walkaround teach`` drives the track robot (with an upward camera) round a 62 m loop with
four 90 degree turns under a 10 m ceiling, maps it and writes the route; the mission's
approach is then that taught route, repeated by the executive (ceiling fixes fused in the
pose filter, avoidance and e-stop above the controller) from a start 0.5 m to the left of
the taught start and turned 10 degrees. The lateral deviation is measured on the
simulator's true trajectory against the teaching run's true trajectory.
"""

import csv
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from executive.cli import main
from executive.core.loader import load_mission
from executive.core.taught_route import load_route
from executive.dryrun import dry_run
from executive.runtime import StopRequest
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS

CAMERA = (
    '    <ceiling-camera x="0" y="0" z="0.6" yaw-deg="0" width-px="640" height-px="480"'
    ' hfov-deg="80" rate-hz="4"/>\n'
)
LOOP = "9 0\n11 0\n11 10\n-11 10\n-11 0\n1.5 0  # back to P's neighbourhood\n"
"""From the station (0, 0) facing east: 62 m round a 22 m x 10 m rectangle, turns of 2 m."""
SETTLED = 3.0
"""Metres from the start after which the deviation is judged: twice the settling distance
(1.5 m) in which the law brings the 0.5 m start offset within 5 %."""


def mission(lib: Path, name: str, approach: str = "", airport: str = "") -> Path:
    text = (MISSIONS / "track" / "straight-run.xml").read_text(encoding="utf-8")
    text = text.replace("  </platform>", CAMERA + "  </platform>", 1)
    text = text.replace("<approach>\n", f"<approach>\n{approach}", 1)
    text = text.replace("  </airport>", f"{airport}  </airport>", 1)
    path = lib / "track" / name
    path.write_text(text, encoding="utf-8")
    return path


def scenario(lib: Path, mission_file: str, name: str, start: str, seed: int = 1) -> Path:
    path = lib / "track" / "scenarios" / name
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<scenario xmlns="urn:walkaround:scenario:1" id="hangar" mission="../{mission_file}"'
        f' seed="{seed}" duration="600">\n  {start}\n'
        '  <ceiling x-min="-25" y-min="-12" x-max="25" y-max="22" height="10"/>\n'
        "</scenario>\n",
        encoding="utf-8",
    )
    return path


@pytest.fixture(scope="module")
def taught(tmp_path_factory) -> Path:
    """The library with a route taught by ``walkaround teach`` in track/taught/."""
    lib = tmp_path_factory.mktemp("hangar") / "lib"
    shutil.copytree(MISSIONS / "track", lib / "track")
    mission(lib, "hangar-teach.xml")
    teach_scenario = scenario(
        lib, "hangar-teach.xml", "teach.xml", '<start x="0" y="0" heading-deg="0"/>'
    )
    path = lib / "track" / "loop.txt"
    path.write_text(LOOP, encoding="utf-8")
    out = lib / "track" / "taught"
    args = ["teach", str(teach_scenario), "--path", str(path), "--out", str(out)]
    assert main([*args, "--speed", "1.0", "--id", "hangar-loop"]) == 0
    return lib


def test_teach_writes_a_valid_route_with_its_mosaic_and_key_images(taught, capsys):
    out = taught / "track" / "taught"
    assert main(["validate", str(out / "route.xml")]) == 0
    assert "taught route 'hangar-loop'" in capsys.readouterr().out
    route = load_route(out / "route.xml")  # the loader checks §2.3's rules
    assert route.length >= 60.0 and route.speed == 1.0
    assert all(k.image is not None and k.image.is_file() for k in route.keys)
    headings = [k.pose_m.theta for k in route.keys]
    turned = np.abs(np.diff(np.unwrap(headings)))
    assert turned.max() < math.radians(10.0) and np.sum(turned) > math.radians(350.0)
    truth = np.loadtxt(out / "taught-path.csv", delimiter=",", skiprows=1)
    keys = np.array([(k.pose_m.x, k.pose_m.y) for k in route.keys])
    near = np.min(np.hypot(*(truth[None, :, 1:3] - keys[:, None, :]).transpose(2, 0, 1)), axis=1)
    assert near.max() < 0.06  # the key poses (mosaic fixes) lie on the true taught path


def lateral(path: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance of each point to the polyline ``path`` (N, 2)."""
    a, ab = path[:-1], np.diff(path, axis=0)
    out = np.empty(len(points))
    for k, q in enumerate(points):
        t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        out[k] = np.min(np.hypot(*(a + t[:, None] * ab - q).T))
    return out


def test_the_taught_route_is_repeated_from_an_offset_start(taught):
    lib = taught
    mission(
        lib,
        "hangar.xml",
        approach='    <taught-route file="taught/route.xml"/>\n',
        airport='    <ceiling-mosaic file="taught/mosaic.npz"/>\n',
    )
    assert load_mission(lib / "track" / "hangar.xml").taught_route is not None
    start = '<start x="0" y="0.5" heading-deg="10"/>'
    sc = load_scenario(scenario(lib, "hangar.xml", "repeat.xml", start, seed=3))
    robot = SimRobot(sc)
    stop = StopRequest()
    trajectory: list[tuple[float, float]] = []

    def observe(t, frame, sent, rt) -> None:
        pose = robot.truth.robot
        trajectory.append((pose.x, pose.y))
        if rt.compiled.route_sessions[0].follower.done:
            stop.set("the taught route is done")

    run = dry_run(sc, robot=robot, stop=stop, observers=[observe], max_time=200.0)
    assert stop, "the route was not completed"
    route = load_route(lib / "track" / "taught" / "route.xml")
    passed = [e for e in run.result.events if e.kind in ("key-passed", "route-done")]
    assert [e.detail["key"] for e in passed] == [k.id for k in route.keys[1:]]
    assert not [e for e in run.result.events if e.kind == "safety"]

    with open(lib / "track" / "taught" / "taught-path.csv", encoding="utf-8") as f:
        taught_xy = np.array([(float(r["x"]), float(r["y"])) for r in csv.DictReader(f)])
    xy = np.array(trajectory)
    travelled = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    deviation = lateral(taught_xy, xy[travelled > SETTLED])
    assert travelled[-1] > 60.0
    # issue 17's acceptance: p95 <= 5 cm, max <= 10 cm (measured: p95 ~2 cm, max ~3 cm)
    assert np.percentile(deviation, 95) <= 0.05
    assert deviation.max() <= 0.10


def test_teach_refuses_bad_input_with_exit_2(tmp_path, capsys):
    lib = tmp_path / "lib"
    shutil.copytree(MISSIONS / "track", lib / "track")
    no_camera = scenario(
        lib, "straight-run.xml", "plain.xml", '<start x="0" y="0" heading-deg="0"/>'
    )
    path = tmp_path / "p.txt"
    path.write_text("5 0\n", encoding="utf-8")
    args = ["teach", str(no_camera), "--path", str(path), "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "<ceiling-camera>" in capsys.readouterr().err
    path.write_text("5 0\nten 3\n", encoding="utf-8")
    assert main(args) == 2
    assert "p.txt:2:1: error: expected a waypoint" in capsys.readouterr().err
    assert main([*args[:-2], "--out", str(tmp_path / "o"), "--speed", "0"]) == 2


def test_the_scripted_path_turns_round_the_corners_on_arcs():
    from executive.core.frames import Pose2
    from executive.teach import fillet_path

    poses = fillet_path(Pose2(0.0, 0.0, 0.0), [(10.0, 0.0), (10.0, 8.0)], radius=2.0)
    xy = np.array([(p.x, p.y) for p in poses])
    steps = np.hypot(*np.diff(xy, axis=0).T)
    assert steps.max() <= 0.05 + 1e-9 and xy[-1] == pytest.approx((10.0, 8.0))
    turn = np.abs(np.diff(np.unwrap([p.theta for p in poses])))
    assert turn.max() <= 0.05 / 2.0 + 1e-9  # curvature 1 / radius, nowhere a corner
    corner = np.hypot(xy[:, 0] - 8.0, xy[:, 1] - 2.0)  # the arc's centre
    on_arc = (xy[:, 0] > 8.0) & (xy[:, 1] < 2.0)
    assert corner[on_arc] == pytest.approx(2.0, abs=1e-6)
    with pytest.raises(ValueError, match="too short"):
        fillet_path(Pose2(0.0, 0.0, 0.0), [(3.0, 0.0), (3.0, 3.0), (0.0, 3.0)], radius=2.0)
