"""When did a sensor last deliver *new* data? (ARCHITECTURE.md §8: every sensor is watched.)

A reading is new data when its stamp is later than the previous reading's stamp, and, for
a sensor whose readings carry noise (a camera's detections), when its content differs from
the previous reading's: a frozen camera pipeline may go on publishing its last image with
fresh stamps, but two live images never give identical detections down to the sub-pixel
noise. Empty content (nothing seen) is not evidence either way and counts as new.

A sensor is stale at ``now`` when its last new data is older than ``limit`` seconds (or it
never delivered any): ``not now - last_fresh <= limit``. :attr:`Freshness.last_fresh` is
the precise "stale from" time: the stamp of the last fresh reading.

Pure Python, no py_trees: the safety layer watches every sensor with it, and the
inspection behaviour uses the same law to accept only fresh images.
"""

from __future__ import annotations

import math
from collections.abc import Hashable


class Freshness:
    """The freshness of one sensor: feed it every reading with :meth:`observe`."""

    __slots__ = ("_content", "last_fresh", "last_stamp", "limit", "repeats_are_stale")

    def __init__(self, limit: float, repeats_are_stale: bool = False) -> None:
        if not limit >= 0.0:
            raise ValueError(f"the stale limit must be >= 0 s, got {limit}")
        self.limit = float(limit)
        self.repeats_are_stale = repeats_are_stale
        self.last_stamp: float | None = None
        """Stamp of the latest reading seen, fresh or repeated."""
        self.last_fresh: float | None = None
        """Stamp of the latest reading that was new data (None: none yet)."""
        self._content: Hashable | None = None

    def observe(self, stamp: float | None, content: Hashable | None = None) -> bool:
        """Take the sensor's latest reading (None: it has none); True if it is new data.

        The same reading seen again (same stamp, or a non-finite one) is ignored; a
        reading older than the previous one is not new data, and the data in hand is now
        that old (a sensor never looks fresher by going back in time). With
        ``repeats_are_stale``, a later reading whose non-empty ``content`` equals the
        previous reading's is a repeat: it moves :attr:`last_stamp`, not
        :attr:`last_fresh`.
        """
        if stamp is None or not math.isfinite(stamp):
            return False
        if self.last_stamp is not None and stamp == self.last_stamp:
            return False
        if self.last_stamp is not None and stamp < self.last_stamp:
            # an older reading than the last one: the data in hand is that old
            self.last_stamp = stamp
            self._content = content
            self.last_fresh = stamp if self.last_fresh is None else min(self.last_fresh, stamp)
            return False
        previous = self._content
        self.last_stamp = stamp
        self._content = content
        if (
            self.repeats_are_stale
            and content is not None
            and previous is not None
            and (content is previous or content == previous)
        ):
            return False
        self.last_fresh = stamp
        return True

    def age(self, now: float) -> float:
        """Seconds since the last fresh reading (inf: never had one)."""
        return math.inf if self.last_fresh is None else now - self.last_fresh

    def stale(self, now: float) -> bool:
        """Whether the last fresh reading is older than :attr:`limit` (or missing)."""
        return not self.age(now) <= self.limit
