"""Taught routes (behaviours.laws.routes, seed 002 §2.3 key images, §3 repetition).

Recordings are scripted: poses sampled along paths of straight and circular pieces, the
landmarks seen those of a grid of ceiling points within a radius of the robot (the
rendered camera's view is tested in test_ceiling_*; here only the ids matter).
"""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from behaviours.laws.routes import (
    KeyImageRules,
    RecordedImage,
    RouteFollower,
    SparseRecordingError,
    common_landmarks,
    gains_for_settling_distance,
    heading_excursion,
    line_deviation,
    select_key_images,
)
from behaviours.laws.vnhv import Damping, second_order_theory, state_from_poses
from executive.core.frames import Pose2, wrap_angle

GRID = 3.0
"""Metres between the scripted ceiling landmarks."""


def path(start: Pose2, pieces: list[tuple[float, float]], ds: float = 0.05) -> list[Pose2]:
    """Poses every ``ds`` along pieces of (length m, curvature 1/m) from ``start``."""
    x, y, th = start.x, start.y, start.theta
    out = [Pose2(x, y, th)]
    for length, kappa in pieces:
        n = max(1, round(length / ds))
        h = length / n
        for _ in range(n):
            if kappa == 0.0:
                x, y = x + h * math.cos(th), y + h * math.sin(th)
            else:
                th2 = th + kappa * h
                x += (math.sin(th2) - math.sin(th)) / kappa
                y -= (math.cos(th2) - math.cos(th)) / kappa
                th = th2
            out.append(Pose2(x, y, wrap_angle(th)))
    return out


def seen(pose: Pose2, radius: float = 6.0) -> frozenset[str]:
    """The grid landmarks within ``radius`` of the robot."""
    i0, j0 = math.floor(pose.x / GRID), math.floor(pose.y / GRID)
    r = math.ceil(radius / GRID) + 1
    return frozenset(
        f"L{i},{j}"
        for i in range(i0 - r, i0 + r + 1)
        for j in range(j0 - r, j0 + r + 1)
        if math.hypot(i * GRID - pose.x, j * GRID - pose.y) <= radius
    )


def record(poses: list[Pose2], radius: float = 6.0) -> list[RecordedImage]:
    return [RecordedImage(p, seen(p, radius)) for p in poses]


HANGAR_ROUTE = [(20.0, 0.0), (math.pi, 0.5), (8.0, 0.0), (math.pi, 0.5), (12.0, 0.0)]
HANGAR_ROUTE += [(math.pi, -0.5), (10.0, 0.0)]
"""59.4 m: three straights joined by 90 deg turns of radius 2 m, two left, one right."""

pieces = st.lists(
    st.tuples(st.floats(0.2, 6.0), st.sampled_from([0.0, 0.0, 0.25, -0.25, 0.5, -0.5, 1.0, -1.0])),
    min_size=1,
    max_size=6,
)


# -- key images -------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(
    pieces,
    st.floats(math.radians(3.0), math.radians(30.0)),
    st.integers(1, 3),
    st.sampled_from([None, 0.01, 0.05]),
    st.floats(2.0, 9.0),
)
def test_key_images_satisfy_the_rules(pcs, threshold, min_common, deviation, radius):
    rec = record(path(Pose2(1.0, 2.0, 0.3), pcs, ds=0.1), radius)
    rules = KeyImageRules(threshold, min_common, deviation)
    try:
        keys = select_key_images(rec, rules)
    except SparseRecordingError as exc:  # reported only if two neighbours break a rule
        a, b = rec[exc.index], rec[exc.index + 1]
        assert (
            len(common_landmarks(a, b)) < min_common
            or heading_excursion(rec, exc.index, exc.index + 1) >= threshold
        )
        return
    assert keys[0] == 0 and keys[-1] == len(rec) - 1
    assert all(b > a for a, b in itertools.pairwise(keys))
    for a, b in itertools.pairwise(keys):
        assert len(common_landmarks(rec[a], rec[b])) >= min_common  # rule 1
        turn = abs(wrap_angle(rec[b].pose_m.theta - rec[a].pose_m.theta))
        # rule 2 between the key images themselves (the law sums the wrapped steps: the
        # direct difference may round to the threshold itself)
        assert turn < threshold + 1e-12
        assert heading_excursion(rec, a, b) < threshold  # and along the stretch
        if deviation is not None and b > a + 1:
            assert line_deviation(rec, a, b) <= deviation
        # greedy: no later image satisfies the rules with key a
        for j in range(b + 1, len(rec)):
            if heading_excursion(rec, a, j) >= threshold:
                break
            fits = deviation is None or line_deviation(rec, a, j) <= deviation
            assert not (len(common_landmarks(rec[a], rec[j])) >= min_common and fits)


def test_a_straight_run_is_cut_where_the_landmarks_change():
    rec = record(path(Pose2(0.0, 0.0, 0.0), [(30.0, 0.0)]), radius=6.0)
    keys = select_key_images(rec)
    gaps = [rec[b].pose_m.x - rec[a].pose_m.x for a, b in itertools.pairwise(keys)]
    assert len(keys) >= 3  # 12 m of view: a 30 m run needs intermediate key images
    assert all(g < 12.0 + 1e-9 for g in gaps)
    assert max(gaps) > 8.0  # but no more than the common landmark forces


def test_a_turn_gets_one_key_image_per_threshold():
    rec = record(path(Pose2(0.0, 0.0, 0.0), [(math.pi, 0.5)], ds=0.02))  # 90 deg
    rules = KeyImageRules(math.radians(10.0), max_deviation=None)
    keys = select_key_images(rec, rules)
    assert len(keys) - 1 == 10  # ceil(90 / 10 - eps): 9.99 deg steps need 10 stretches


def test_the_paper_rules_alone_accept_a_line_beside_the_path():
    """Why the fit condition exists: a turn's first key image, a few degrees round, passes
    both rules with an image 8 m back on the straight, and its line runs beside it."""
    rec = record(path(Pose2(0.0, 0.0, 0.0), [(8.0, 0.0), (0.2, 0.5)], ds=0.05), radius=9.0)
    loose = select_key_images(rec, KeyImageRules(max_deviation=None))
    assert loose == (0, len(rec) - 1)
    assert line_deviation(rec, 0, len(rec) - 1) > 0.3
    tight = select_key_images(rec, KeyImageRules())
    assert all(line_deviation(rec, a, b) <= 0.02 for a, b in itertools.pairwise(tight))


def test_a_too_sparse_recording_is_reported():
    poses = path(Pose2(0.0, 0.0, 0.0), [(10.0, 0.0)], ds=0.5)
    rec = record(poses)
    rec[7] = RecordedImage(rec[7].pose_m, frozenset({"elsewhere"}))  # the landmarks lost
    with pytest.raises(SparseRecordingError) as exc:
        select_key_images(rec)
    assert exc.value.index == 6 and "rule 1" in exc.value.reason
    turned = record(path(Pose2(0.0, 0.0, 0.0), [(1.0, 0.0), (0.4, 0.5)], ds=0.4))
    with pytest.raises(SparseRecordingError, match="rule 2"):
        select_key_images(turned, KeyImageRules(math.radians(5.0)))
    with pytest.raises(ValueError):
        select_key_images([])
    single = select_key_images(record([Pose2(0.0, 0.0, 0.0)]))
    assert single == (0,)


def test_rules_refuse_meaningless_thresholds():
    for bad in (0.0, -1.0, math.radians(95.0), math.nan):
        with pytest.raises(ValueError):
            KeyImageRules(bad)
    with pytest.raises(ValueError):
        KeyImageRules(min_common=0)
    with pytest.raises(ValueError):
        KeyImageRules(max_deviation=0.0)


# -- gains --------------------------------------------------------------------------------------
@pytest.mark.parametrize("distance", [0.5, 1.5, 4.0])
def test_gains_settle_in_the_distance_asked(distance):
    gains = gains_for_settling_distance(distance)
    theory = second_order_theory(gains)
    assert theory.damping is Damping.CRITICAL
    assert theory.settling_distance == pytest.approx(distance, rel=1e-6)


# -- repeating ----------------------------------------------------------------------------------
def unicycle(
    follower: RouteFollower, start: Pose2, dt: float = 0.02, limit: int = 40_000
) -> tuple[np.ndarray, list]:
    """Integrate the follower's commands exactly (arcs); the poses and the steps."""
    x, y, th = start.x, start.y, start.theta
    poses, steps = [(x, y, th)], []
    for _ in range(limit):
        step = follower.step(Pose2(x, y, th))
        steps.append(step)
        if step.done:
            break
        if abs(step.omega) < 1e-12:
            x += step.v * math.cos(th) * dt
            y += step.v * math.sin(th) * dt
        else:
            r = step.v / step.omega
            th2 = th + step.omega * dt
            x += r * (math.sin(th2) - math.sin(th))
            y -= r * (math.cos(th2) - math.cos(th))
            th = th2
        poses.append((x, y, wrap_angle(th)))
    return np.array(poses), steps


def deviation_from(taught: list[Pose2], xy: np.ndarray) -> np.ndarray:
    """Distance of each point to the taught polyline."""
    a = np.array([(p.x, p.y) for p in taught[:-1]])
    b = np.array([(p.x, p.y) for p in taught[1:]])
    ab = b - a
    out = np.empty(len(xy))
    for k, q in enumerate(xy):
        t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        out[k] = np.min(np.hypot(*(a + t[:, None] * ab - q).T))
    return out


def test_the_route_is_repeated_on_the_taught_path_from_an_offset():
    taught = path(Pose2(5.0, 5.0, 0.0), HANGAR_ROUTE)
    rec = record(taught[::4])
    keys = [rec[k].pose_m for k in select_key_images(rec)]
    follower = RouteFollower(keys, 0.5, gains_for_settling_distance(1.5), 1.0, 1.0)
    start = taught[0] @ Pose2(0.0, 0.5, math.radians(10.0))
    poses, steps = unicycle(follower, start)
    assert steps[-1].done
    assert [s.target for s in steps if s.switched] == [*list(range(2, len(keys))), len(keys) - 1]
    dev = deviation_from(taught, poses[:, :2])
    travelled = np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]
    after = dev[travelled > 3.0]  # twice the settling distance from the start offset
    assert np.percentile(after, 95) < 0.01 and after.max() < 0.015
    end = Pose2(*poses[-1])
    assert state_from_poses(end, keys[-1]).s == pytest.approx(0.0, abs=0.02)


def test_omega_does_not_jump_when_the_key_image_switches():
    taught = path(Pose2(0.0, 0.0, 0.0), HANGAR_ROUTE[:4])
    rec = record(taught[::4])
    keys = [rec[k].pose_m for k in select_key_images(rec)]
    gains = gains_for_settling_distance(1.5)
    for blend, bound in ((0.3, 0.03), (0.0, None)):
        follower = RouteFollower(keys, 0.5, gains, 1.0, 1.0, blend=blend)
        _, steps = unicycle(follower, keys[0])
        omega = np.array([s.omega for s in steps[:-1]])
        jumps = np.abs(np.diff(omega))
        at_switch = [jumps[k - 1] for k, s in enumerate(steps[:-1]) if s.switched and k > 0]
        assert len(at_switch) >= 10
        if bound is not None:  # blended: a switch is no rougher than the turns themselves
            assert max(at_switch) < bound
            assert jumps.max() < bound
        else:  # the bare switch the blend prevents
            assert max(at_switch) > 0.1


def test_a_route_taught_backwards_is_repeated_backwards():
    """Taught reversing (the robot faces +x and drives towards -x, then curves): V < 0."""
    forward = path(Pose2(0.0, 0.0, math.pi), [(6.0, 0.0), (math.pi / 2, 0.5), (4.0, 0.0)])
    taught = [Pose2(p.x, p.y, wrap_angle(p.theta + math.pi)) for p in forward]  # facing back
    rec = record(taught[::2])
    keys = [rec[k].pose_m for k in select_key_images(rec)]
    follower = RouteFollower(keys, -0.4, gains_for_settling_distance(1.0), 1.0, 1.0)
    start = taught[0] @ Pose2(0.0, -0.3, math.radians(-8.0))
    poses, steps = unicycle(follower, start)
    assert steps[-1].done
    assert all(s.v < 0.0 for s in steps[:-1])
    heading = np.array(
        [
            wrap_angle(p[2] - math.atan2(dy, dx) - math.pi)
            for p, (dx, dy) in zip(poses[1:], np.diff(poses[:, :2], axis=0), strict=False)
        ]
    )
    assert np.all(np.abs(heading) < math.radians(20.0))  # it moves towards its back
    dev = deviation_from(taught, poses[:, :2])
    travelled = np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]
    assert dev[travelled > 2.0].max() < 0.015


def test_speed_is_lowered_to_keep_omega_within_the_limit_and_to_stop_at_the_end():
    keys = [Pose2(0.0, 0.0, 0.0), Pose2(10.0, 0.0, 0.0)]
    gains = gains_for_settling_distance(1.0)
    follower = RouteFollower(keys, 1.0, gains, 0.2, 0.5)
    step = follower.step(Pose2(0.0, 1.0, 0.0))  # 1 m off the line: eq. 12 asks a lot
    assert abs(step.omega) == pytest.approx(0.2) and 0.0 < step.v < 1.0
    near = follower.step(Pose2(9.9, 0.0, 0.0))
    assert near.v == pytest.approx(math.sqrt(2.0 * 0.5 * 0.1))
    assert follower.step(Pose2(10.0, 0.0, 0.0)).done
    with pytest.raises(ValueError):
        RouteFollower(keys[:1], 1.0, gains, 1.0, 1.0)
    with pytest.raises(ValueError):
        RouteFollower(keys, 0.0, gains, 1.0, 1.0)
