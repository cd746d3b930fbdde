"""Scenario files: valid ones load, each kind of mistake is reported at its line."""

import pytest

from executive.cli import main
from sim2d.scenario import FaultKind, PathMover, check_scenario, load_scenario
from tests.sim2d_helpers import scenario_file

GOOD = """  <parking-offset dx="0.5" dy="-0.3" dheading-deg="2"/>
  <noise pixel="1.0"/>
  <obstacles>
    <box id="tug" kind="vehicle" x="-40" y="30" heading-deg="10" length="3" width="1.6"
         height="1.8"/>
    <path id="walker" kind="person" radius="0.3" height="1.8" speed="1.2" trigger-radius="6">
      <waypoint x="-20" y="-4"/><waypoint x="-20" y="6"/>
    </path>
  </obstacles>
  <faults>
    <laser-dropout laser="front" at="10" duration="2"/>
    <camera-freeze camera="front-left" at="20" duration="5"/>
  </faults>"""


def test_good_scenario_loads(tmp_path):
    scenario = load_scenario(scenario_file(tmp_path, GOOD))
    assert scenario.mission.id == "a320-preflight"
    assert isinstance(scenario.obstacles[1], PathMover)
    assert [f.kind for f in scenario.faults] == [FaultKind.LASER_DROPOUT, FaultKind.CAMERA_FREEZE]
    nominal, true = scenario.mission.nominal_placement(), scenario.true_placement()
    assert true.x - nominal.x == pytest.approx(0.5)
    assert scenario.start == scenario.mission.airport.station  # default start
    assert scenario.noise.pixel == 1.0 and scenario.noise.gps == 0.03  # defaults kept


# (what to replace in GOOD, by what, expected line, code, message part). Line 1 is the
# XML declaration, line 2 the <scenario> tag, so GOOD starts on line 3.
BROKEN = [
    ('laser="front"', 'laser="top"', 13, "unknown-reference", "laser 'top' is not a platform"),
    ('camera="front-left"', 'camera="front"', 14, "unknown-reference", "(known: front-left,"),
    ('id="walker"', 'id="tug"', 8, "duplicate-id", "duplicate obstacle id 'tug'"),
    ('<waypoint x="-20" y="6"/>', "", 8, "schema", "<path> is incomplete"),
    ('radius="0.3" height', "height", 8, "obstacle-shape", "either 'radius'"),
    ('x="-40" y="30"', 'x="-3.8" y="-17.7"', 6, "obstacle-overlap", "main-gear"),
    ('x="-40" y="30"', 'x="-60" y="10"', 6, "obstacle-overlap", "the robot's start"),
    ('dheading-deg="2"', 'dheading-deg="north"', 3, "schema", "'north' is not"),
    ('<noise pixel="1.0"/>', '<noise pixel="-1"/>', 4, "schema", "it must be between 0 and 20 px"),
    ('kind="vehicle"', 'kind="plane"', 6, "schema", "'plane' is not one of"),
    ("<faults>", '<faults><gps-loss at="5"/>', 12, "schema", "missing the required attribute"),
]


@pytest.mark.parametrize(
    ("old", "new", "line", "code", "message"),
    BROKEN,
    ids=[b[3] + "-" + str(i) for i, b in enumerate(BROKEN)],
)
def test_broken_scenario_reported_at_its_line(tmp_path, old, new, line, code, message):
    assert old in GOOD
    path = scenario_file(tmp_path, GOOD.replace(old, new, 1))
    problems = check_scenario(path)
    assert any(
        p.where.line == line and p.code == code and message in p.message for p in problems
    ), "\n".join(map(str, problems))
    assert all(p.where.file.endswith("test.xml") or "preflight" in p.where.file for p in problems)


def test_mission_path_may_not_leave_the_library(tmp_path):
    path = scenario_file(tmp_path)
    path.write_text(
        path.read_text().replace('mission="../preflight.xml"', 'mission="../../../x.xml"')
    )
    [problem] = check_scenario(path)
    assert problem.code == "mission-path" and problem.where.line == 2


def test_invalid_mission_problems_are_listed_with_its_file(tmp_path):
    path = scenario_file(tmp_path)
    mission = path.parent.parent / "preflight.xml"
    mission.write_text(mission.read_text().replace('r-es="0.6"', 'r-es="9"'))
    problems = check_scenario(path)
    codes = {(p.code, p.where.file.endswith("preflight.xml")) for p in problems}
    assert ("safety-radii", True) in codes and ("mission-invalid", False) in codes


def test_validate_cli_accepts_scenarios(tmp_path, capsys):
    good = scenario_file(tmp_path, GOOD)
    bad = scenario_file(tmp_path, GOOD.replace('laser="front"', 'laser="top"'), name="bad.xml")
    assert main(["validate", str(good)]) == 0
    assert main(["validate", str(good), str(bad)]) == 2
    out = capsys.readouterr().out
    assert "scenario 't'" in out and "laser 'top'" in out
