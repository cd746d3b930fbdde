"""The lasers' blind pockets beside the body and the memory that fills them
(behaviours/laws/blind_spots.py), which vouches for an arc retreat's sweep."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from behaviours.laws.blind_spots import (
    MEMORY_REACH,
    BlindSpotMemory,
    blind_depth,
    pockets_only,
    seen_by,
)
from executive.core.frames import Pose2
from tests.test_safety import mission


def platform():
    return mission().platform


def test_two_end_lasers_leave_pockets_beside_the_middle_of_the_body():
    """The lasers 0.05 m in from the ends of a 1.4 x 1.0 m robot, 270 degrees each: the
    pockets reach 0.15 m out from the sides (|x| + |y| < 0.65), nothing else is unseen."""
    p = platform()
    lasers = p.lasers.values()
    depth = blind_depth(lasers, p.length, p.width, 2.5)
    assert 0.14 <= depth <= 0.2
    assert pockets_only(lasers, p.length, p.width, 2.5)
    beside = np.array([0.0, 0.0, 0.3]), np.array([p.width / 2 + 0.1, -p.width / 2 - 0.1, 0.62])
    assert list(seen_by(lasers, *beside)) == [False, False, True]
    # a front laser alone leaves the whole rear unseen: no pockets a memory could fill
    assert not pockets_only([p.lasers["front"]], p.length, p.width, 2.5)
    narrow = dataclasses.replace(p.lasers["rear"], fov=math.radians(180))
    assert not pockets_only([p.lasers["front"], narrow], p.length, p.width, 2.5)


def scan_of(p, world: np.ndarray, pose: Pose2) -> np.ndarray:
    """The returns the lasers give of the world points at ``pose``: those in view, robot
    frame."""
    robot = pose.inverse().apply(world)
    return robot[seen_by(p.lasers.values(), robot[:, 0], robot[:, 1])]


def test_a_post_passed_close_is_remembered_while_it_is_in_a_pocket():
    """Driving past a post 5 cm off the right side: seen ahead, hidden while abeam (where
    the memory hands it on, at its place in the robot frame), seen again behind, then
    no longer handed on (the scan speaks for it)."""
    p = platform()
    world = np.array([[2.0, -p.width / 2 - 0.05]])
    memory = BlindSpotMemory(p.lasers.values(), p.length, p.width)
    states = []
    for x in np.arange(0.0, 4.0, 0.01):
        pose = Pose2(float(x), 0.0, 0.0)
        points = scan_of(p, world, pose)
        hidden = memory.update(points, pose)
        if len(hidden):
            assert len(points) == 0
            assert np.allclose(hidden, world - [x, 0.0], atol=0.02)
        states.append("seen" if len(points) else "hidden" if len(hidden) else "none")
    runs = [s for k, s in enumerate(states) if k == 0 or s != states[k - 1]]
    assert runs == ["seen", "hidden", "seen"]


def test_a_turn_in_place_keeps_a_remembered_return_where_it_is():
    p = platform()
    world = np.array([[0.0, p.width / 2 + 0.05]])
    memory = BlindSpotMemory(p.lasers.values(), p.length, p.width)
    # seen from further back, then the robot rolls up alongside it and turns a little
    for pose in [Pose2(x, 0.0, 0.0) for x in np.arange(-1.0, 0.0, 0.02)] + [
        Pose2(0.0, 0.0, th) for th in np.linspace(0.0, 0.05, 6)
    ]:
        hidden = memory.update(scan_of(p, world, pose), pose)
    c, s = math.cos(0.05), math.sin(0.05)
    expected = [c * world[0, 0] + s * world[0, 1], c * world[0, 1] - s * world[0, 0]]
    assert len(hidden) == 1 and np.allclose(hidden[0], expected, atol=0.02)


def test_only_returns_near_the_footprint_are_remembered():
    p = platform()
    memory = BlindSpotMemory(p.lasers.values(), p.length, p.width)
    far = np.array([[p.length / 2 + MEMORY_REACH + 0.2, 0.0]])
    memory.update(far, Pose2(0.0, 0.0, 0.0))
    # the robot drives on until that point would lie beside it: nothing is handed on
    assert len(memory.update(np.zeros((0, 2)), Pose2(p.length / 2 + 0.5, 0.0, 0.0))) == 0
