"""Shared fixtures and paths."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "missions"
CORPUS = REPO / "tests" / "corpus"

SHIPPED_MISSIONS = {
    "a320": MISSIONS / "a320" / "preflight.xml",
    "b737-800": MISSIONS / "b737-800" / "preflight.xml",
    "lab": MISSIONS / "lab" / "visual-servoing.xml",
}


@pytest.fixture(scope="session")
def a320_path() -> Path:
    return SHIPPED_MISSIONS["a320"]
