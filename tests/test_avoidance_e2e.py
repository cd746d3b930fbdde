"""Issue 6 (in progress): the spiral obstacle avoidance drives the simulated robot.

Opt-in (``CompileOptions.avoidance``) until the campaign of issue 6 is run; this test
shows the wiring works in sim2d on the thesis's 40 m track with its two static obstacles.
"""

import pytest

from executive.dryrun import dry_run
from executive.report import metrics
from tests.sim2d_helpers import make_scenario

pytestmark = pytest.mark.slow

STATIC = (
    '<obstacles><box id="a-parked-car" kind="vehicle" x="12" y="0.4" heading-deg="0"'
    ' length="4.2" width="1.8" height="1.5"/>'
    '<circle id="b-bin" kind="equipment" x="28" y="-0.3" radius="0.6" height="1.0"/>'
    "</obstacles>"
)


def test_spiral_avoidance_around_the_two_static_obstacles_of_the_40_m_run(tmp_path):
    scenario = make_scenario(tmp_path, STATIC, mission_type="track", mission="straight-run.xml")
    run = dry_run(scenario, avoidance=True)
    report = metrics(run)
    assert run.result.outcome == "completed", run.result.reason
    assert not report["collisions"] and not report["geofence_breaches"]
    assert report["estops"] == 0
    assert report["min_clearance"] > 1.0
    assert report["checkpoints_reached"] == 1
    assert report["max_position_error"] < 0.15
    switches = [e for e in run.result.events if e.kind == "controller"]
    engaged = [e for e in switches if e.detail["to"].startswith("spiral")]
    released = [e for e in switches if e.detail["from"].startswith("spiral")]
    assert len(engaged) == 4  # car and bin, out and back: no re-trigger loop
    assert all("r_OA" in e.detail["reason"] for e in engaged)
    assert len(released) == 4
