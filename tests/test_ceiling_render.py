"""The upward camera's rendered ceiling images (sim2d/ceiling.py, issue 17).

Behaviour against the documented model: where a lamp appears (``UpwardCamera.project``),
the mirror convention, the scale Z/f of a translation, lamps switched off, occluders,
seeded noise, the dark outside, validation, and the repeated tiles.
"""

import math

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from executive.core.frames import Pose2
from sim2d.ceiling import (
    OCCLUDER_GREY,
    OUTSIDE_GREY,
    CeilingSpec,
    CeilingTexture,
    Occluder,
    UpwardCamera,
    render,
    walker,
)

LAMP_XY = (10.3, 9.7)
THRESHOLD = 228  # above everything but a lit emitter (250)
CAMERAS = {
    "default": UpwardCamera(),
    "offset": UpwardCamera(mount_x=0.35, mount_y=-0.12, mount_z=0.9, mount_yaw=0.4),
    # a long lens: the footprint (about 1 cm) is below the texel, so level 0 is sampled
    "narrow": UpwardCamera(fx=1150.0, fy=1150.0, cx=300.0, cy=250.0),
}


@pytest.fixture(scope="module")
def one_lamp():
    """A 20 m x 20 m ceiling 12 m high with a single lamp and no repeated tiles."""
    spec = CeilingSpec(x_max=20.0, y_max=20.0, height=12.0, lamps=(LAMP_XY,), repeated_tiles=0)
    return CeilingTexture(spec)


@pytest.fixture(scope="module")
def hangar():
    """A 24 m x 18 m ceiling with the default pattern: a lamp grid, beams, tiles."""
    return CeilingTexture(CeilingSpec(x_max=24.0, y_max=18.0, height=12.0, seed=7))


def lit_centroid(image):
    """Intensity-weighted centroid (u, v) of the lit-emitter pixels."""
    weight = np.clip(image.astype(float) - THRESHOLD, 0.0, None)
    assert weight.sum() > 0.0, "no lit lamp in view"
    v, u = np.mgrid[: image.shape[0], : image.shape[1]]
    return np.array([(u * weight).sum(), (v * weight).sum()]) / weight.sum()


def lamp_uv(texture, camera, pose, xy=LAMP_XY):
    return camera.project([(*xy, texture.spec.height)], pose)[0]


def shift_between(a, b):
    """(du, dv) such that content at (u, v) in ``a`` is at (u + du, v + dv) in ``b``:
    phase correlation, refined by ECC (OpenCV's enhanced correlation coefficient)."""
    a, b = a.astype(np.float32), b.astype(np.float32)
    window = cv2.createHanningWindow(a.shape[::-1], cv2.CV_64F)
    (du, dv), _ = cv2.phaseCorrelate(a.astype(np.float64), b.astype(np.float64), window)
    warp = np.array([[1.0, 0.0, du], [0.0, 1.0, dv]], dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    _, warp = cv2.findTransformECC(a, b, warp, cv2.MOTION_TRANSLATION, criteria, None, 5)
    return warp[:, 2].astype(float)


# -- geometry -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(CAMERAS))
@settings(max_examples=25, deadline=None)
@given(
    dx=st.floats(-6.0, 6.0),
    dy=st.floats(-6.0, 6.0),
    theta=st.floats(-math.pi, math.pi),
)
def test_lamp_appears_where_project_says(one_lamp, name, dx, dy, theta):
    camera = CAMERAS[name]
    pose = Pose2(LAMP_XY[0] + dx, LAMP_XY[1] + dy, theta)
    expected = lamp_uv(one_lamp, camera, pose)
    margin = 40.0
    assume(margin < expected[0] < camera.image_width_px - margin)
    assume(margin < expected[1] < camera.image_height_px - margin)
    image = render(one_lamp, camera, pose)
    assert image.shape == (camera.image_height_px, camera.image_width_px)
    assert image.dtype == np.uint8
    assert np.linalg.norm(lit_centroid(image) - expected) < 0.5  # brief: 1 px; seen: 0.2


def test_image_is_mirrored_and_turns_with_the_robot(one_lamp):
    """Top of the image is forward; u grows to the robot's LEFT (mirror of a top-down map
    drawn forward-up); turning left moves a point ahead towards the image's left."""
    camera = CAMERAS["default"]
    cx, cy = camera.cx, camera.cy
    ahead = Pose2(LAMP_XY[0] - 3.0, LAMP_XY[1], 0.0)  # the lamp 3 m ahead
    u, v = lit_centroid(render(one_lamp, camera, ahead))
    assert abs(u - cx) < 1.0
    assert v < cy - 50.0
    to_left = Pose2(LAMP_XY[0], LAMP_XY[1] - 3.0, 0.0)  # the lamp 3 m to the left
    u, v = lit_centroid(render(one_lamp, camera, to_left))
    assert u > cx + 50.0
    assert abs(v - cy) < 1.0
    turned = Pose2(ahead.x, ahead.y, 0.3)  # the robot turned left
    u, v = lit_centroid(render(one_lamp, camera, turned))
    assert u < cx - 20.0
    assert np.linalg.norm((u, v) - lamp_uv(one_lamp, camera, turned)) < 1.0
    # counter-clockwise on the screen (u right, v down) when the robot turns left
    before = math.atan2(-(lamp_uv(one_lamp, camera, ahead)[1] - cy), 0.0)
    after = math.atan2(-(v - cy), u - cx)
    assert after - before == pytest.approx(0.3, abs=0.01)


@pytest.mark.parametrize("name", ["default", "offset"])
@pytest.mark.parametrize(("forward", "left"), [(0.4, 0.0), (0.0, 0.4), (-0.25, 0.3), (0.013, 0.0)])
def test_translation_moves_content_by_f_d_over_z(hangar, name, forward, left):
    """Scale Z/f: moving d metres moves the image content by f d / (H - camera height)."""
    camera = CAMERAS[name]
    pose = Pose2(11.0, 8.0, 0.7)
    moved = pose @ Pose2(forward, left, 0.0)
    shift = shift_between(render(hangar, camera, pose), render(hangar, camera, moved))
    z = hangar.spec.height - camera.mount_z
    # the camera moves (a, b) in its own frame F; content moves the other way, mirrored
    c, s = math.cos(camera.mount_yaw), math.sin(camera.mount_yaw)
    a, b = c * forward + s * left, -s * forward + c * left
    expected = np.array([-camera.fx * b / z, camera.fy * a / z])
    assert shift == pytest.approx(expected, abs=0.03)


def test_project_and_unproject_are_inverse():
    camera = CAMERAS["offset"]
    pose = Pose2(3.0, -2.0, 2.5)
    uv = np.array([[0.0, 0.0], [639.0, 479.0], [100.5, 300.25]])
    xy = camera.unproject(uv, pose, 12.0)
    back = camera.project(np.column_stack([xy, np.full(3, 12.0)]), pose)
    assert back == pytest.approx(uv, abs=1e-9)
    assert np.isnan(camera.project([(0.0, 0.0, 0.5)], pose)).all()  # below the camera


def test_texel_world_mapping(one_lamp):
    points = np.array([[0.005, 19.995], [LAMP_XY[0], LAMP_XY[1]], [12.34, 5.67]])
    texels = one_lamp.to_texel(points)
    assert texels[0] == pytest.approx([0.0, 0.0])  # texel (0, 0): the north-west corner
    assert one_lamp.to_world(texels) == pytest.approx(points)
    col, row = np.rint(texels[1]).astype(int)
    assert one_lamp.image[row, col] == 250  # the lamp's centre is lit in the texture


# -- lamps, occluders, imaging ---------------------------------------------------------------
def test_lamp_switched_off_goes_dark_and_nothing_else_changes(hangar):
    camera = CAMERAS["default"]
    lamp = hangar.lamps[len(hangar.lamps) // 2]
    pose = Pose2(lamp.x + 1.0, lamp.y - 0.5, 0.9)
    lit = render(hangar, camera, pose)
    dark = render(hangar, camera, pose, lamps_off={lamp.id})
    u, v = np.rint(lamp_uv(hangar, camera, pose, (lamp.x, lamp.y))).astype(int)
    assert lit[v, u] > THRESHOLD
    assert dark[v, u] < 100
    # pixels that changed all see the lamp's square (plus 2 px of interpolation)
    rows, cols = np.nonzero(lit != dark)
    assert rows.size > 100
    xy = camera.unproject(np.column_stack([cols, rows]), pose, hangar.spec.height)
    reach = hangar.spec.lamp_extent + 2.0 * max(camera.footprint(hangar.spec.height))
    assert np.abs(xy - (lamp.x, lamp.y)).max() <= reach
    # other lamps in view stay lit
    others = [lamp_uv(hangar, camera, pose, (o.x, o.y)) for o in hangar.lamps if o.id != lamp.id]
    inside = [p for p in others if 5 < p[0] < camera.image_width_px - 5 and 5 < p[1] < 475]
    assert inside
    for p in inside:
        assert dark[round(p[1]), round(p[0])] > THRESHOLD


def test_lamps_off_out_of_view_change_nothing_and_unknown_ids_raise(hangar):
    camera = CAMERAS["default"]
    far = max(hangar.lamps, key=lambda lamp: lamp.x + lamp.y)
    pose = Pose2(2.0, 2.0, 0.0)
    assert np.array_equal(
        render(hangar, camera, pose), render(hangar, camera, pose, lamps_off=[far.id])
    )
    with pytest.raises(ValueError, match="no lamp"):
        render(hangar, camera, pose, lamps_off={len(hangar.lamps)})


def test_occluder_is_a_dark_disc_of_the_projected_size(hangar):
    camera = CAMERAS["default"]
    pose = Pose2(12.0, 9.0, 0.2)
    head = Occluder(12.5, 9.3, 0.15, 1.8)  # a walker's head seen from below
    image = render(hangar, camera, pose, occluders=[head])
    centre = camera.project([(head.x, head.y, head.height)], pose)[0]
    radius = camera.fx * head.radius / (head.height - camera.mount_z)
    angles = np.linspace(0.0, 2.0 * math.pi, 64, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])

    def grey_on_circle(scale):
        pts = np.rint(centre + scale * radius * ring).astype(int)
        return image[pts[:, 1], pts[:, 0]]

    assert (grey_on_circle(0.9) == OCCLUDER_GREY).all()
    assert (grey_on_circle(1.1) == OCCLUDER_GREY).mean() < 0.1
    person = walker(12.3, 9.1)  # a walker 0.3 m from the camera hides part of the view
    hidden = render(hangar, camera, pose, occluders=person)
    assert 0.05 < (hidden == OCCLUDER_GREY).mean() < 0.5
    with pytest.raises(ValueError, match="not above the camera"):
        render(hangar, camera, pose, occluders=[(12.0, 9.0, 0.2, 0.3)])


def test_noise_and_blur_are_seeded(hangar):
    camera = CAMERAS["default"]
    pose = Pose2(9.0, 7.0, -0.4)
    clean = render(hangar, camera, pose)

    def noisy(seed):
        rng = np.random.default_rng(seed)
        return render(hangar, camera, pose, blur_px=1.2, noise_sigma=3.0, rng=rng)

    first = noisy(5)
    assert np.array_equal(first, noisy(5))
    assert not np.array_equal(first, noisy(6))
    blurred = render(hangar, camera, pose, blur_px=1.2)
    residual = first.astype(float) - blurred
    assert abs(residual.mean()) < 0.2
    assert residual.std() == pytest.approx(3.0, rel=0.1)
    assert (
        np.abs(np.diff(blurred.astype(float))).mean() < np.abs(np.diff(clean.astype(float))).mean()
    )
    with pytest.raises(ValueError, match="rng"):
        render(hangar, camera, pose, noise_sigma=1.0)


def test_exposure_and_illumination_gradient(hangar):
    camera = CAMERAS["default"]
    pose = Pose2(9.0, 7.0, 1.0)
    clean = render(hangar, camera, pose).astype(float)
    half = render(hangar, camera, pose, exposure=0.5).astype(float)
    assert np.abs(half - 0.5 * clean).max() <= 0.5 + 1e-9
    graded = render(hangar, camera, pose, gradient=(0.6, 0.0)).astype(float)
    ratio = graded.sum(axis=0) / clean.sum(axis=0)
    assert ratio[:50].mean() == pytest.approx(1.0 - 0.3 * 270 / 320, abs=0.03)
    assert ratio[-50:].mean() == pytest.approx(1.0 + 0.3 * 270 / 320, abs=0.03)
    vignetted = render(hangar, camera, pose, vignetting=1.0).astype(float)
    assert vignetted[0, 0] < 0.5 * clean[0, 0]
    assert vignetted[240, 320] == pytest.approx(clean[240, 320], abs=1.0)


def test_outside_the_ceiling_is_dark(hangar):
    camera = CAMERAS["default"]
    beyond = render(hangar, camera, Pose2(hangar.spec.x_max + 30.0, 9.0, 0.3))
    assert (beyond == OUTSIDE_GREY).all()
    pose = Pose2(hangar.spec.x_max - 1.0, 3.0, 2.2)  # looking over the south-east corner
    image = render(hangar, camera, pose)
    v, u = np.mgrid[: image.shape[0], : image.shape[1]]
    xy = camera.unproject(np.stack([u, v], axis=-1), pose, hangar.spec.height)
    margin = 2.0 * max(camera.footprint(hangar.spec.height))
    s = hangar.spec
    outside = (
        (xy[..., 0] < s.x_min - margin)
        | (xy[..., 0] > s.x_max + margin)
        | (xy[..., 1] < s.y_min - margin)
        | (xy[..., 1] > s.y_max + margin)
    )
    inside = (
        (xy[..., 0] > s.x_min + margin)
        & (xy[..., 0] < s.x_max - margin)
        & (xy[..., 1] > s.y_min + margin)
        & (xy[..., 1] < s.y_max - margin)
    )
    assert outside.sum() > 10_000
    assert inside.sum() > 10_000
    assert (image[outside] == OUTSIDE_GREY).all()
    assert image[inside].mean() > 60.0


# -- the texture ------------------------------------------------------------------------------
def test_repeated_tiles_are_texel_identical_and_look_alike(hangar):
    tiles = hangar.repeated_tiles
    assert len(tiles) == hangar.spec.repeated_tiles >= 2
    first = hangar.image[tiles[0].slices]
    for tile in tiles[1:]:
        assert (tile.row, tile.col) != (tiles[0].row, tiles[0].col)
        assert np.array_equal(hangar.image[tile.slices], first)
    # the camera over two copies sees the same thing; elsewhere something else
    camera = CAMERAS["default"]

    def view_at(col, row):
        x, y = hangar.to_world((col, row))
        image = render(hangar, camera, Pose2(x, y, 0.5)).astype(float)
        return image[215:265, 295:345]  # about the tile (1.6 m is 53 px)

    centres = [(t.col + t.cols / 2 - 0.5, t.row + t.rows / 2 - 0.5) for t in tiles]
    same = np.abs(view_at(*centres[0]) - view_at(*centres[1])).mean()
    other = np.abs(view_at(*centres[0]) - view_at(centres[0][0] + 250, centres[0][1])).mean()
    assert same < 0.25 * other


def test_texture_is_seeded():
    spec = CeilingSpec(x_max=8.0, y_max=6.0, texel=0.02, repeated_tiles=2, seed=1)
    again = CeilingTexture(spec).image
    assert np.array_equal(CeilingTexture(spec).image, again)
    other = CeilingSpec(x_max=8.0, y_max=6.0, texel=0.02, repeated_tiles=2, seed=2)
    assert not np.array_equal(CeilingTexture(other).image, again)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"height": 0.0}, "height"),
        ({"height": math.nan}, "finite"),
        ({"x_max": -1.0}, "x_max"),
        ({"texel": 0.0}, "texel"),
        ({"texel": 0.001}, "coarser texel"),
        ({"lamp_radius": -0.3}, "lamp_radius"),
        ({"lamp_spacing": (1.0, 6.0)}, "overlap"),
        ({"beam_width": 7.0}, "beam_width"),
        ({"purlin_width": 0.0}, "purlin_width"),
        ({"panel_size": (0.0, 1.0)}, "panel_size"),
        ({"lamps": ((5.0, 5.0), (5.5, 5.0))}, "overlap"),
        ({"lamps": ((50.0, 5.0),)}, "outside"),
        ({"repeated_tiles": -1}, "repeated_tiles"),
    ],
)
def test_bad_spec_values_raise(changes, message):
    with pytest.raises(ValueError, match=message):
        CeilingSpec(**{"x_max": 20.0, "y_max": 15.0, **changes})


def test_unplaceable_tiles_and_bad_cameras_raise(one_lamp):
    with pytest.raises(ValueError, match="repeated tiles"):
        CeilingTexture(CeilingSpec(x_max=6.0, y_max=6.0, texel=0.02, repeated_tiles=40))
    with pytest.raises(ValueError, match="focal"):
        UpwardCamera(fx=0.0)
    with pytest.raises(ValueError, match="rate"):
        UpwardCamera(rate=0.0)
    with pytest.raises(ValueError, match="not above"):
        render(one_lamp, UpwardCamera(mount_z=12.5), Pose2(5.0, 5.0, 0.0))
