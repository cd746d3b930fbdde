"""The loader against a corpus of broken files: every mistake at the right place.

``tests/corpus/library`` is a small mission library: ``base/`` holds a valid aircraft and
mission, ``broken/`` holds copies of them with one mistake each (or files that are not
walkaround XML at all). Every file in ``broken/`` has a row in :data:`CASES` giving the
line (and column, where meaningful) where the problem must be reported, its code and a
piece of its message. Line and column numbers were read off the files by hand: when you
edit a corpus file, update its row.

The XXE files hold ``@SECRET_URL@``; the tests substitute a ``file://`` URL to a secret
they create in ``tmp_path`` and check the secret never reaches the user.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest
from lxml import etree

from executive.cli import main
from executive.core.loader import check_file, load_aircraft, load_mission
from executive.core.model import (
    CameraKind,
    Circle,
    Frame,
    InspectionMethod,
    Polygon,
    ServoMethod,
    TurnMode,
    ZoneKind,
)
from executive.core.problems import InvalidInputError, Problem
from sim2d.scenario import check_scenario, load_scenario

LIBRARY = Path(__file__).parent / "corpus" / "library"
BASE = LIBRARY / "base"
BROKEN = LIBRARY / "broken"
SECRET_PLACEHOLDER = "@SECRET_URL@"


@dataclass(frozen=True)
class Case:
    """One broken file and the problem it must produce."""

    file: str
    line: int
    column: int | None  # None: not meaningful for this problem (e.g. libxml2's own)
    code: str
    message: str  # a substring of the message
    count: int = 1  # problems in total (all files)


CASES: list[Case] = [
    # -- not XML, or not ours ---------------------------------------------------------------
    Case("empty.xml", 1, 1, "empty", "file is empty"),
    Case("whitespace-only.xml", 1, 1, "empty", "file is empty"),
    Case("binary-garbage.xml", 1, 1, "xml-syntax", "not an XML document"),
    # libxml2 notices the unclosed <inspect> (line 43) at the next end tag and cascades
    Case("mission-unclosed-tag.xml", 44, None, "xml-syntax", "inspect line 43", count=3),
    Case("mission-mixed-garbage.xml", 61, 1, "xml-syntax", "Extra content at the end"),
    Case("mission-wrong-namespace.xml", 2, 1, "wrong-root", "'urn:walkaround:mission:2'"),
    Case("mission-no-namespace.xml", 2, 1, "wrong-root", "<mission> with no namespace"),
    Case("mission-wrong-root.xml", 2, 1, "wrong-root", "unknown document <scenario>"),
    # -- hostile XML: refused at the DOCTYPE, before anything expands -------------------------
    Case("mission-doctype.xml", 2, 1, "doctype", "DOCTYPE declarations are not allowed"),
    Case("mission-xxe.xml", 2, 1, "doctype", "DOCTYPE declarations are not allowed"),
    Case("mission-xxe-parameter-entity.xml", 2, 1, "doctype", "DOCTYPE declarations"),
    Case("mission-billion-laughs.xml", 2, 1, "doctype", "entity-expansion attacks"),
    Case(
        "mission-too-deep.xml",
        4,
        None,
        "too-deep",
        "nested more than 32 levels deep",
    ),
    # -- schema ---------------------------------------------------------------------------------
    Case(
        "mission-unknown-element.xml",
        48,
        7,
        "schema",
        "<inspekt> is not expected here; expected <inspect>",
    ),
    Case("mission-unknown-attribute.xml", 46, 70, "schema", "'dwel': unknown attribute"),
    Case(
        "mission-missing-attribute.xml",
        38,
        5,
        "schema",
        "<handover> is missing the required attribute 'heading-deg'",
    ),
    Case("mission-missing-element.xml", 19, 3, "schema", "expected <safety>"),
    Case(
        "mission-elements-out-of-order.xml",
        19,
        3,
        "schema",
        "<navigation> is not expected here; expected <safety>",
    ),
    Case("mission-non-numeric.xml", 20, 57, "schema", "'0,15' is not a number"),
    Case("mission-nan.xml", 23, 14, "schema", "'NaN' is not a finite number"),
    Case("aircraft-inf.xml", 38, 53, "schema", "'INF' is not a finite number"),
    Case(
        "aircraft-negative-radius.xml",
        15,
        41,
        "schema",
        "'-1.1' is out of range; it must be between 0.01 and 50 m",
    ),
    Case(
        "mission-angle-out-of-range.xml",
        54,
        62,
        "schema",
        "'heading-deg': '450' is out of range; it must be between -360 and 360 deg",
    ),
    # same mistake in a UTF-16 file: lines and columns count characters, not bytes
    Case("mission-utf16.xml", 54, 62, "schema", "<checkpoint> attribute 'heading-deg'"),
    Case("mission-bad-enum.xml", 25, 26, "schema", "'refueling' is not one of: refuelling,"),
    # -- ids and references ---------------------------------------------------------------------
    Case(
        "mission-duplicate-checkpoint.xml",
        50,
        17,
        "duplicate-id",
        "duplicate checkpoint id 'CP02' (first defined at line 45)",
    ),
    Case(
        "mission-duplicate-waypoint.xml",
        57,
        15,
        "duplicate-id",
        "duplicate waypoint id 'wp-2' (first defined at line 37)",
    ),
    Case(
        "mission-duplicate-inspect.xml",
        48,
        16,
        "duplicate-id",
        "checkpoint 'CP02' inspects item 'static-ports-left-clear' twice (first at line 47)",
    ),
    Case(
        "aircraft-duplicate-feature.xml",
        38,
        14,
        "duplicate-id",
        "duplicate feature id 'pitot-left' (first defined at line 35)",
    ),
    Case(
        "aircraft-item-unknown-feature.xml",
        50,
        32,
        "unknown-reference",
        "refers to feature 'pitot-lft', which is not defined (did you mean 'pitot-left'?)",
    ),
    Case(
        "mission-unknown-item.xml",
        43,
        16,
        "unknown-reference",
        "item 'nose-gear-tires' is not an inspection item of the aircraft "
        "(did you mean 'nose-gear-tyres'?)",
    ),
    Case(
        "mission-unknown-target.xml",
        51,
        30,
        "unknown-reference",
        "target 'eng2-inlet' is not a feature of the aircraft",
    ),
    Case(
        "mission-unknown-camera.xml",
        51,
        17,
        "unknown-reference",
        "camera 'pan-tilt' is not a platform camera",
    ),
    Case(
        "mission-target-without-camera.xml",
        42,
        17,
        "target-without-camera",
        "checkpoint 'CP01': a servo target needs a camera",
    ),
    Case(
        "mission-aircraft-type-mismatch.xml",
        3,
        10,
        "aircraft-type",
        "'A321-200' does not match the aircraft file's type 'A320-200'",
    ),
    # -- values that must agree -------------------------------------------------------------------
    Case(
        "mission-res-above-roa.xml",
        19,
        11,
        "safety-radii",
        "r-es (3 m) must be smaller than r-oa-trigger (2.5 m)",
    ),
    Case(
        "mission-res-equal-roa.xml",
        19,
        11,
        "safety-radii",
        "r-es (2.5 m) must be smaller than r-oa-trigger (2.5 m)",
    ),
    Case(
        "mission-cruise-too-fast.xml",
        20,
        15,
        "speed-limit",
        "cruise-speed 2.5 m/s exceeds the platform's max-speed 2 m/s",
    ),
    Case(
        "mission-waypoint-too-fast.xml",
        37,
        57,
        "speed-limit",
        "waypoint 'wp-2': speed 3 m/s exceeds the platform's max-speed 2 m/s",
    ),
    Case(
        "mission-pan-limits-order.xml",
        14,
        13,
        "limits-order",
        "camera 'ptz': pan-min-deg must be smaller than pan-max-deg",
    ),
    Case(
        "mission-stereo-without-baseline.xml",
        7,
        5,
        "missing",
        "stereo camera 'front' needs a 'baseline'",
    ),
    Case(
        "mission-image-larger-than-sensor.xml",
        9,
        13,
        "image-size",
        "output image (8000x600) is larger than the sensor (1384x1032)",
    ),
    # -- aircraft geometry -------------------------------------------------------------------------
    Case(
        "mission-zone-self-intersecting.xml",
        26,
        7,
        "invalid-polygon",
        "polygon 'refuel-rh': not a valid simple polygon: its edges cross each other at (18, -10)",
    ),
    Case(
        "aircraft-polygon-collinear.xml",
        11,
        5,
        "invalid-polygon",
        "polygon 'main-gear-right': the polygon has no area: its points are all on one line",
    ),
    Case(
        "aircraft-point-z-and-h.xml",
        36,
        7,
        "point-height",
        "feature 'pitot-left': a point needs exactly one of 'z' (in F, down) or 'h' "
        "(height above the ground), not both",
    ),
    Case(
        "aircraft-point-no-height.xml",
        36,
        7,
        "point-height",
        "feature 'pitot-left': a point needs exactly one of 'z'",
    ),
    Case("aircraft-zero-normal.xml", 43, 7, "zero-normal", "feature 'eng1-inlet': the normal"),
    # -- where the robot stands -----------------------------------------------------------------
    Case(
        "mission-checkpoint-in-footprint.xml",
        54,
        5,
        "clearance",
        "checkpoint 'CP04' is inside the aircraft footprint 'main-gear-left'",
    ),
    Case(
        "mission-checkpoint-too-close.xml",
        54,
        5,
        "clearance",
        "checkpoint 'CP04' is 0.30 m from the aircraft footprint 'main-gear-left'; "
        "the robot needs 1.46 m to turn on the spot without an emergency stop",
    ),
    Case(
        "mission-checkpoint-in-zone.xml",
        54,
        5,
        "clearance",
        "checkpoint 'CP04' is inside forbidden zone 'refuel-rh' (refuelling)",
    ),
    Case(
        "mission-waypoint-in-airport-zone.xml",
        37,
        5,
        "clearance",
        "waypoint 'wp-2' is inside forbidden zone 'gpu' (equipment)",
    ),
    # inside both the engine footprint and the engine-danger zone: two problems
    Case(
        "mission-aircraft-frame-waypoint-in-footprint.xml",
        58,
        5,
        "clearance",
        "waypoint 'wp-ret-2' is inside the aircraft footprint 'eng1'",
        count=2,
    ),
    Case(
        "mission-handover-in-footprint.xml",
        38,
        5,
        "clearance",
        "the handover point is inside the aircraft footprint 'nose-gear'",
    ),
    # -- what the cameras can see -----------------------------------------------------------------
    # the item on the same feature cannot be inspected either: two problems
    Case(
        "mission-target-out-of-range.xml",
        42,
        32,
        "target-not-visible",
        "servo target 'nose-gear-leg' is 10.5 m from camera 'front', beyond its "
        "detection range of 10 m",
        count=2,
    ),
    Case(
        "mission-target-outside-pan.xml",
        42,
        32,
        "target-not-visible",
        "on camera 'front', outside its limits -90..90 deg",
    ),
    Case(
        "mission-item-too-far.xml",
        52,
        16,
        "item-not-visible",
        "item 'pitot-left-scan' cannot be inspected from here",
    ),
    # -- the aircraft file reference ------------------------------------------------------------
    Case(
        "mission-aircraft-path-escapes.xml",
        2,
        65,
        "aircraft-path",
        "leads outside the mission library root",
    ),
    Case(
        "mission-aircraft-path-absolute.xml",
        2,
        65,
        "aircraft-path",
        "aircraft path '/etc/passwd' must be relative to the mission file",
    ),
    Case(
        "mission-aircraft-missing.xml",
        2,
        65,
        "aircraft-path",
        "aircraft file '../base/aircraft-a321.xml' does not exist",
    ),
    Case("mission-aircraft-path-directory.xml", 2, 65, "aircraft-path", "'../base'"),
    # the aircraft file's own problem is listed too (see test_invalid_aircraft_...)
    Case(
        "mission-aircraft-invalid.xml",
        2,
        65,
        "aircraft-invalid",
        "aircraft file 'aircraft-negative-radius.xml' has 1 problem(s)",
        count=2,
    ),
    Case(
        "mission-aircraft-path-is-mission.xml",
        2,
        65,
        "aircraft-invalid",
        "aircraft file '../base/mission.xml' has 1 problem(s)",
        count=2,
    ),
    # -- foreign namespaces: reported where they are, never an XPath crash (issue 12) ------------
    Case("mission-foreign-element.xml", 19, 3, "foreign-namespace", "<x:hint> is an element in"),
    Case("mission-foreign-attribute.xml", 19, 43, "foreign-namespace", "attribute 'x:margin'"),
    Case("mission-foreign-root-attribute.xml", 4, 42, "foreign-namespace", "'x:owner' is in"),
    Case("mission-xinclude.xml", 23, 5, "foreign-namespace", "<xi:include> is an XInclude"),
    Case("mission-xml-lang.xml", 54, 17, "foreign-namespace", "'xml:lang' is in namespace"),
    Case("aircraft-foreign-element.xml", 18, 3, "foreign-namespace", "<x:extra> is an element"),
    Case("aircraft-foreign-attribute.xml", 16, 45, "foreign-namespace", "'x:colour' is in"),
    Case("scenario-foreign-element.xml", 25, 3, "foreign-namespace", "<x:more>", count=2),
    Case("scenario-foreign-attribute.xml", 15, 45, "foreign-namespace", "'x:mass' is in"),
    Case("scenario-xinclude.xml", 12, 3, "foreign-namespace", "<xi:include> is an XInclude"),
    # -- references to other files ---------------------------------------------------------------
    Case(
        "mission-aircraft-path-10000-chars.xml",
        2,
        65,
        "schema",
        "is 10002 characters long; it must be at most 1024",
    ),
    Case(
        "scenario-mission-path-10000-chars.xml",
        2,
        63,
        "schema",
        "is 9998 characters long; it must be at most 1024",
    ),
    Case("scenario-mission-missing.xml", 2, 63, "mission-path", "does not exist"),
    # -- physical ranges: the range and its unit in the message (issue 12) ------------------------
    Case("mission-max-speed-1e308.xml", 5, 38, "schema", "between 0.01 and 10 m/s"),
    Case("mission-laser-resolution-1e-9.xml", 17, 12, "schema", "between 0.05 and 10 deg"),
    Case("mission-image-height-5000-digits.xml", 9, 34, "schema", "(5000 characters) is out"),
    Case("mission-pixel-um-denormal.xml", 8, 46, "schema", "'1e-320' is out of range"),
    Case("mission-camera-rate-inf.xml", 15, 50, "schema", "'INF' is not a finite number"),
    Case("mission-laser-rate-zero.xml", 17, 45, "schema", "between 1 and 100 Hz"),
    Case("mission-position-tolerance-tiny.xml", 20, 57, "schema", "between 0.005 and 10 m"),
    Case("mission-station-1e308.xml", 23, 14, "schema", "between -10000 and 10000 m"),
    Case("mission-dwell-1e9.xml", 42, 55, "schema", "between 0 and 3600 s"),
    Case("aircraft-origin-height-1e6.xml", 2, 61, "schema", "between 0.1 and 30 m"),
    Case("aircraft-point-1e308.xml", 8, 14, "schema", "between -100 and 100 m"),
    Case(
        "aircraft-polygon-repeated-point.xml",
        7,
        5,
        "invalid-polygon",
        "polygon 'main-gear-left': point 4 repeats point 3 at (18.2, 4.5)",
    ),
    Case("aircraft-footprint-too-wide.xml", 5, 3, "footprint-extent", "spans 13.6 m x 92.9 m"),
    Case("scenario-group-million.xml", 20, 48, "schema", "'1000000' is out of range"),
    Case("scenario-physics-rate-1e9.xml", 7, 12, "schema", "between 50 and 1000 Hz"),
    Case("scenario-physics-rate-1e-3.xml", 7, 12, "schema", "'1e-3' is out of range"),
    Case("scenario-parking-offset-1e308.xml", 5, 19, "schema", "between -50 and 50 m"),
    Case("scenario-seed-5000-digits.xml", 2, 93, "schema", "between 0 and 4294967295"),
    Case("scenario-duration-nan.xml", 3, 11, "schema", "'NaN' is not a finite number"),
    Case("scenario-slip-total.xml", 10, 9, "schema", "between 0 and 0.9"),
    Case("scenario-gps-noise-1e6.xml", 9, 27, "schema", "between 0 and 10 m"),
    Case("scenario-chaser-speed-1e6.xml", 23, 13, "schema", "between 0.01 and 20 m/s"),
    Case("scenario-fault-at-1e300.xml", 28, 15, "schema", "between 0 and 86400 s"),
    Case("scenario-too-many-movers.xml", 12, 3, "too-many-obstacles", "605 moving obstacles"),
    # -- physics: stopping within r_ES, nothing over the start or the station --------------------
    Case(
        "mission-r-es-cannot-stop.xml",
        19,
        11,
        "stopping-distance",
        "r-es 0.3 m is shorter than the 0.60 m the robot needs to stop from cruise-speed 1 m/s "
        "with max-acceleration 1 m/s^2",
    ),
    Case(
        "mission-r-es-cannot-stop-waypoint.xml",
        19,
        11,
        "stopping-distance",
        "from waypoint 'wp-2' speed 1.9 m/s with max-acceleration 1 m/s^2",
    ),
    Case(
        "mission-parking-over-station.xml",
        23,
        5,
        "clearance",
        "the charging station is inside the aircraft footprint 'nose-gear'",
    ),
    Case(
        "scenario-aircraft-over-start.xml",
        5,
        3,
        "aircraft-overlap",
        "the aircraft footprint 'nose-gear' (at the true parking pose, nominal + parking "
        "offset) overlaps the robot's start",
    ),
    Case("scenario-obstacle-over-station.xml", 15, 5, "obstacle-overlap", "the charging station"),
    Case("scenario-walker-over-start.xml", 16, 5, "obstacle-overlap", "'walker' overlaps the"),
]


def _params() -> list:
    return [pytest.param(case, id=case.file.removesuffix(".xml")) for case in CASES]


def _same_file(problem: Problem, path: Path) -> bool:
    return Path(problem.where.file).resolve() == path.resolve()


def _listing(problems: list[Problem] | tuple[Problem, ...]) -> str:
    return "\n".join(str(p) for p in problems) or "(no problems)"


def _check(path: Path) -> list[Problem]:
    """Every problem of a corpus file, with the checker its name calls for."""
    if path.name.startswith("scenario"):
        return check_scenario(path)
    return check_file(path)


def _loader_for(path: Path):
    """The loader for a corpus file, from its name (files of neither kind: both)."""
    if path.name.startswith("scenario"):
        return [load_scenario]
    if path.name.startswith("aircraft"):
        return [load_aircraft]
    if path.name.startswith("mission"):
        return [load_mission]
    return [load_aircraft, load_mission]


# -- the valid library ------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["aircraft.xml", "mission.xml"])
def test_base_files_are_valid(name):
    assert check_file(BASE / name) == []


def test_base_scenario_is_valid():
    assert check_scenario(BASE / "scenario.xml") == []
    scenario = load_scenario(BASE / "scenario.xml")
    assert (len(scenario.obstacles), len(scenario.faults), scenario.seed) == (5, 5, 7)


def test_base_aircraft_model():
    aircraft = load_aircraft(BASE / "aircraft.xml")
    assert aircraft.type == "A320-200"
    assert aircraft.origin_height == 3.5
    assert [s.id for s in aircraft.footprint] == [
        "nose-gear",
        "main-gear-left",
        "main-gear-right",
        "eng1",
        "eng2",
    ]
    assert [type(s) for s in aircraft.footprint] == [Circle, Polygon, Polygon, Circle, Circle]
    assert [p.id for p in aircraft.outline] == ["fuselage", "wing-left", "wing-right"]
    assert list(aircraft.features) == [
        "static-ports-left",
        "pitot-left",
        "nose-gear-leg",
        "eng1-inlet",
    ]
    ports = aircraft.features["static-ports-left"]
    assert [p.z for p in ports.points] == pytest.approx([1.3, 1.3])  # 3.5 - h 2.2
    assert aircraft.features["pitot-left"].points[0].z == 1.3  # given as z
    assert aircraft.features["pitot-left"].detection_range == 5.0  # "5e0"
    assert aircraft.features["nose-gear-leg"].servo is ServoMethod.PBVS
    assert {i: aircraft.items[i].feature for i in aircraft.items} == {
        "static-ports-left-clear": "static-ports-left",
        "pitot-left-scan": "pitot-left",
        "nose-gear-tyres": "nose-gear-leg",
        "eng1-inlet-clear": "eng1-inlet",
    }
    assert aircraft.items["pitot-left-scan"].method is InspectionMethod.SCAN_3D
    assert aircraft.items["static-ports-left-clear"].description == (
        "Static ports clear, covers removed"
    )
    assert aircraft.features["eng1-inlet"].where.line == 41


def test_base_mission_model():
    mission = load_mission(BASE / "mission.xml")
    assert mission.id == "corpus-preflight"
    assert mission.aircraft.type == "A320-200"
    assert [c.id for c in mission.checkpoints] == ["CP01", "CP02", "CP03", "CP04"]
    assert [c.where.line for c in mission.checkpoints] == [41, 45, 50, 54]
    cp1, cp2, cp3, cp4 = mission.checkpoints
    assert (cp1.camera, cp1.target, cp1.servo, cp1.dwell) == ("front", "nose-gear-leg", None, 1)
    assert cp1.items == ("nose-gear-tyres",)
    assert cp2.servo is ServoMethod.IBVS
    assert cp2.items == ("static-ports-left-clear", "pitot-left-scan")
    assert cp2.pose.theta == pytest.approx(-math.pi / 2)
    assert (cp3.camera, cp3.target) == ("ptz", "eng1-inlet")
    assert (cp4.name, cp4.items, cp4.camera, cp4.target, cp4.dwell) == (
        "LH main gear",
        (),
        None,
        None,
        0.0,
    )
    assert sum(len(c.items) for c in mission.checkpoints) == 4

    zones = mission.airport.zones
    assert [(z.id, z.kind, z.frame, type(z.shape)) for z in zones] == [
        ("refuel-rh", ZoneKind.REFUELLING, Frame.AIRCRAFT, Polygon),
        ("eng1-danger", ZoneKind.ENGINE_DANGER, Frame.AIRCRAFT, Circle),
        ("gpu", ZoneKind.EQUIPMENT, Frame.AIRPORT, Circle),
    ]
    assert [w.id for w in mission.approach] == ["wp-apron-edge", "wp-2"]
    assert mission.approach[1].speed == 1.0
    assert mission.approach[1].heading == pytest.approx(math.radians(30))
    assert (mission.handover.x, mission.handover.y) == (-12, -4)
    assert mission.handover.heading == pytest.approx(math.radians(45))
    assert [(w.id, w.frame) for w in mission.return_route] == [
        ("wp-ret-1", Frame.AIRPORT),
        ("wp-ret-2", Frame.AIRCRAFT),
    ]

    platform = mission.platform
    assert platform.half_width == 0.5
    assert {c: platform.cameras[c].kind for c in platform.cameras} == {
        "front": CameraKind.STEREO,
        "ptz": CameraKind.PTZ,
    }
    assert platform.cameras["front"].pan_limits == pytest.approx((-math.pi / 2, math.pi / 2))
    assert platform.cameras["ptz"].image_width_px == 1920  # defaults to width-px
    assert platform.lasers["front"].beam_count == 1081
    assert (mission.safety.r_es, mission.safety.r_oa_trigger) == (0.6, 2.5)
    assert mission.navigation.turn_mode is TurnMode.ALIGN_FIRST


# -- the broken corpus ------------------------------------------------------------------------
def test_every_broken_file_has_an_expectation():
    names = [c.file for c in CASES]
    assert len(names) == len(set(names)), "a file appears twice in CASES"
    on_disk = {p.name for p in BROKEN.iterdir()}
    assert on_disk - set(names) == set(), "corpus files without a row in CASES"
    assert set(names) - on_disk == set(), "rows in CASES without a corpus file"
    assert len(on_disk) >= 30


@pytest.mark.parametrize("case", _params())
def test_problem_reported_at_its_place(case: Case):
    path = BROKEN / case.file
    problems = _check(path)  # must not raise
    here = [p for p in problems if p.code == case.code and _same_file(p, path)]
    assert here, f"no '{case.code}' problem in {case.file}:\n{_listing(problems)}"
    at_line = [p for p in here if p.where.line == case.line]
    assert at_line, f"'{case.code}' not at line {case.line}:\n{_listing(problems)}"
    if case.column is not None:
        assert [p.where.column for p in at_line] == [case.column] * len(at_line)
    assert any(case.message in p.message for p in at_line), _listing(problems)
    for p in problems:
        assert "Traceback" not in p.message
        assert "{urn:" not in p.message  # namespaces are stripped from schema messages


@pytest.mark.parametrize("case", _params())
def test_problem_count(case: Case):
    problems = _check(BROKEN / case.file)
    assert len(problems) == case.count, _listing(problems)


@pytest.mark.parametrize("case", [pytest.param(c, id=c.file.removesuffix(".xml")) for c in CASES])
def test_loaders_raise_and_build_nothing(case: Case):
    path = BROKEN / case.file
    for loader in _loader_for(path):
        with pytest.raises(InvalidInputError) as info:
            loader(path)
        assert info.value.problems
        if loader in (load_mission, load_scenario) or case.file.startswith("aircraft"):
            assert case.code in {p.code for p in info.value.problems}, _listing(info.value.problems)


def test_invalid_aircraft_is_reported_in_both_files():
    mission = BROKEN / "mission-aircraft-invalid.xml"
    aircraft = BROKEN / "aircraft-negative-radius.xml"
    problems = check_file(mission)
    in_mission = [p for p in problems if _same_file(p, mission)]
    in_aircraft = [p for p in problems if _same_file(p, aircraft)]
    assert [(p.where.line, p.where.column, p.code) for p in in_mission] == [
        (2, 65, "aircraft-invalid")
    ]
    assert [(p.where.line, p.where.column, p.code) for p in in_aircraft] == [(15, 41, "schema")]
    assert "radius" in in_aircraft[0].message
    assert set(check_file(aircraft)) == set(in_aircraft)


@pytest.mark.parametrize("what", ["missing", "directory"])
def test_check_file_never_raises_on_odd_paths(tmp_path, what):
    path = tmp_path / "nope.xml" if what == "missing" else tmp_path
    problems = check_file(path)
    assert [p.code for p in problems] == ["not-found" if what == "missing" else "not-a-file"]


# -- the command line ---------------------------------------------------------------------------
def test_cli_valid_files_exit_0(capsys):
    assert main(["validate", str(BASE / "aircraft.xml"), str(BASE / "mission.xml")]) == 0
    out = capsys.readouterr().out
    assert "4 checkpoints, 4 item inspections, 3 forbidden zones" in out
    assert "2 valid, 0 invalid" in out


def test_cli_broken_file_exits_2(capsys):
    path = BROKEN / "mission-duplicate-checkpoint.xml"
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr().out
    assert f"FAIL  {path}: 1 problem(s)" in out
    assert ":50:17: error: duplicate checkpoint id 'CP02'" in out
    assert '<checkpoint id="CP02" name="Engine 1 inlet"' in out  # the offending line


def test_cli_valid_and_broken_together_exit_2(capsys):
    files = [str(BASE / "mission.xml"), str(BROKEN / "mission-res-equal-roa.xml")]
    assert main(["validate", *files]) == 2
    assert "1 valid, 1 invalid" in capsys.readouterr().out


def test_cli_whole_corpus_no_traceback(capsys):
    files = sorted(str(p) for p in BROKEN.iterdir())
    assert main(["validate", *files]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    assert f"0 valid, {len(files)} invalid" in captured.out


def test_cli_json_lists_every_expected_problem(capsys):
    files = [BROKEN / c.file for c in CASES]
    assert main(["validate", "--json", *map(str, files)]) == 2
    report = json.loads(capsys.readouterr().out)
    assert report["valid"] is False
    assert [Path(f["file"]).name for f in report["files"]] == [c.file for c in CASES]
    for case, entry in zip(CASES, report["files"], strict=True):
        assert entry["valid"] is False
        assert entry["summary"] is None
        assert entry["problems"], case.file
        for problem in entry["problems"]:
            assert set(problem) == {"file", "line", "column", "code", "message"}
            assert isinstance(problem["line"], int) and isinstance(problem["column"], int)
        found = {
            (p["line"], p["code"])
            for p in entry["problems"]
            if Path(p["file"]).resolve() == (BROKEN / case.file).resolve()
        }
        assert (case.line, case.code) in found, (case.file, found)


def test_cli_json_valid_file(capsys):
    assert main(["validate", "--json", str(BASE / "mission.xml")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report == {
        "valid": True,
        "files": [
            {
                "file": str(BASE / "mission.xml"),
                "valid": True,
                "summary": "mission 'corpus-preflight' for A320-200: 4 checkpoints, "
                "4 item inspections, 3 forbidden zones",
                "problems": [],
            }
        ],
    }


# -- hostile XML ------------------------------------------------------------------------------
def _hostile_copy(tmp_path: Path, template: str, encoding: str, url: str) -> Path:
    """A corpus file with the secret URL filled in, in ``encoding``, inside a library."""
    text = (BROKEN / template).read_text(encoding="utf-8").replace(SECRET_PLACEHOLDER, url)
    text = text.replace('encoding="UTF-8"', f'encoding="{encoding}"')
    text = text.replace('aircraft="../base/aircraft.xml"', 'aircraft="aircraft.xml"')
    folder = tmp_path / "library" / "a320"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "aircraft.xml").write_bytes((BASE / "aircraft.xml").read_bytes())
    path = folder / f"{encoding.lower()}-{template}"
    path.write_bytes(text.encode(encoding.lower()))
    return path


@pytest.fixture
def secret(tmp_path) -> tuple[str, Path]:
    marker = "TOP-SECRET-" + uuid.uuid4().hex
    path = tmp_path / "secret.txt"
    path.write_text(marker + "\n", encoding="utf-8")
    return marker, path


XXE_TEMPLATES = ["mission-xxe.xml", "mission-xxe-parameter-entity.xml"]
ENCODINGS = ["UTF-8", "UTF-16"]


def test_xxe_template_is_a_real_attack(tmp_path, secret):
    """Sanity check of the corpus: a careless parser does leak the secret."""
    marker, secret_path = secret
    path = _hostile_copy(tmp_path, "mission-xxe.xml", "UTF-8", secret_path.as_uri())
    careless = etree.XMLParser(resolve_entities=True, load_dtd=True, no_network=True)
    root = etree.fromstring(path.read_bytes(), careless)
    assert marker in etree.tostring(root, encoding="unicode")


@pytest.mark.parametrize("encoding", ENCODINGS)
@pytest.mark.parametrize("template", XXE_TEMPLATES)
def test_xxe_secret_never_leaks(tmp_path, secret, capsys, template, encoding):
    marker, secret_path = secret
    path = _hostile_copy(tmp_path, template, encoding, secret_path.as_uri())

    problems = check_file(path)
    assert problems
    assert marker not in repr(problems)
    with pytest.raises(InvalidInputError) as info:
        load_mission(path)
    assert marker not in repr(info.value.problems) and marker not in str(info.value)

    assert main(["validate", str(path)]) == 2
    captured = capsys.readouterr()
    assert marker not in captured.out + captured.err
    assert main(["validate", "--json", str(path)]) == 2
    captured = capsys.readouterr()
    assert marker not in captured.out + captured.err
    report = json.loads(captured.out)
    assert report["files"][0]["problems"]

    # the installed command, in its own process
    for extra in ([], ["--json"]):
        run = subprocess.run(
            [sys.executable, "-m", "executive.cli", "validate", *extra, str(path)],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert run.returncode == 2, run.stderr
        assert marker not in run.stdout + run.stderr
        assert "Traceback" not in run.stderr


@pytest.mark.parametrize(
    ("template", "encoding"),
    [
        pytest.param(t, e, id=f"{t.removesuffix('.xml')}-{e}")
        for t in [*XXE_TEMPLATES, "mission-billion-laughs.xml"]
        for e in ENCODINGS
    ],
)
def test_doctype_refused_before_the_parser_uses_it(tmp_path, secret, template, encoding):
    _, secret_path = secret
    path = _hostile_copy(tmp_path, template, encoding, secret_path.as_uri())
    problems = check_file(path)
    assert [p.code for p in problems] == ["doctype"], _listing(problems)


@pytest.mark.skipif(
    not hasattr(os, "mkfifo"),
    reason="the proof that no external entity is opened reads through a named pipe "
    "(os.mkfifo), which this OS lacks",
)
@pytest.mark.parametrize(
    "encoding",
    [
        "UTF-8",
        # Regression: a UTF-16 file once slipped past a byte scan for '<!DOCTYPE' and
        # libxml2 opened the external parameter entity (file:///dev/zero hung for ever).
        "UTF-16",
    ],
)
def test_external_parameter_entity_is_never_opened(tmp_path, encoding):
    """The loader must not even open a file named by an external entity.

    The entity names a FIFO: opening it for reading blocks until a writer comes, so the
    test sees whether the parser tried (and then lets it go with an empty file).
    """
    fifo = tmp_path / "entity.fifo"
    os.mkfifo(fifo)
    path = _hostile_copy(tmp_path, "mission-xxe-parameter-entity.xml", encoding, fifo.as_uri())
    code = "from executive.core.loader import check_file; import sys; check_file(sys.argv[1])"
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)])
    opens = 0
    deadline = time.monotonic() + 60
    try:
        # libxml2 may open the file more than once: serve every reader until the end
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # succeeds iff a reader waits
            except OSError:
                time.sleep(0.02)
                continue
            opens += 1
            os.close(fd)  # end of file for the reader: let it go on
            time.sleep(0.02)
        assert proc.poll() is not None, "check_file did not finish within 60 s"
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    opened = opens > 0
    assert not opened, "the parser opened the file named by the external entity"
