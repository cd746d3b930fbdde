"""Collaborative mode: follow the operator (seed 000 lines 1379-1452, Table 2.3; issue 15).

A thin adapter over :mod:`behaviours.laws.follow`. The operator designates a person on
the HUD (:attr:`executive.core.records.OperatorRequests.follow`, a point in A and a
distance); one :class:`FollowSession` per tree holds the follower law and feeds it the
laser tracks (:data:`behaviours.keys.OBSTACLES`, robot frame) placed in A with the pose
estimate, once per tick whichever node asks first. Its nodes:

* :class:`OperatorLost` (guard): a follow request is pending and the person is lost (not
  seen for ``lost_after`` s, or nobody at the designated point);
* :class:`AskOperator` (controller): holds the robot still and asks "operator lost:
  designate again" (:data:`behaviours.keys.QUESTION`) until a new designation;
* :class:`FollowRequested` (guard): a follow request is pending and the person is not lost;
* :class:`FollowOperator` (controller): the law's command along the person's trail.

The guards' feedback says which track, which gap, lost or not: the runtime logs it with
every controller switch (``follow operator``, ``hold: operator lost``). An operator's
abort ends the follow request it finds (the operator's state clears it); a follow asked
for after the abort is followed (the operator has the robot again).
"""

from __future__ import annotations

import math

import numpy as np
import py_trees

from behaviours.base import Controller, Guard, Node
from behaviours.keys import COMMAND, OBSTACLES, OPERATOR, POSE, QUESTION, OperatorQuestion
from behaviours.laws.follow import (
    LOST,
    FollowCommand,
    FollowParams,
    OperatorFollower,
    PersonTrack,
)
from executive.core.frames import Pose2
from executive.core.model import Platform
from executive.core.records import (
    Obstacles,
    OperatorRequests,
    PoseEstimate,
    TrackedObstacle,
    VelocityCommand,
)

Status = py_trees.common.Status

LOST_QUESTION = "operator lost: designate again"
"""The question put to the operator when the person is lost (the HUD shows it)."""

LOST_CHOICES = ("wait",)
"""The answers offered with it: designating again is the real answer (a new follow
request); "wait" only acknowledges."""


def track_in_airport(track: TrackedObstacle, pose_a: Pose2) -> PersonTrack:
    """A tracked obstacle (robot frame R) as a :class:`PersonTrack` in A; a circle by its
    fitted centre and radius."""
    centre = track.position
    size = track.size
    if track.kind == "circle" and len(track.shape) == 3:
        centre = (track.shape[0], track.shape[1])
        size = track.shape[2]
    x, y = pose_a.apply(np.asarray(centre, dtype=float))
    c, s = math.cos(pose_a.theta), math.sin(pose_a.theta)
    vx, vy = track.velocity
    return PersonTrack(
        track.id, track.kind, (float(x), float(y)), (c * vx - s * vy, s * vx + c * vy), size
    )


class FollowSession:
    """The follower of one tree, shared by its guards and controllers.

    :meth:`observe` is called by every node of the follow branches; it works once per
    obstacle estimate (its stamp), so the order of the nodes does not matter.
    """

    def __init__(self, platform: Platform, r_es: float, period: float) -> None:
        default = FollowParams()
        self.params = FollowParams(
            length=platform.length,
            width=platform.width,
            r_es=r_es,
            max_speed=min(default.max_speed, platform.max_speed),
            max_omega=min(default.max_omega, platform.max_angular_speed),
            brake=0.5 * platform.max_acceleration,
            period=period,
        )
        self.follower = OperatorFollower(self.params)
        self.request: tuple[float, float, float] | None = None
        self.losses = 0
        self._stamp: float | None = None
        self.last: FollowCommand | None = None

    @property
    def requested(self) -> bool:
        return self.request is not None

    @property
    def lost(self) -> bool:
        return self.requested and self.follower.state == LOST

    def observe(
        self, operator: OperatorRequests, pose: PoseEstimate | None, obstacles: Obstacles | None
    ) -> None:
        """Take this tick's request and tracks (once per obstacle stamp)."""
        follow = operator.follow
        if follow is None:
            if self.request is not None:
                self.follower.cancel()
            self.request = None
            return
        stamp = obstacles.stamp if obstacles is not None else None
        key = (follow.x, follow.y, follow.distance)
        if key != self.request:
            self.request = key
            self.follower.designate(
                stamp if stamp is not None else follow.stamp, (follow.x, follow.y), follow.distance
            )
        if pose is None or obstacles is None or stamp == self._stamp:
            return
        self._stamp = stamp
        was_lost = self.follower.state == LOST
        tracks = [track_in_airport(t, pose.pose_a) for t in obstacles.tracks if t.kind != "zone"]
        self.follower.observe(obstacles.stamp, pose.pose_a, tracks)
        if self.follower.state == LOST and not was_lost:
            self.losses += 1

    def describe(self) -> str:
        f = self.follower
        if not self.requested:
            return "no person designated"
        ident = f"track {f.track_id}" if f.track_id is not None else "no track"
        return f"{f.state}, {ident}: {f.reason}"


class _FollowNode:
    """Reads the request, the pose and the tracks and feeds the session."""

    session: FollowSession

    def _observe(self, node: Node) -> PoseEstimate | None:
        operator: OperatorRequests = node.read(OPERATOR, OperatorRequests())
        pose: PoseEstimate | None = node.read(POSE)
        self.session.observe(operator, pose, node.read(OBSTACLES))
        return pose


class FollowRequested(_FollowNode, Guard):
    """SUCCESS while a person is designated and not lost (searching for them included)."""

    reads = (OPERATOR, POSE, OBSTACLES)

    def __init__(self, session: FollowSession, name: str = "follow requested?") -> None:
        super().__init__(name)
        self.session = session

    def update(self) -> Status:
        self._observe(self)
        self.feedback_message = self.session.describe()
        ok = self.session.requested and not self.session.lost
        return Status.SUCCESS if ok else Status.FAILURE


class OperatorLost(_FollowNode, Guard):
    """SUCCESS while a person is designated but lost: the robot stops and asks."""

    reads = (OPERATOR, POSE, OBSTACLES)

    def __init__(self, session: FollowSession, name: str = "operator lost?") -> None:
        super().__init__(name)
        self.session = session

    def update(self) -> Status:
        self._observe(self)
        lost = self.session.lost
        self.feedback_message = self.session.follower.reason if lost else "not lost"
        return Status.SUCCESS if lost else Status.FAILURE


class FollowOperator(_FollowNode, Controller):
    """The follower law's command: along the person's trail, at the set gap."""

    reads = (OPERATOR, POSE, OBSTACLES)
    writes = (COMMAND,)

    def __init__(self, session: FollowSession, name: str = "follow operator") -> None:
        super().__init__(name)
        self.session = session

    def update(self) -> Status:
        pose = self._observe(self)
        if pose is None:
            self.write(COMMAND, VelocityCommand.stop())
            self.feedback_message = "no pose estimate: stop"
            return Status.RUNNING
        out = self.session.follower.command(pose.pose_a)
        self.session.last = out
        self.write(COMMAND, VelocityCommand(out.v, out.omega))
        self.feedback_message = f"{out.state}: {out.reason}, v {out.v:.2f} m/s"
        return Status.RUNNING


class AskOperator(Controller):
    """Holds the robot still and asks the operator to designate the person again."""

    writes = (COMMAND, QUESTION)

    def __init__(self, session: FollowSession, name: str = "hold: operator lost") -> None:
        super().__init__(name)
        self.session = session

    def update(self) -> Status:
        self.write(COMMAND, VelocityCommand.stop())
        follower = self.session.follower
        self.write(
            QUESTION,
            OperatorQuestion(
                follower.now, f"operator-lost-{self.session.losses}", LOST_QUESTION, LOST_CHOICES
            ),
        )
        self.feedback_message = follower.reason
        return Status.RUNNING
