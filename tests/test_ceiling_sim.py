"""The hangar ceiling in missions, scenarios, sim2d and the pose filter (issue 17,
seed 002): the upward camera as platform data, the ceiling and its lamps in scenarios,
the image sim2d puts in every SensorFrame, the mosaic file, and ceiling fixes keeping the
pose estimate on the ground truth with GPS denied."""

from __future__ import annotations

import io
import json
import math
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import py_trees
import pytest

from behaviours.keys import POSE, SENSOR_FRAME
from behaviours.laws.ceiling_landmarks import CeilingMapper, law_camera_for
from behaviours.laws.localisation import PoseFilter
from behaviours.laws.mosaic import load_mosaic, mosaic_data, save_mosaic
from behaviours.sensing.ceiling import CeilingFixer
from behaviours.sensing.localisation import Localise
from executive.cli import main
from executive.compiler import CompileError, compile_mission
from executive.core import mosaicfile
from executive.core.frames import Pose2
from executive.core.loader import load_mission
from executive.core.model import CeilingCameraSpec
from executive.core.mosaicfile import MosaicFormatError, read_mosaic, write_mosaic
from executive.core.problems import InvalidInputError
from executive.core.records import CeilingImage, VelocityCommand
from sim2d.ceiling import CeilingTexture, render, upward_camera_for, walker
from sim2d.robot import SimRobot
from sim2d.scenario import (
    LampSwitch,
    check_scenario,
    lamp_timeline,
    load_scenario,
    scenario_xml,
)
from tests.conftest import MISSIONS

CAMERA = (
    '<ceiling-camera x="0.1" y="0" z="0.6" yaw-deg="0" width-px="640" height-px="480"'
    ' hfov-deg="80" rate-hz="4"/>'
)
CAMERA_SPEC = CeilingCameraSpec(0.1, 0.0, 0.0, 640, 480, math.radians(80.0), 4.0, 0.6)
"""What CAMERA reads as."""
CEILING = '<ceiling x-min="-8" y-min="-10" x-max="25" y-max="10" height="10" seed="3"'


def library(
    root: Path, camera: str | None = CAMERA, mosaic: str | None = None, scenario: str = ""
) -> Path:
    """A copy of the track missions; straight-run.xml with ``camera`` in its platform and
    ``mosaic`` in its airport; ``scenario`` (inner XML) as scenarios/ceiling.xml, whose
    path is returned."""
    lib = root / "lib"
    if lib.exists():
        shutil.rmtree(lib)
    shutil.copytree(MISSIONS / "track", lib / "track")
    mission = lib / "track" / "straight-run.xml"
    text = mission.read_text(encoding="utf-8")
    if camera is not None:
        text = text.replace("  </platform>", f"    {camera}\n  </platform>", 1)
    if mosaic is not None:
        text = text.replace("  </airport>", f"    {mosaic}\n  </airport>", 1)
    mission.write_text(text, encoding="utf-8")
    path = lib / "track" / "scenarios" / "ceiling.xml"
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<scenario xmlns="urn:walkaround:scenario:1" id="ceiling" mission="../straight-run.xml"'
        ' seed="3" duration="60">\n'
        f"{scenario}\n</scenario>\n",
        encoding="utf-8",
    )
    return path


def line_of(path: Path, needle: str) -> int:
    lines = path.read_text(encoding="utf-8").splitlines()
    return next(i for i, line in enumerate(lines, start=1) if needle in line)


# -- the platform's upward camera -------------------------------------------------------------
def test_ceiling_camera_is_platform_data(tmp_path: Path) -> None:
    library(tmp_path)
    mission = load_mission(tmp_path / "lib" / "track" / "straight-run.xml")
    spec = mission.platform.ceiling_camera
    assert spec is not None
    assert (spec.mount_x, spec.mount_y, spec.mount_z, spec.rate_hz) == (0.1, 0.0, 0.6, 4.0)
    assert spec.hfov == pytest.approx(math.radians(80.0))
    # f from the field of view; OpenCV's principal point; the same camera in sim2d and law
    assert spec.fx == pytest.approx(320.0 / math.tan(math.radians(40.0)))
    camera = upward_camera_for(spec)
    assert camera.hfov == pytest.approx(spec.hfov) and (camera.cx, camera.cy) == (319.5, 239.5)
    law = law_camera_for(spec, 10.0)
    assert law == law_camera_for(camera, 10.0)
    assert law.height == pytest.approx(9.4)
    assert spec == CAMERA_SPEC
    assert load_mission(MISSIONS / "track" / "straight-run.xml").platform.ceiling_camera is None


@pytest.mark.parametrize(
    ("old", "new", "code", "message"),
    [
        ('hfov-deg="80"', 'hfov-deg="170"', "schema", "between 10 and 150 deg"),
        ('rate-hz="4"', 'rate-hz="0"', "schema", "rate-hz"),
        ('z="0.6"', 'z="-1"', "schema", "'z'"),
        ('width-px="640"', 'width-px="8"', "schema", "width-px"),
        ('x="0.1"', 'x="2.5"', "ceiling-camera-mount", "off the robot's 1.4 m x 1 m footprint"),
        ('yaw-deg="0" ', "", "schema", "yaw-deg"),
    ],
)
def test_bad_ceiling_camera_is_refused_at_its_line(
    tmp_path: Path, old: str, new: str, code: str, message: str
) -> None:
    assert old in CAMERA
    library(tmp_path, camera=CAMERA.replace(old, new))
    path = tmp_path / "lib" / "track" / "straight-run.xml"
    with pytest.raises(InvalidInputError) as info:
        load_mission(path)
    problems = [p for p in info.value.problems if p.code == code]
    assert problems, [str(p) for p in info.value.problems]
    assert message in problems[0].message
    assert problems[0].where.line == line_of(path, "<ceiling-camera")


# -- the ceiling in scenarios -------------------------------------------------------------------
SWITCHES = """
  <lamps-off at="10" ids="0 5 7"/>
  <lamps-off at="20" fraction="0.5"/>
  <lamps-on at="30" ids="5"/>
  <lamps-on at="40" fraction="1"/>
</ceiling>"""


def test_scenario_ceiling_and_lamp_timeline(tmp_path: Path) -> None:
    body = f'{CEILING} beam-spacing="5" noise-grey="0" exposure="1.2">{SWITCHES}'
    scenario = load_scenario(library(tmp_path, scenario=body))
    ceiling = scenario.ceiling
    assert ceiling is not None
    spec = ceiling.spec
    assert (spec.x_min, spec.x_max, spec.height, spec.seed, spec.beam_spacing) == (
        -8.0,
        25.0,
        10.0,
        3,
        5.0,
    )
    assert spec.lamp_spacing == (6.0, 6.0) and ceiling.exposure == 1.2  # defaults kept
    n = len(spec.lamp_centres())
    seed = scenario.seed
    assert ceiling.lamps_off(9.99, seed) == frozenset()
    assert ceiling.lamps_off(10.0, seed) == {0, 5, 7}
    after_fraction = ceiling.lamps_off(20.0, seed)
    assert {0, 5, 7} < after_fraction
    assert len(after_fraction) == 3 + round(0.5 * (n - 3))
    assert ceiling.lamps_off(30.0, seed) == after_fraction - {5}
    assert ceiling.lamps_off(1e6, seed) == frozenset()  # every lamp back on
    # the fraction is drawn from the scenario's seed: the same seed, the same lamps;
    # another seed (a campaign's next episode), other lamps
    assert ceiling.timeline(seed) == lamp_timeline(ceiling.switches, n, 3)
    assert ceiling.timeline(4)[1] != ceiling.timeline(seed)[1]
    # written back as a scenario file, it reads the same
    copy = scenario.source.replace("ceiling.xml", "copy.xml")
    Path(copy).write_text(scenario_xml(scenario, "../straight-run.xml"), encoding="utf-8")
    assert load_scenario(copy).ceiling == ceiling


def test_lamp_timeline_orders_switches_by_time() -> None:
    switches = (LampSwitch(5.0, False, (1,)), LampSwitch(1.0, True, (1, 2)))
    assert lamp_timeline(switches, 4, 0) == ((1.0, frozenset({1, 2})), (5.0, frozenset({2})))
    with pytest.raises(ValueError, match="lamp id 4"):
        lamp_timeline((LampSwitch(0.0, True, (4,)),), 4, 0)


BAD_CEILINGS = [
    (CEILING.replace('height="10"', 'height="2"') + "/>", "<ceiling", "schema", "between 3 and 60"),
    (f'{CEILING} noise-grey="nan"/>', "<ceiling", "schema", "noise-grey"),
    (
        CEILING.replace('x-max="25"', 'x-max="-9"') + "/>",
        "<ceiling",
        "ceiling",
        "x_max must exceed x_min",
    ),
    (
        f'{CEILING}><lamps-off at="1" ids="2 999"/></ceiling>',
        "<lamps-off",
        "unknown-reference",
        "lamp 999 does not exist: this ceiling has",
    ),
    (
        f'{CEILING}><lamps-off at="1" ids="2" fraction="0.5"/></ceiling>',
        "<lamps-off",
        "lamp-switch",
        "exactly one",
    ),
    (f'{CEILING}><lamps-on at="1"/></ceiling>', "<lamps-on", "lamp-switch", "exactly one"),
    (f'{CEILING}><lamps-on at="1" ids="x"/></ceiling>', "<lamps-on", "schema", "ids"),
    (f'{CEILING}><lamps-on at="-1" ids="1"/></ceiling>', "<lamps-on", "schema", "at"),
    (f'{CEILING}><lamps-off at="1" fraction="2"/></ceiling>', "<lamps-off", "schema", "fraction"),
]


@pytest.mark.parametrize(("body", "needle", "code", "message"), BAD_CEILINGS)
def test_bad_ceiling_is_refused_at_its_line(
    tmp_path: Path, body: str, needle: str, code: str, message: str
) -> None:
    path = library(tmp_path, scenario=body)
    problems = [p for p in check_scenario(path) if p.code == code]
    assert problems, [str(p) for p in check_scenario(path)]
    assert message in problems[0].message
    assert problems[0].where.line == line_of(path, needle)


def test_ceiling_must_be_above_the_camera_and_validate_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    camera = CAMERA.replace('z="0.6"', 'z="4"')
    path = library(tmp_path, camera=camera, scenario=f"{CEILING.replace('10', '4.2')}/>")
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr().out
    assert f"ceiling.xml:{line_of(path, '<ceiling')}:" in out
    assert "more than 0.5 m above the platform's ceiling-camera" in out


# -- the upward image in the SensorFrame --------------------------------------------------------
PERSON = (
    '<obstacles><path id="walker" kind="person" radius="0.3" height="1.8" speed="1.0"'
    ' start-time="1000"><waypoint x="3.1" y="0.95"/><waypoint x="8" y="0.95"/></path>'
    "</obstacles>"
)


def test_sensor_frame_image_is_the_render_at_the_true_pose(tmp_path: Path) -> None:
    """Noise off: the image is exactly the renderer's at the true pose, with the lamps of
    the timeline off and the person (waiting beside the track) as a walker."""
    body = f'<start x="0" y="0" heading-deg="0"/>{PERSON}{CEILING} noise-grey="0">{SWITCHES}'
    scenario = load_scenario(library(tmp_path, scenario=body))
    robot = SimRobot(scenario)
    ceiling = scenario.ceiling
    assert ceiling is not None and scenario.mission.platform.ceiling_camera is not None
    texture = CeilingTexture(ceiling.spec)
    camera = upward_camera_for(scenario.mission.platform.ceiling_camera)
    occluders = walker(3.1, 0.95, stature=1.8)  # the person waits at its first waypoint
    occluded = 0
    # 5 s straight at 0.6 m/s: the robot passes beside the person; then turns, to 21 s
    # (lamps switched at 10 and 20 s)
    plan = [(0.6, 0.0, 0.25)] * 24 + [(0.6, 0.3, 2.0)] * 4 + [(0.4, -0.2, 2.0)] * 4
    for v, omega, seconds in plan:
        robot.send(VelocityCommand(v, omega))
        robot.advance(seconds)
        image = robot.read().ceiling
        assert image is not None and image.stamp == pytest.approx(robot.time)
        pose = robot.truth.robot
        lamps_off = ceiling.lamps_off(image.stamp, scenario.seed)
        expected = render(texture, camera, pose, lamps_off=lamps_off, occluders=occluders)
        assert np.array_equal(image.image, expected)
        occluded += not np.array_equal(expected, render(texture, camera, pose, lamps_off=lamps_off))
    assert 2 <= occluded <= 12  # the person was in view for a while, then not
    assert not robot.truth.collisions


def test_ceiling_images_are_seeded_and_only_with_camera_and_ceiling(tmp_path: Path) -> None:
    path = library(tmp_path, scenario=f"{CEILING}/>")
    a, b = SimRobot(load_scenario(path)), SimRobot(load_scenario(path))
    for robot in (a, b):
        robot.send(VelocityCommand(0.5, 0.1))
        robot.advance(1.0)
    ia, ib = a.read().ceiling, b.read().ceiling
    assert ia is not None and ib is not None and np.array_equal(ia.image, ib.image)
    assert ia.stamp == pytest.approx(1.0)
    assert SimRobot(load_scenario(library(tmp_path, scenario=""))).read().ceiling is None
    no_camera = library(tmp_path, camera=None, scenario=f"{CEILING}/>")
    robot = SimRobot(load_scenario(no_camera))
    assert robot.ceiling is None and robot.read().ceiling is None


# -- the mosaic file ----------------------------------------------------------------------------
@dataclass
class Mapped:
    texture: CeilingTexture
    mapper: CeilingMapper
    height: float


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> Mapped:
    """The ceiling of the track scenarios mapped along the track, 0.5 m apart, 15 m."""
    scenario = load_scenario(library(tmp_path_factory.mktemp("map"), scenario=f"{CEILING}/>"))
    assert scenario.ceiling is not None and scenario.mission.platform.ceiling_camera is not None
    camera = upward_camera_for(scenario.mission.platform.ceiling_camera)
    height = scenario.ceiling.spec.height
    texture = CeilingTexture(scenario.ceiling.spec)
    mapper = CeilingMapper(law_camera_for(camera, height))
    rng = np.random.default_rng(5)
    for k in range(31):
        pose = Pose2(0.5 * k, 0.0, 0.0)
        mapper.add_image(render(texture, camera, pose, noise_sigma=2.0, rng=rng), pose)
    return Mapped(texture, mapper, height)


def test_saved_mosaic_localises_as_the_one_in_memory(mapped: Mapped, tmp_path: Path) -> None:
    path = tmp_path / "hangar.npz"
    save_mosaic(path, mapped.mapper, ceiling_height=mapped.height)
    loaded = load_mosaic(path)
    memory = mapped.mapper.localiser()
    assert loaded.mosaic == memory.mosaic and loaded.camera == memory.camera
    assert loaded.config == memory.config and loaded.image_size == memory.image_size
    camera = upward_camera_for(CAMERA_SPEC)
    rng = np.random.default_rng(8)
    fixes = 0
    for x, y, th in [(2.0, 0.5, 0.2), (7.3, -1.0, -0.4), (12.0, 1.5, 2.5)]:
        truth = Pose2(x, y, th)
        image = render(mapped.texture, camera, truth, noise_sigma=2.0, rng=rng)
        prior = Pose2(x + 0.2, y - 0.1, th + 0.03)
        a, b = loaded.locate(image, prior), memory.locate(image, prior)
        assert a is not None and b is not None
        assert a.pose == b.pose and np.array_equal(a.covariance, b.covariance)
        assert a.pose.distance_to(truth) < 0.03
        fixes += 1
    assert fixes == 3


def _npz(members: dict[str, np.ndarray]) -> bytes:
    out = io.BytesIO()
    np.savez(out, **members)
    return out.getvalue()


def test_bad_mosaic_files_are_refused_clearly(
    mapped: Mapped, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    good = tmp_path / "good.npz"
    save_mosaic(good, mapped.mapper, ceiling_height=mapped.height)
    raw = good.read_bytes()
    with np.load(good) as npz:
        members = {k: npz[k] for k in npz.files}
    meta = json.loads(str(members["meta"][()]))

    def variant(**changes: object) -> bytes:
        return _npz({**members, **changes})  # type: ignore[arg-type]

    newer = dict(meta, version=2)
    cases = {
        "truncated": (raw[: len(raw) // 2], "truncated or corrupt"),
        "text": (b"landmarks: many\n", "truncated or corrupt"),
        "empty": (b"", "truncated or corrupt"),
        "missing": (_npz({k: v for k, v in members.items() if k != "points"}), "missing points"),
        "version": (variant(meta=np.array(json.dumps(newer))), "version 2 is newer"),
        "format": (variant(meta=np.array('{"format": "x"}')), "not a ceiling mosaic"),
        "json": (variant(meta=np.array("{")), "not valid JSON"),
        "shape": (variant(points=members["points"][:-1]), "points must be a"),
        "dtype": (variant(descriptors=members["descriptors"].astype(np.int16)), "uint8"),
        "nan": (variant(poses=members["poses"] * np.nan), "finite"),
        "object": (variant(counts=np.array([None] * len(members["counts"]))), "corrupt"),
        "height": (variant(meta=np.array(json.dumps(dict(meta, ceiling_height=1.0)))), "below"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / f"{name}.npz"
        path.write_bytes(data)
        with pytest.raises(MosaicFormatError, match=message) as info:
            load_mosaic(path)
        assert str(path) in str(info.value), name
    # a zip bomb's members are refused before they are expanded (a 1 MB limit here)
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("meta.npy", b"\0" * (2 * 1024 * 1024))
    (tmp_path / "bomb.npz").write_bytes(bomb.getvalue())
    monkeypatch.setattr(mosaicfile, "MAX_MOSAIC_BYTES", 1024 * 1024)
    with pytest.raises(MosaicFormatError, match="would expand"):
        read_mosaic(tmp_path / "bomb.npz")
    monkeypatch.undo()
    # unknown tuning refused by the localiser's loader
    bad_config = tmp_path / "config.npz"
    bad_config.write_bytes(variant(meta=np.array(json.dumps(dict(meta, config={"nope": 1})))))
    with pytest.raises(MosaicFormatError, match="unknown setting 'nope'"):
        load_mosaic(bad_config)
    write_mosaic(tmp_path / "again.npz", mosaic_data(load_mosaic(good), mapped.height))
    assert load_mosaic(tmp_path / "again.npz").mosaic == load_mosaic(good).mosaic


def test_mission_names_its_mosaic_and_validate_checks_it(
    mapped: Mapped, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    element = '<ceiling-mosaic file="hangar.npz"/>'
    library(tmp_path, mosaic=element)
    folder = tmp_path / "lib" / "track"
    mission_path = folder / "straight-run.xml"
    with pytest.raises(InvalidInputError) as info:
        load_mission(mission_path)  # no file yet
    (problem,) = info.value.problems
    assert problem.code == "ceiling-mosaic-path" and "does not exist" in problem.message
    assert problem.where.line == line_of(mission_path, "<ceiling-mosaic")
    (folder / "hangar.npz").write_bytes(b"PK\x03\x04 not really")
    assert main(["validate", str(mission_path)]) == 2
    out = capsys.readouterr().out
    assert "ceiling-mosaic file 'hangar.npz' has 1 problem(s)" in out
    assert "hangar.npz: not a readable ceiling mosaic" in out
    save_mosaic(folder / "hangar.npz", mapped.mapper, ceiling_height=mapped.height)
    mission = load_mission(mission_path)
    assert mission.ceiling_mosaic == (folder / "hangar.npz").resolve()
    library(tmp_path, mosaic='<ceiling-mosaic file="../../../etc/passwd"/>')
    with pytest.raises(InvalidInputError, match="leads outside the mission library"):
        load_mission(mission_path)


def _localise_node(root: py_trees.behaviour.Behaviour) -> Localise:
    return next(n for n in root.iterate() if isinstance(n, Localise))


def test_compiler_wires_ceiling_fixes_only_with_camera_and_mosaic(
    mapped: Mapped, tmp_path: Path
) -> None:
    element = '<ceiling-mosaic file="hangar.npz"/>'
    for camera, expected in ((CAMERA, True), (None, False)):
        library(tmp_path, camera=camera, mosaic=element)
        folder = tmp_path / "lib" / "track"
        save_mosaic(folder / "hangar.npz", mapped.mapper, ceiling_height=mapped.height)
        compiled = compile_mission(load_mission(folder / "straight-run.xml"))
        assert (_localise_node(compiled.root).ceiling is not None) is expected
    library(tmp_path, camera=CAMERA)
    compiled = compile_mission(load_mission(tmp_path / "lib" / "track" / "straight-run.xml"))
    assert _localise_node(compiled.root).ceiling is None
    # a lens other than the mosaic's: its ORB descriptors are for another scale
    library(tmp_path, camera=CAMERA.replace('hfov-deg="80"', 'hfov-deg="60"'), mosaic=element)
    folder = tmp_path / "lib" / "track"
    save_mosaic(folder / "hangar.npz", mapped.mapper, ceiling_height=mapped.height)
    with pytest.raises(CompileError) as info:
        compile_mission(load_mission(folder / "straight-run.xml"))
    (problem,) = [p for p in info.value.problems if p.code == "ceiling-camera"]
    assert "cm of ceiling per pixel" in problem.message
    assert problem.where.line == line_of(folder / "straight-run.xml", "<ceiling-camera")


# -- closed loop: GPS denied under the ceiling --------------------------------------------------
def _drive(scenario, fixer: CeilingFixer | None) -> tuple[list[float], SimRobot]:
    """Localise ticked at 50 Hz against sim2d while the robot drives a 12 m S-bend;
    returns the position error of the estimate at each tick."""
    py_trees.blackboard.Blackboard.clear()
    robot = SimRobot(scenario)
    m = scenario.mission
    node = Localise(scenario.start, m.platform.track, m.nominal_placement(), ceiling=fixer)
    bb = py_trees.blackboard.Client(name="ceiling-test")
    bb.register_key(key=SENSOR_FRAME.name, access=py_trees.common.Access.WRITE)
    bb.register_key(key=POSE.name, access=py_trees.common.Access.READ)
    errors = []
    for i in range(50 * 20):
        bb.set(SENSOR_FRAME.name, robot.read(), overwrite=True)
        node.tick_once()
        robot.send(VelocityCommand(0.6, 0.15 * math.sin(i / 100.0)))
        robot.advance(0.02)
        errors.append(bb.get(POSE.name).pose_a.distance_to(robot.truth.robot))
    return errors, robot


def test_ceiling_fixes_hold_the_estimate_with_gps_denied(mapped: Mapped, tmp_path: Path) -> None:
    body = (
        '<start x="0" y="0" heading-deg="0"/><slip longitudinal="0.05"/><gps mode="denied"/>'
        f"{CEILING}/>"
    )
    scenario = load_scenario(library(tmp_path, scenario=body))
    mosaic = tmp_path / "hangar.npz"
    save_mosaic(mosaic, mapped.mapper, ceiling_height=mapped.height)
    fixer = CeilingFixer(load_mosaic(mosaic))
    with_fixes, robot = _drive(scenario, fixer)
    without, _ = _drive(scenario, None)
    assert robot.truth.robot.x > 10.0  # it drove the bend
    assert fixer.counts["images"] == 80 and fixer.counts["accepted"] >= 76
    assert max(with_fixes) < 0.04
    assert without[-1] > 0.2  # dead reckoning drifts: 5 % slip, no GPS


def test_fixer_counts_what_it_does_not_fuse(mapped: Mapped) -> None:
    """A fix the filter's gate refuses, an image with no landmark of the mosaic and an
    image too old are counted, and leave the filter as it was."""
    fixer = CeilingFixer(mapped.mapper.localiser())
    camera = upward_camera_for(CAMERA_SPEC)
    truth = Pose2(6.0, 0.5, 0.1)
    image = render(mapped.texture, camera, truth, noise_sigma=2.0, rng=np.random.default_rng(3))
    # a filter sure (1 cm) of a pose 10 cm off: the fix is 7 sigmas away
    confident = PoseFilter(Pose2(6.1, 0.5, 0.1), track=0.85, sigma_xy=0.01, sigma_theta=0.002)
    assert not fixer.step(1.0, CeilingImage(1.0, image), confident)
    assert fixer.counts["rejected"] == 1
    assert (confident.pose.x, confident.pose.y) == (6.1, 0.5)  # unchanged
    assert not fixer.step(1.0, CeilingImage(1.0, image), confident)  # the same image
    assert fixer.counts["images"] == 1
    # the same image with an honest filter: fused, on the truth
    honest = PoseFilter(Pose2(6.1, 0.5, 0.1), track=0.85, sigma_xy=0.1, sigma_theta=0.02)
    assert fixer.step(2.0, CeilingImage(1.5, image), honest)
    assert fixer.counts["accepted"] == 1 and honest.pose.distance_to(truth) < 0.02
    # a lost filter (3 m off, and sure of it): the gated matching finds no landmark
    lost = PoseFilter(Pose2(3.0, -2.5, 0.1), track=0.85, sigma_xy=0.05)
    assert not fixer.step(3.0, CeilingImage(3.0, image), lost)
    assert fixer.counts["no-fix"] == 1
    assert not fixer.step(10.0, CeilingImage(4.0, image), honest)  # 6 s old
    assert fixer.counts == {"images": 4, "accepted": 1, "rejected": 1, "no-fix": 1, "stale": 1}
