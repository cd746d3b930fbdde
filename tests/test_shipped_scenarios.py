"""Every shipped scenario builds a world that runs, and sim-view draws it."""

import pytest

from executive.cli import main
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS

SCENARIOS = sorted(MISSIONS.rglob("scenarios/*.xml"))


def test_each_airliner_has_the_required_scenarios():
    required = {
        "clear-apron",
        "busy-apron",
        "adversarial-trolley",
        "gps-denied-hangar",
        "camera-faults",
        "offset-apron",
    }
    for kind in ("a320", "b737-800"):
        names = {p.stem for p in (MISSIONS / kind / "scenarios").glob("*.xml")}
        assert required <= names, kind
    track = load_scenario(MISSIONS / "track" / "scenarios" / "straight-run-40m.xml")
    kinds = [type(o).__name__ for o in track.obstacles]
    assert kinds.count("StaticObstacle") == 2 and len(kinds) - kinds.count("StaticObstacle") == 2
    assert "Chaser" in kinds  # one of the moving obstacles is adversarial


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: f"{p.parent.parent.name}/{p.stem}")
def test_scenario_world_runs(path):
    robot = SimRobot(load_scenario(path))
    robot.advance(2.0)
    frame = robot.read()
    assert set(frame.scans) == set(robot.scenario.mission.platform.lasers)
    assert not robot.truth.collisions  # nothing starts in contact with the robot


def test_sim_view_writes_a_picture(tmp_path, capsys):
    from matplotlib.image import imread

    out = tmp_path / "world.png"
    busy = MISSIONS / "a320" / "scenarios" / "busy-apron.xml"
    assert main(["sim-view", str(busy), "--out", str(out), "--at", "1"]) == 0
    image = imread(out)
    assert image.shape[0] > 500 and image.shape[1] > 500
    assert image[..., :3].std() > 0.05  # not a blank canvas
    assert "wrote" in capsys.readouterr().out
