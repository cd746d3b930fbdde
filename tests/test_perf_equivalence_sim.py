"""The simulator's fast paths give exactly what the plain ones give.

* :func:`sim2d.raycast.cast_scans` (several scans cast together) equals
  :func:`sim2d.raycast.cast_scan` row by row, bit for bit, including the cases it hands
  back to it (a scan with a single (beam, shape) pair, one-segment scenes, negative
  increments);
* :func:`sim2d.sensors.scan_lasers` equals scanning laser by laser, noise included;
* :meth:`sim2d.cameras.FeatureCloud.out_of_range` only says so where :func:`detect`
  finds nothing.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from executive.core.frames import Pose2
from executive.core.resources import missions_dir
from sim2d.cameras import detect
from sim2d.raycast import Scene, cast_scan, cast_scans
from sim2d.robot import SimRobot
from sim2d.scenario import load_scenario
from sim2d.sensors import scan_lasers

BUSY = missions_dir() / "a320" / "scenarios" / "busy-apron.xml"
HOKUYO = (-0.75 * math.pi, math.pi / 720, 1081, 30.0)


def _random_scene(rng: np.random.Generator, n_seg: int, n_circ: int) -> Scene:
    segments = rng.uniform(-20.0, 20.0, (n_seg, 4))
    circles = np.column_stack((rng.uniform(-20.0, 20.0, (n_circ, 2)), rng.uniform(0.05, 2, n_circ)))
    scene = Scene(segments, circles, np.arange(n_seg), np.arange(n_seg, n_seg + n_circ))
    boxes = [Scene.from_box(*rng.uniform(-15, 15, 2), rng.uniform(-3, 3), 2.0, 1.0, 99)]
    return Scene.concat([scene, *boxes]) if n_seg > 3 else scene


@pytest.mark.parametrize("seed", range(4))
def test_cast_scans_equals_cast_scan_row_by_row(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for trial in range(150):
        sizes = [(30, 10), (1, 3), (0, 1), (0, 2), (2, 0), (5, 5)][trial % 6]
        scene = _random_scene(rng, *sizes)
        origins = [tuple(rng.uniform(-25.0, 25.0, 2)) for _ in range(3)]
        headings = list(rng.uniform(-4.0, 4.0, 3))
        increment = [math.pi / 720, -math.pi / 720, 0.01][trial % 3]
        model = (rng.uniform(-3.0, 3.0), increment, [1081, 200][trial % 2], [30.0, 8.0][trial % 2])
        batch = cast_scans(scene, origins, headings, *model)
        for row, (origin, heading) in enumerate(zip(origins, headings, strict=True)):
            assert np.array_equal(batch[row], cast_scan(scene, origin, heading, *model))


def test_cast_scans_scan_with_a_single_pair() -> None:
    """A scan with one (beam, shape) pair next to a busy one: numpy rounds a lone complex
    product differently, so cast_scans must cast it alone."""
    rng = np.random.default_rng(1)
    lone = 0
    for _ in range(200):
        tiny = [(*rng.uniform(-10.0, 10.0, 2), 0.001) for _ in range(3)]
        scene = Scene([(48, 40, 52, 41), (60, 60, 61, 65)], [*tiny, (50.0, 50.0, 3.0)])
        origins = [(0.0, 0.0), (50.0 + rng.uniform(-6, 6), 45.0 + rng.uniform(-3, 3))]
        headings = list(rng.uniform(-4.0, 4.0, 2))
        batch = cast_scans(scene, origins, headings, *HOKUYO)
        single = [cast_scan(scene, o, h, *HOKUYO) for o, h in zip(origins, headings, strict=True)]
        lone += int((single[0] < HOKUYO[3]).sum() == 1)
        assert all(np.array_equal(b, s) for b, s in zip(batch, single, strict=True))
    assert lone > 10


def test_scan_lasers_equals_laser_by_laser() -> None:
    robot = SimRobot(load_scenario(BUSY))
    lasers = [sensor for sensor, _ in robot.lasers.values()]
    assert len(lasers) == 2
    twins = copy.deepcopy(lasers)  # same generator states
    scene = robot.world.scene
    rng = np.random.default_rng(3)
    centre = scene.segments.reshape(-1, 2).mean(axis=0)
    for _ in range(40):
        pose = Pose2(*(centre + rng.uniform(-30.0, 30.0, 2)), rng.uniform(-4.0, 4.0))
        together = scan_lasers(lasers, scene, pose, 1.0)
        for twin, scan in zip(twins, together, strict=True):
            alone = scan_lasers([twin], scene, pose, 1.0)[0]
            assert np.array_equal(alone.ranges, scan.ranges)
            assert (alone.angle_min, alone.angle_increment) == (
                scan.angle_min,
                scan.angle_increment,
            )
    assert all(
        a.rng.bit_generator.state == b.rng.bit_generator.state
        for a, b in zip(lasers, twins, strict=True)
    )


def test_out_of_range_only_where_nothing_is_detected() -> None:
    robot = SimRobot(load_scenario(BUSY))
    cloud = robot.cloud
    rng = np.random.default_rng(4)
    centre = cloud.points[:, :2].mean(axis=0)
    blind = 0
    for _ in range(300):
        pose = Pose2(*(centre + rng.uniform(-60.0, 60.0, 2)), rng.uniform(-4.0, 4.0))
        if not cloud.out_of_range(pose.x, pose.y, robot._camera_reach):
            continue
        blind += 1
        for rig, _ in robot.rigs:
            for pan, tilt in ((0.0, 0.0), (1.5, 0.5), (-2.5, -0.3)):
                frame = detect(
                    rig,
                    pan,
                    tilt,
                    pose,
                    cloud,
                    rng=rng,
                    pixel_noise=0.0,
                    dropout=0.0,
                    occluded=None,
                    stamp=0.0,
                )
                assert frame.detections == ()
    assert blind > 20
