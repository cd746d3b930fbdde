"""The taught-route file (schemas/route.xsd, executive.core.taught_route) and a mission's
``<taught-route>`` approach (issue 17, seed 002 §2.3): loaded, checked with file:line,
refused by ``walkaround validate`` with exit 2.

The mosaic here is a small hand-made one (a few landmarks, one keypoint each): only its
ids and ceiling height matter to the route's checks; real mosaics are in
test_teach_repeat_e2e.py.
"""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from behaviours.controllers.repeat import FollowTaughtRoute, RouteProgressing
from executive.cli import main
from executive.compiler import compile_mission
from executive.core.frames import Pose2
from executive.core.loader import check_file, load_mission
from executive.core.model import KeyImage, TaughtRoute
from executive.core.mosaicfile import MosaicData, write_mosaic
from executive.core.problems import InvalidInputError
from executive.core.taught_route import check_route, load_route, route_xml
from tests.conftest import MISSIONS

IDS = ("L0", "L1", "L2", "L3")
KEYS = [  # (id, x, y, heading deg, landmarks): 4 m east, then a 5 deg turn, P at (2, 0)
    ("k0", -6.0, 0.0, 0.0, "L0 L1"),
    ("k1", -2.0, 0.0, 0.0, "L1 L2"),
    ("k2", 1.9, 0.1, 5.0, "L2 L3"),
]


def mosaic(path: Path, ids: tuple[str, ...] = IDS, height: float = 10.0) -> Path:
    n = len(ids)
    write_mosaic(
        path,
        MosaicData(
            ceiling_height=height,
            focal_px=381.0,
            cu=319.5,
            cv=239.5,
            camera_height=height - 0.6,
            robot_from_camera=Pose2(0.0, 0.0, math.pi / 2),
            image_size=(640, 480),
            config={},
            ids=ids,
            poses=np.array([(3.0 * k, 1.0, 0.0) for k in range(n)], dtype=np.float64),
            counts=np.ones(n, dtype=np.int64),
            points=np.zeros((n, 2)),
            descriptors=np.zeros((n, 32), dtype=np.uint8),
            created_in=np.arange(n, dtype=np.int64),
            origin_px=np.zeros((n, 2)),
        ),
    )
    return path


def route_text(keys=KEYS, speed: str = "0.5", height: str = "10", extra: str = "") -> str:
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<route xmlns="urn:walkaround:route:1" id="r" mosaic="../hangar.npz"',
        f'       ceiling-height="{height}" speed="{speed}"{extra}>',
    ]
    for kid, x, y, h, lms in keys:
        lines.append(f'  <key id="{kid}" x="{x}" y="{y}" heading-deg="{h}" landmarks="{lms}"/>')
    lines.append("</route>")
    return "\n".join(lines) + "\n"


@pytest.fixture
def lib(tmp_path: Path) -> Path:
    """A copy of the track mission folder with a mosaic and a routes/ folder."""
    root = tmp_path / "lib"
    shutil.copytree(MISSIONS / "track", root / "track")
    mosaic(root / "track" / "hangar.npz")
    (root / "track" / "routes").mkdir()
    return root


def write_route(lib: Path, text: str, name: str = "r.xml") -> Path:
    path = lib / "track" / "routes" / name
    path.write_text(text, encoding="utf-8")
    return path


def codes(problems) -> list[str]:
    return [p.code for p in problems]


def test_a_route_file_loads(lib):
    route = load_route(write_route(lib, route_text(extra=' settling-distance="2"')))
    assert [k.id for k in route.keys] == ["k0", "k1", "k2"]
    assert route.keys[2].pose_m.theta == pytest.approx(math.radians(5.0))
    assert route.keys[0].landmarks == frozenset({"L0", "L1"})
    assert route.speed == 0.5 and route.settling_distance == 2.0
    assert route.max_heading_change == pytest.approx(math.radians(10.0))
    assert route.mosaic == (lib / "track" / "hangar.npz").resolve()
    assert route.length == pytest.approx(4.0 + math.hypot(3.9, 0.1))


def test_route_xml_round_trips(lib):
    keys = tuple(
        KeyImage(kid, Pose2(x, y, math.radians(h + 180.0)), frozenset(lms.split()))
        for kid, x, y, h, lms in KEYS
    )  # taught backwards: facing west while going east
    route = TaughtRoute("r", Path("x"), 10.0, -0.4, 1.5, math.radians(12.0), keys)
    path = write_route(lib, route_xml(route, "../hangar.npz"))
    back = load_route(path)
    assert [(k.id, k.landmarks) for k in back.keys] == [(k.id, k.landmarks) for k in keys]
    for a, b in zip(back.keys, keys, strict=True):
        assert a.pose_m.x == pytest.approx(b.pose_m.x, abs=1e-5)
        assert math.cos(a.pose_m.theta - b.pose_m.theta) == pytest.approx(1.0)
    assert back.speed == -0.4 and back.max_heading_change == pytest.approx(math.radians(12.0))


@pytest.mark.parametrize(
    ("keys", "speed", "code", "line"),
    [
        ([*KEYS[:2], ("k1", 1.9, 0.1, 5.0, "L2")], "0.5", "duplicate-id", 6),
        ([KEYS[0], ("k1", -2.0, 0.0, 0.0, "L2 L3"), KEYS[2]], "0.5", "route-rule-1", 5),
        ([*KEYS[:2], ("k2", 1.9, 0.1, 15.0, "L2")], "0.5", "route-rule-2", 6),
        ([*KEYS[:2], ("k2", -4.0, 0.0, 0.0, "L2")], "0.5", "route-direction", 6),
        (KEYS, "-0.5", "route-direction", 5),
        (KEYS, "0", "route-speed", 3),  # the line of the attribute
        ([*KEYS[:2], ("k2", 1.9, 0.1, 5.0, "L2 L9")], "0.5", "route-landmark", 6),
        ([*KEYS[:2], ("k2", -2.0, 0.0, 0.0, "L2")], "0.5", "route-spacing", 6),
    ],
)
def test_a_route_breaking_a_rule_is_refused_at_its_line(lib, keys, speed, code, line):
    path = write_route(lib, route_text(keys, speed))
    problems = check_route(path)
    assert code in codes(problems), problems
    where = next(p for p in problems if p.code == code).where
    assert where.line == line and where.file.endswith("r.xml")


def test_the_mosaic_must_exist_be_valid_and_match_the_ceiling(lib):
    path = write_route(lib, route_text(height="12"))
    assert "route-ceiling" in codes(check_route(path))
    (lib / "track" / "hangar.npz").write_bytes(b"not an archive")
    problems = check_route(path)
    assert "mosaic-invalid" in codes(problems) and "mosaic-format" in codes(problems)
    (lib / "track" / "hangar.npz").unlink()
    assert "mosaic-path" in codes(check_route(path))
    outside = write_route(lib, route_text().replace("../hangar.npz", "../../../x.npz"))
    assert "mosaic-path" in codes(check_route(outside))


def test_the_schema_refuses_a_route_of_one_key(lib):
    path = write_route(lib, route_text(KEYS[:1]))
    assert codes(check_route(path)) == ["schema"] or "schema" in codes(check_route(path))


def mission_with_route(lib: Path, route: str = "routes/r.xml", handover: str = "") -> Path:
    text = (lib / "track" / "straight-run.xml").read_text(encoding="utf-8")
    text = text.replace("<approach>\n", f'<approach>\n    <taught-route file="{route}"/>\n', 1)
    if handover:
        text = text.replace('<handover x="2" y="0" heading-deg="0"/>', handover, 1)
    path = lib / "track" / "hangar.xml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_mission_approach_can_be_a_taught_route(lib):
    write_route(lib, route_text())
    mission = load_mission(mission_with_route(lib))
    assert mission.taught_route is not None and mission.approach == ()
    assert mission.taught_route.keys[-1].id == "k2"
    compiled = compile_mission(mission)
    assert [s.route.id for s in compiled.route_sessions] == ["r"]
    # the route's navigation has the guards of any: trap, e-stop, avoidance, then the law
    nav = next(n for n in compiled.root.iterate() if n.name == "navigate route r")
    trap, guards = nav.children
    assert isinstance(trap, RouteProgressing)
    names = [c.name for c in guards.children]
    assert names[0] == "e-stop route r" and isinstance(guards.children[-1], FollowTaughtRoute)
    assert {"dodge route r", "avoid route r", "replan route r"} <= set(names)
    approach = next(n for n in compiled.root.iterate() if n.name == "approach")
    order = [c.name for c in approach.children]
    assert order.index("navigate route r") < order.index("navigate P")


def test_a_taught_route_must_end_near_p_and_exist(lib):
    write_route(lib, route_text())
    far = mission_with_route(lib, handover='<handover x="5" y="0" heading-deg="0"/>')
    problems = check_file(far)
    assert "taught-route-end" in codes(problems)
    assert "ends 3.10 m from the handover point P" in str(problems)
    missing = mission_with_route(lib, route="routes/none.xml")
    assert "taught-route-path" in codes(check_file(missing))
    write_route(lib, route_text(speed="0"), "bad.xml")
    bad = mission_with_route(lib, route="routes/bad.xml")
    problems = check_file(bad)
    assert "taught-route-invalid" in codes(problems) and "route-speed" in codes(problems)
    with pytest.raises(InvalidInputError):
        load_mission(bad)


def test_waypoints_and_a_taught_route_are_exclusive(lib):
    write_route(lib, route_text())
    path = mission_with_route(lib)
    text = path.read_text(encoding="utf-8").replace(
        '<taught-route file="routes/r.xml"/>',
        '<waypoint id="w" x="1" y="0"/>\n    <taught-route file="routes/r.xml"/>',
    )
    path.write_text(text, encoding="utf-8")
    assert "schema" in codes(check_file(path))


def test_walkaround_validate_reports_routes(lib, capsys):
    good = write_route(lib, route_text())
    bad = write_route(lib, route_text(speed="0"), "bad.xml")
    assert main(["validate", str(good)]) == 0
    assert "taught route 'r': 3 key images" in capsys.readouterr().out
    assert main(["validate", "--json", str(bad)]) == 2
    report = json.loads(capsys.readouterr().out)
    assert report["files"][0]["problems"][0]["code"] == "route-speed"
    assert main(["validate", str(mission_with_route(lib))]) == 0
