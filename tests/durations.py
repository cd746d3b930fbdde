"""The test suite's recorded durations, longest first: the order xdist hands tests out.

pytest-xdist gives each worker the next test (``--dist loadgroup``: the next group)
in collection order. In file order the README's main job, the longest test (a whole A320
dry-run), came near the end, and one worker ran it alone for minutes after the other had
finished: with the longest tests first, the short ones fill the gaps at the end (the
longest-processing-time rule). ``durations.json`` maps test ids to seconds (setup and
call) measured in a CI run; tests not in it keep their collection order after those in
it, so a stale file costs time, never a test.

Refresh it from a CI log run with ``--durations=0``::

    python tests/durations.py < ci.log > tests/durations.json
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path

FILE = Path(__file__).with_name("durations.json")
SHORTEST = 10.0
"""Seconds below which a test is not recorded: the order of short tests hardly matters."""

_LINE = re.compile(r"^\s*([0-9.]+)s (setup|call|teardown)\s+(\S+)")


def load(path: Path = FILE) -> dict[str, float]:
    """Recorded seconds by test id (empty when there is no file)."""
    if not path.exists():
        return {}
    return {str(k): float(v) for k, v in json.loads(path.read_text()).items()}


def parse(lines: Iterable[str]) -> dict[str, float]:
    """Seconds per test id (its setup, call and teardown summed) from pytest's
    ``--durations`` report, the ``SHORTEST`` and longer ones, longest first."""
    total: dict[str, float] = {}
    for line in lines:
        match = _LINE.match(line)
        if match:
            seconds, _, test = match.groups()
            total[test] = total.get(test, 0.0) + float(seconds)
    kept = {k: round(v, 1) for k, v in total.items() if v >= SHORTEST}
    return dict(sorted(kept.items(), key=lambda kv: -kv[1]))


def test_id(nodeid: str) -> str:
    """``nodeid`` without the ``@group`` suffix pytest-xdist gives a grouped test."""
    return nodeid.split("@", 1)[0]


if __name__ == "__main__":
    json.dump(parse(sys.stdin), sys.stdout, indent=1)
    sys.stdout.write("\n")
