"""The pose filter's recent poses, for measurements that arrive late.

A laser registration or a ceiling fix is computed from data stamped some time ago (a
scan, an image); the filter has moved on since. Its poses over the last ``horizon``
seconds let the measurement's prior be the pose *at its stamp*, and its result be carried
forward to now (``pose_then.inverse() @ pose_now``).
"""

from __future__ import annotations

from collections import deque

from executive.core.frames import Pose2


class PoseHistory:
    """(stamp, pose in A) samples of the last ``horizon`` seconds, oldest first."""

    def __init__(self, horizon: float) -> None:
        self.horizon = horizon
        self._poses: deque[tuple[float, Pose2]] = deque()

    def record(self, stamp: float, pose_a: Pose2) -> None:
        """Remember the filter's pose at ``stamp`` (call after every prediction)."""
        poses = self._poses
        poses.append((stamp, pose_a))
        while poses and poses[0][0] < stamp - self.horizon:
            poses.popleft()

    def at(self, stamp: float, default: Pose2) -> Pose2:
        """The pose of the sample nearest ``stamp`` (``default`` when there is none)."""
        if not self._poses:
            return default
        return min(self._poses, key=lambda sp: abs(sp[0] - stamp))[1]
