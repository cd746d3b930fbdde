"""The shipped mission library: every file valid, and the missions look like the brief."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from executive.cli import check_any, main
from executive.core.loader import load_mission
from executive.core.model import Frame, ZoneKind
from executive.core.resources import missions_dir, shipped_mission_files
from tests.conftest import MISSIONS, SHIPPED_MISSIONS

ALL_FILES = sorted(MISSIONS.rglob("*.xml"))


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: str(p.relative_to(MISSIONS)))
def test_every_shipped_file_is_valid(path):
    assert check_any(path) == []


def test_library_has_every_type():
    folders = {p.relative_to(MISSIONS).parts[0] for p in ALL_FILES}
    types = {p.parent.name for p in MISSIONS.glob("*/aircraft.xml")}
    assert types == {"a320", "b737-800", "lab", "track"}
    # besides the aircraft types, the robot files (the wires of a robot, issue 14) and the
    # Monte Carlo campaigns over the types' scenarios (issue 16)
    assert folders == types | {"robots", "campaigns"}
    assert {p.name for p in (MISSIONS / "robots").glob("*.xml")} >= {"hil-localhost.xml"}
    assert all(p.exists() for p in SHIPPED_MISSIONS.values())


@pytest.mark.parametrize("name", ["a320", "b737-800"])
def test_airliner_missions_shape(name):
    mission = load_mission(SHIPPED_MISSIONS[name])
    assert 18 <= len(mission.checkpoints) <= 25
    kinds = {z.kind for z in mission.airport.zones}
    assert ZoneKind.REFUELLING in kinds and ZoneKind.ENGINE_DANGER in kinds
    # The charging station is about 60 m from the aircraft's nose.
    station, parking = mission.airport.station, mission.airport.parking
    assert 45 <= math.hypot(station.x - parking.x, station.y - parking.y) <= 80
    # Walk-around order (FCOM and Boeing FCOM): start on the LEFT forward fuselage
    # (+y in the aircraft frame), round the nose, down the right side (-y), back up the left.
    first = mission.checkpoints[0].pose
    assert first.y > 0 and first.x < mission.aircraft.dimensions.length / 3
    ys = np.array([c.pose.y for c in mission.checkpoints])
    first_right = int(np.argmax(ys < -1.0))
    assert first_right <= 5
    back_left = first_right + int(np.argmax(ys[first_right:] > 1.0))
    assert back_left > first_right + 5
    assert np.all(ys[back_left:] > -1.0), "the return leg stays on the left side"
    # Every feature that is inspected somewhere exists; every item is inspected once at least.
    inspected = {i for c in mission.checkpoints for i in c.items}
    assert inspected <= set(mission.aircraft.items)
    assert len(inspected) >= 0.8 * len(mission.aircraft.items)


def test_lab_mockup_is_a_fence_with_targets():
    mission = load_mission(SHIPPED_MISSIONS["lab"])
    assert mission.aircraft.type == "lab-mockup"
    assert any(f.kind == "target" for f in mission.aircraft.features.values())
    assert len(mission.checkpoints) == 3
    assert {c.servo for c in mission.checkpoints if c.servo} >= {"pbvs", "ibvs"}


def test_aircraft_frame_zones_move_with_the_aircraft():
    mission = load_mission(SHIPPED_MISSIONS["a320"])
    assert any(z.frame is Frame.AIRCRAFT for z in mission.airport.zones)


def test_validate_cli_on_shipped_library(capsys):
    assert main(["validate", *map(str, ALL_FILES)]) == 0
    text = capsys.readouterr().out
    assert text.count("ok    ") == len(ALL_FILES)
    assert main(["validate", "--json", *map(str, ALL_FILES)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["valid"] is True and len(report["files"]) == len(ALL_FILES)


def test_installed_package_carries_its_data(tmp_path):
    """`walkaround validate` without files checks the library shipped in the package,
    from any working directory (the README's non-editable `pip install .`)."""
    assert {p.name for p in shipped_mission_files()} >= {"aircraft.xml", "preflight.xml"}
    assert (missions_dir() / "a320" / "preflight.xml").is_file()
    env = {**os.environ, "PYTHONPATH": ""}
    result = subprocess.run(
        [sys.executable, "-m", "executive.cli", "validate"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "invalid" in result.stdout and " 0 invalid" in result.stdout
