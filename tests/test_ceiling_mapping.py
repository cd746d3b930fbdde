"""Ceiling landmarks on rendered images (issue 17, seed 002 §2.1-2.2): the mosaic built
along a drive and localisation in it, checked against the renderer's ground truth."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import pytest

from behaviours.laws.ceiling import (
    camera_from_landmark_eq1,
    localise,
    robot_pose_from_landmark_eq2,
)
from behaviours.laws.ceiling_landmarks import (
    CeilingLocaliser,
    CeilingMapper,
    Landmark,
    LandmarkConfig,
    detect,
    law_camera_for,
    observe_landmarks,
    predict_image_pose,
    subpixel,
)
from executive.core.frames import Pose2, wrap_angle
from sim2d.ceiling import (
    CeilingSpec,
    CeilingTexture,
    UpwardCamera,
    render,
    scripted_drive,
    walker,
)

HEIGHT = 10.0  # m: a small hangar, 20 m x 14 m
SPEC = CeilingSpec(x_max=20.0, y_max=14.0, height=HEIGHT, seed=3, repeated_tiles=4)
CAMERA = UpwardCamera()  # 640 x 480, 80 degrees, at the robot's centre, 0.6 m up


def _errors(estimate: Pose2, truth: Pose2) -> tuple[float, float]:
    return estimate.distance_to(truth), abs(wrap_angle(estimate.theta - truth.theta))


def _odometry_prior(
    estimate: Pose2, previous: Pose2, current: Pose2, rng: np.random.Generator
) -> Pose2:
    """The last estimate moved by the true motion with 5 % / 1 degree of odometry error."""
    delta = previous.inverse() @ current
    noisy = Pose2(
        delta.x * (1.0 + 0.05 * rng.standard_normal()),
        delta.y + 0.01 * rng.standard_normal(),
        delta.theta + math.radians(1.0) * rng.standard_normal(),
    )
    return estimate @ noisy


@dataclass
class Mapped:
    texture: CeilingTexture
    mapper: CeilingMapper
    path: list[Pose2]
    fixes: list[Pose2 | None]


@pytest.fixture(scope="module")
def mapped() -> Mapped:
    """A 36 m loop with four 90-degree turns at 2 Hz and 1 m/s, grey noise 2."""
    texture = CeilingTexture(SPEC)
    path = scripted_drive(
        Pose2(4.0, 4.0, 0.0),
        [(12.0, 0.0), (6.0, math.pi / 2), (12.0, math.pi / 2), (6.0, math.pi / 2)],
        0.5,
    )
    mapper = CeilingMapper(law_camera_for(CAMERA, HEIGHT))
    rng = np.random.default_rng(1)
    fixes: list[Pose2 | None] = []
    estimate = path[0]
    for k, truth in enumerate(path):
        prior = truth if k == 0 else _odometry_prior(estimate, path[k - 1], truth, rng)
        image = render(texture, CAMERA, truth, noise_sigma=2.0, rng=rng)
        fix = mapper.add_image(image, prior)
        fixes.append(None if fix is None else fix.pose)
        estimate = prior if fix is None else fix.pose
    return Mapped(texture, mapper, path, fixes)


# -- conventions --------------------------------------------------------------------------------
@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0), (0.25, -0.1, 0.4), (-0.3, 0.2, -2.0)])
def test_robot_from_camera_maps_renderer_to_law(mount: tuple[float, float, float]) -> None:
    """Ground-truth projection of a landmark (a point and a direction on the ceiling) ->
    image pose -> eq. 2 gives back the true robot pose, for any mount."""
    camera = UpwardCamera(mount_x=mount[0], mount_y=mount[1], mount_yaw=mount[2])
    law = law_camera_for(camera, HEIGHT)
    robot = Pose2(7.0, 5.0, 2.3)
    landmark = Pose2(8.5, 3.9, -0.7)  # in A = M
    tip = landmark.apply([0.5, 0.0])
    uv = camera.project([[landmark.x, landmark.y, HEIGHT], [*tip, HEIGHT]], robot)
    phi = math.atan2(uv[1, 1] - uv[0, 1], uv[1, 0] - uv[0, 0])
    got = robot_pose_from_landmark_eq2(landmark, Pose2(uv[0, 0], uv[0, 1], phi), law)
    assert got.distance_to(robot) < 1e-9
    assert abs(wrap_angle(got.theta - robot.theta)) < 1e-9
    predicted = predict_image_pose(landmark, robot, law)
    assert np.allclose([predicted.x, predicted.y], uv[0], atol=1e-9)
    assert abs(wrap_angle(predicted.theta - phi)) < 1e-9


def test_render_detect_law_gives_true_pose() -> None:
    """Render -> detector -> rigid fit -> law: the robot pose equals the true one (mosaic
    from one image at a known pose, then a moved and turned robot)."""
    texture = CeilingTexture(SPEC)
    mapper = CeilingMapper(law_camera_for(CAMERA, HEIGHT))
    start = Pose2(10.0, 7.0, 0.3)
    mapper.add_image(render(texture, CAMERA, start), start)
    assert len(mapper.landmarks) >= 4
    localiser = mapper.localiser()
    for move in (Pose2(0.4, 0.1, 0.0), Pose2(0.0, 0.0, 0.5), Pose2(1.0, -0.3, 1.2)):
        truth = start @ move
        fix = localiser.locate(render(texture, CAMERA, truth), truth @ Pose2(0.2, -0.2, 0.05))
        assert fix is not None and len(fix.used) >= 3
        position, heading = _errors(fix.pose, truth)
        assert position < 0.015 and heading < math.radians(0.3), (move, position, heading)


# -- (a) the mosaic ------------------------------------------------------------------------------
def test_mosaic_landmarks_match_ground_truth(mapped: Mapped) -> None:
    """Every landmark's mosaic pose is within 2 cm and 0.3 degree of its true pose: its
    origin pixel in its creation image unprojected at the true pose, and the direction of
    that image's +u axis in A (mount yaw + 90 degrees from the robot's heading)."""
    length = sum(a.distance_to(b) for a, b in zip(mapped.path, mapped.path[1:], strict=False))
    assert length >= 20.0
    assert all(fix is not None for fix in mapped.fixes)
    landmarks = list(mapped.mapper.landmarks.values())
    assert len(landmarks) >= 20
    errors, headings = [], []
    for lm in landmarks:
        truth_robot = mapped.path[lm.created_in]
        xy = CAMERA.unproject(np.array(lm.origin_px), truth_robot, HEIGHT)
        errors.append(math.hypot(lm.pose.x - xy[0], lm.pose.y - xy[1]))
        truth_theta = truth_robot.theta + CAMERA.mount_yaw + math.pi / 2.0
        headings.append(abs(wrap_angle(lm.pose.theta - truth_theta)))
    print(
        f"\nmosaic: {len(landmarks)} landmarks, position error p50 "
        f"{100 * np.median(errors):.2f} cm max {100 * max(errors):.2f} cm, heading max "
        f"{math.degrees(max(headings)):.3f} deg"
    )
    assert max(errors) <= 0.02
    assert max(headings) <= math.radians(0.3)


# -- (b) localisation on another path, degraded images -------------------------------------------
def test_localisation_on_another_path_with_lamps_off_and_walker(mapped: Mapped) -> None:
    """A different path (diagonal S over the mapped area) at 4 Hz, grey noise 4, 30 % of
    the lamps off, a walker beside the robot: p95 <= 3 cm and <= 1 degree."""
    rng = np.random.default_rng(7)
    lamps = len(mapped.texture.lamps)
    off = rng.choice(lamps, size=max(1, round(0.3 * lamps)), replace=False).tolist()
    path = scripted_drive(
        Pose2(5.0, 5.0, 0.5), [(5.0, 0.0), (4.0, -1.0), (4.0, 1.2), (3.0, 2.0)], 0.25
    )
    localiser = mapped.mapper.localiser()
    estimate = path[0]
    pos, head = [], []
    for k, truth in enumerate(path):
        prior = truth if k == 0 else _odometry_prior(estimate, path[k - 1], truth, rng)
        person = truth.apply([0.3, 0.35])  # at the robot's front-left shoulder
        image = render(
            mapped.texture,
            CAMERA,
            truth,
            lamps_off=off,
            noise_sigma=4.0,
            rng=rng,
            occluders=walker(float(person[0]), float(person[1])),
            gradient=(0.2, -0.1),
        )
        fix = localiser.locate(image, prior)
        assert fix is not None, k
        p, h = _errors(fix.pose, truth)
        pos.append(p)
        head.append(h)
        estimate = fix.pose
    pos_cm, head_deg = 100 * np.array(pos), np.degrees(head)
    print(
        f"\nlocalisation over {len(path)} images: position p50 {np.median(pos_cm):.2f} "
        f"p95 {np.percentile(pos_cm, 95):.2f} max {pos_cm.max():.2f} cm; heading p50 "
        f"{np.median(head_deg):.3f} p95 {np.percentile(head_deg, 95):.3f} max "
        f"{head_deg.max():.3f} deg"
    )
    assert np.percentile(pos_cm, 95) <= 3.0
    assert np.percentile(head_deg, 95) <= 1.0


# -- (c) repeated tiles ----------------------------------------------------------------------------
def test_repeated_tiles_do_not_mislocalise(mapped: Mapped) -> None:
    """Under each copy of the repeated tile, with priors off by up to 0.5 m and 5 degrees,
    no fix is more than 10 cm off."""
    texture = mapped.texture
    localiser = mapped.mapper.localiser()
    rng = np.random.default_rng(11)
    worst, fixes = 0.0, 0
    centres = []
    for rect in texture.repeated_tiles:
        c = texture.to_world((rect.col + rect.cols / 2.0 - 0.5, rect.row + rect.rows / 2.0 - 0.5))
        centres.append(c)
    for c in centres:
        for _ in range(6):
            truth = Pose2(float(c[0]), float(c[1]), rng.uniform(-math.pi, math.pi))
            r, a = 0.5 * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
            prior = Pose2(
                truth.x + r * math.cos(a),
                truth.y + r * math.sin(a),
                truth.theta + math.radians(rng.uniform(-5.0, 5.0)),
            )
            image = render(texture, CAMERA, truth, noise_sigma=2.0, rng=rng)
            fix = localiser.locate(image, prior)
            if fix is None:
                continue
            fixes += 1
            worst = max(worst, _errors(fix.pose, truth)[0])
    print(f"\nrepeated tiles: {fixes}/{6 * len(centres)} fixes, worst {100 * worst:.2f} cm")
    assert len(centres) == SPEC.repeated_tiles
    assert fixes >= 0.9 * 6 * len(centres)
    assert worst <= 0.10


def test_gate_is_what_tells_tile_copies_apart(mapped: Mapped) -> None:
    """A landmark made of one tile copy's keypoints (no distinctiveness filter), seen with
    two copies in view: with a 0.5 m / 5 degree prior it is found on its own copy; with a
    prior displaced by the offset between the copies it is found, just as well, on the
    other copy (the control: descriptors alone cannot tell the copies apart)."""
    texture = mapped.texture
    law = law_camera_for(CAMERA, HEIGHT)
    centres = [
        texture.to_world((r.col + r.cols / 2.0 - 0.5, r.row + r.rows / 2.0 - 0.5))
        for r in texture.repeated_tiles
    ]
    pairs = [(a, b) for a in centres for b in centres if 2.0 < np.hypot(*(a - b)) < 8.0]
    assert pairs, "need two tile copies within 8 m"
    ca, cb = pairs[0]
    at_tile = Pose2(float(ca[0]), float(ca[1]), 0.4)
    image = render(texture, CAMERA, at_tile)
    features = detect(image)
    half_px = 0.7 * CAMERA.fx / (HEIGHT - CAMERA.mount_z)  # inside the 1.6 m tile
    inside = np.hypot(*(features.points - (CAMERA.cx, CAMERA.cy)).T) < half_px
    pts = subpixel(image, features.points[inside], LandmarkConfig())
    mean = pts.mean(axis=0)
    tile = Landmark(
        "tile",
        at_tile @ law.robot_from_camera @ camera_from_landmark_eq1(Pose2(*mean, 0.0), law),
        pts - mean,
        features.descriptors[inside],
    )
    mid = (ca + cb) / 2.0
    truth = Pose2(float(mid[0]), float(mid[1]), -0.3)  # both copies in view
    seen = render(texture, CAMERA, truth, noise_sigma=2.0, rng=np.random.default_rng(5))
    found = detect(seen)
    shift = Pose2(float(cb[0] - ca[0]), float(cb[1] - ca[1]), 0.0)
    for prior, expected in (
        (truth @ Pose2(0.35, -0.35, math.radians(5.0)), truth),
        (shift.inverse() @ truth, shift.inverse() @ truth),  # believes it is displaced
    ):
        obs = observe_landmarks(found, [tile], prior, law, (640, 480))
        assert len(obs) == 1
        got = robot_pose_from_landmark_eq2(tile.pose, obs[0].image_pose, law)
        assert _errors(got, expected)[0] < 0.05, (prior, got, expected)


# -- (d) timing ------------------------------------------------------------------------------------
def test_localisation_step_time(mapped: Mapped) -> None:
    """One localisation step (detect, gated match, fits, eq. 1-3) on a 640x480 image;
    printed, not asserted (the issue's budget is 10 ms)."""
    localiser: CeilingLocaliser = mapped.mapper.localiser()
    truth = Pose2(10.0, 7.0, 0.8)
    image = render(mapped.texture, CAMERA, truth, noise_sigma=2.0, rng=np.random.default_rng(3))
    prior = truth @ Pose2(0.1, -0.1, 0.02)
    localiser.locate(image, prior)
    times, detect_times = [], []
    for _ in range(30):
        t0 = time.perf_counter()
        features = detect(image, localiser.config)
        t1 = time.perf_counter()
        fix = localise(localiser.observe(features, prior), localiser.mosaic, localiser.camera)
        t2 = time.perf_counter()
        times.append(t2 - t0)
        detect_times.append(t1 - t0)
        assert fix is not None
    print(
        f"\nlocalisation step: median {1e3 * np.median(times):.2f} ms (detection "
        f"{1e3 * np.median(detect_times):.2f} ms), {len(localiser.landmarks)} landmarks"
    )
