"""Shared fixtures and paths."""

import time
from collections.abc import Callable
from pathlib import Path

import cv2
import py_trees
import pytest

from tests import durations

# One thread per test worker, as OPENBLAS_NUM_THREADS=1 does for numpy: pytest-xdist
# already runs a worker per core, and OpenCV's own pool (ORB, warps in the ceiling tests)
# would crowd the HIL rig's real-time processes out of the other core (a lost 0.1 s base
# heartbeat is a link loss by design).
cv2.setNumThreads(1)

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "missions"
CORPUS = REPO / "tests" / "corpus"

SHIPPED_MISSIONS = {
    "a320": MISSIONS / "a320" / "preflight.xml",
    "b737-800": MISSIONS / "b737-800" / "preflight.xml",
    "lab": MISSIONS / "lab" / "visual-servoing.xml",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Longest tests first, as recorded in tests/durations.json (tests/durations.py says
    why); the others after them, in collection order."""
    recorded = durations.load()
    items.sort(key=lambda item: -recorded.get(durations.test_id(item.nodeid), 0.0))


@pytest.fixture(scope="session")
def a320_path() -> Path:
    return SHIPPED_MISSIONS["a320"]


@pytest.fixture
def fresh_blackboard():
    """An empty py_trees blackboard for the test, and none left behind."""
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


def blackboard_writer(*keys):
    """A blackboard client that may write ``keys`` (behaviours.keys.Key)."""
    client = py_trees.blackboard.Client(name="test")
    for key in keys:
        client.register_key(key=key.name, access=py_trees.common.Access.WRITE)
    return client


def wait_until(predicate: Callable[[], object], timeout: float, what: str) -> None:
    """Poll ``predicate`` every 50 ms of wall time (another process or thread moves the
    world); fail naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")
