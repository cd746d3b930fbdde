"""Properties of the loader: whatever the input, a valid model or reported problems.

Arbitrary bytes and mutations of the shipped A320 mission must never raise anything but
:class:`InvalidInputError` from ``load_*`` and never raise at all from ``check_file``.
"""

import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from executive.core.loader import check_file, load_aircraft, load_mission
from executive.core.model import Mission
from executive.core.problems import InvalidInputError, Problem
from tests.conftest import MISSIONS

A320_MISSION = (MISSIONS / "a320" / "preflight.xml").read_text(encoding="utf-8")
A320_AIRCRAFT = (MISSIONS / "a320" / "aircraft.xml").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def library():
    """A private copy of the A320 folder; each example overwrites its mutated file."""
    root = Path(tempfile.mkdtemp(prefix="walkaround-prop-"))
    shutil.copytree(MISSIONS / "a320", root / "a320")
    yield root
    shutil.rmtree(root, ignore_errors=True)


def _outcome(path: Path, loader):
    problems = check_file(path)
    assert isinstance(problems, list)
    assert all(isinstance(p, Problem) and p.message for p in problems)
    try:
        model = loader(path)
    except InvalidInputError as exc:
        assert problems, "load raised but check_file found nothing"
        assert set(exc.problems) == set(problems)
        return None
    assert not problems
    return model


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.binary(max_size=2048))
def test_arbitrary_bytes_never_crash(library, data):
    path = library / "a320" / "fuzz.xml"
    path.write_bytes(data)
    assert _outcome(path, load_mission) is None  # random bytes are never a valid mission


@st.composite
def mutated(draw, text: str) -> str:
    """A valid document with a few random edits: deletions, insertions, value swaps."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["delete", "insert", "replace-value", "duplicate-line"]))
        if kind == "delete":
            i = draw(st.integers(0, len(text) - 1))
            j = draw(st.integers(i, min(len(text), i + 40)))
            text = text[:i] + text[j:]
        elif kind == "insert":
            i = draw(st.integers(0, len(text)))
            junk = draw(
                st.sampled_from(
                    ["<", ">", '"', "&", "&amp;", "<x/>", "-1", "1e999", "NaN", ' id="a"', "]]>"]
                )
                | st.text(max_size=8)
            )
            text = text[:i] + junk + text[i:]
        elif kind == "replace-value":
            starts = [k for k in range(len(text)) if text.startswith('="', k)]
            if starts:
                k = draw(st.sampled_from(starts)) + 2
                end = text.find('"', k)
                value = draw(
                    st.sampled_from(["", "0", "-5", "1e6", "x", "CP01", "0.0001", "999"])
                    | st.text(alphabet="abc-_.019 ", max_size=6)
                )
                text = text[:k] + value + text[end:]
        else:
            lines = text.splitlines(keepends=True)
            i = draw(st.integers(0, len(lines) - 1))
            lines.insert(i, lines[i])
            text = "".join(lines)
    return text


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mutated(A320_MISSION))
def test_mutated_mission_gives_model_or_problems(library, text):
    path = library / "a320" / "mutant.xml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    model = _outcome(path, load_mission)
    assert model is None or isinstance(model, Mission)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mutated(A320_AIRCRAFT))
def test_mutated_aircraft_gives_model_or_problems(library, text):
    path = library / "a320" / "aircraft-mutant.xml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    _outcome(path, load_aircraft)
