"""Properties of ``walkaround validate`` and of what it accepts (issue 12, section 1).

(a) Mutating attribute values of every shipped file kind (aircraft, mission, scenario)
    with adversarial numbers and strings, ``validate`` exits 0 or 2 and never prints a
    traceback, nor turns a crash into an ``internal-error`` problem.
(b) Whatever ``validate`` accepts, a short dry-run of it runs or is refused as bad input:
    never a traceback, a hang or unbounded memory. The dry-runs happen in one worker
    process with a memory limit (``RLIMIT_AS``), each with a wall-clock timeout as the
    hang detector and a few simulated seconds (``max_time``).

Values for (b) are drawn mostly inside each attribute's range as the XSD states it (its
bounds, values just inside them, random values between), because the question is
whether the ranges are tight enough that every accepted value can be simulated.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import resource
import select
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from executive.cli import main
from executive.core.resources import missions_dir, schema_path
from executive.core.xmlsafe import Range, attribute_ranges

REPO = Path(__file__).resolve().parent.parent

# Shipped files of every kind, small enough to validate many times in a minute (the A320
# aircraft is included: it is the biggest aircraft file; its mission takes seconds).
AIRCRAFT = ["track/aircraft.xml", "lab/aircraft.xml", "a320/aircraft.xml"]
MISSIONS = ["track/straight-run.xml", "lab/visual-servoing.xml", "track/avoidance-leg.xml"]
SCENARIOS = [
    "track/scenarios/straight-run-40m.xml",
    "track/scenarios/clear-apron.xml",
    "lab/scenarios/clear-apron.xml",
    "track/scenarios/props.xml",  # written below: every scenario element
]
# What to validate with the mutated file: the file itself and one file that uses it.
USERS = {
    "track/aircraft.xml": ["track/straight-run.xml"],
    "lab/aircraft.xml": ["lab/visual-servoing.xml"],
    "a320/aircraft.xml": [],
    "track/straight-run.xml": ["track/scenarios/props.xml"],
    "lab/visual-servoing.xml": ["lab/scenarios/clear-apron.xml"],
    "track/avoidance-leg.xml": [],
}

PROPS_SCENARIO = """<?xml version="1.0" encoding="UTF-8"?>
<scenario xmlns="urn:walkaround:scenario:1" id="track-props" mission="../straight-run.xml"
          seed="3" duration="600">
  <description>Every scenario element, acting in the first seconds of the run.</description>
  <parking-offset dx="0.2" dy="-0.1" dheading-deg="1"/>
  <start x="0" y="0" heading-deg="0"/>
  <physics rate-hz="100"/>
  <noise laser-range="0.01" pixel="0.5" camera-dropout="0.02" wheel="0.01" imu-rate="0.002"
         imu-bias="0.002" gps="0.03"/>
  <slip longitudinal="0.02" turn="0.2" lateral="0.05"/>
  <gps mode="open" rate-hz="5" shadow-margin="1"/>
  <obstacles>
    <box id="car" kind="vehicle" x="10" y="2.5" heading-deg="10" length="4" width="1.8"
         height="1.5"/>
    <circle id="bin" kind="equipment" x="5" y="-2.5" radius="0.5" height="1"/>
    <path id="walker" kind="person" radius="0.3" height="1.8" speed="1.2" start-time="0.5"
          trigger-radius="8" loop="true">
      <waypoint x="4" y="-4"/><waypoint x="4" y="4"/>
    </path>
    <group id="crew" x="7" y="5" radius="2" count="4" speed="0.8" person-radius="0.3"
           height="1.8"/>
    <chaser id="trolley" kind="trolley" x="8" y="-4" length="1.2" width="0.8" height="1"
            speed="0.5" trigger-radius="10" pursuit="20"/>
  </obstacles>
  <faults>
    <laser-dropout laser="front" at="0.5" duration="0.5"/>
    <camera-freeze camera="front-left" at="1" duration="1"/>
    <gps-loss at="1.5" duration="1"/>
    <slip-burst at="2" duration="1" factor="3"/>
    <bumper-hit bumper="rear" at="3" duration="0.5"/>
  </faults>
</scenario>
"""

_ATTRIBUTE = re.compile(r"""<([\w:.\-]+)\b|\s([\w:.\-]+)\s*=\s*"([^"]*)\"""")


def _attributes(text: str) -> list[tuple[str, str, int, int]]:
    """(element, attribute, start, end of the value) of every attribute, in order."""
    found = []
    element = ""
    for m in _ATTRIBUTE.finditer(text):
        if m.group(1):
            element = m.group(1)
        elif not m.group(2).startswith("xmlns"):
            found.append((element, m.group(2), m.start(3), m.end(3)))
    return found


def _source_text(name: str) -> str:
    """The unmutated text of a library file (the props scenario is this module's)."""
    if name.endswith("props.xml"):
        return PROPS_SCENARIO
    return (missions_dir() / name).read_text(encoding="utf-8")


def _escape(value: str) -> str:
    return value.replace("&", "&amp;").replace("<", "&lt;").replace('"', "&quot;")


@pytest.fixture(scope="module")
def library() -> Iterator[Path]:
    """A private copy of the shipped library (each example restores what it changed)."""
    root = Path(tempfile.mkdtemp(prefix="walkaround-validate-prop-"))
    shutil.copytree(missions_dir(), root, dirs_exist_ok=True)
    (root / "track" / "scenarios" / "props.xml").write_text(PROPS_SCENARIO, encoding="utf-8")
    yield root
    shutil.rmtree(root, ignore_errors=True)


def _validate(*paths: Path) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(["validate", *map(str, paths)])
        except SystemExit as exc:  # argparse; never expected here
            status = int(exc.code or 0)
    return status, out.getvalue() + err.getvalue()


@contextlib.contextmanager
def _mutated(path: Path, edits: list[tuple[int, int, str]]) -> Iterator[None]:
    """``path`` with values replaced (start, end, new text), restored afterwards."""
    original = path.read_bytes()
    text = original.decode("utf-8")
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    try:
        path.write_bytes(text.encode("utf-8", errors="surrogatepass"))
        yield
    finally:
        path.write_bytes(original)


# -- (a) validate never crashes --------------------------------------------------------------
ADVERSARIAL_NUMBERS = [
    "1e308", "-1e308", "1e309", "1e-320", "4.9e-324", "0", "-0", "-1", "NaN", "nan", "INF",
    "-INF", "Infinity", "+1", "1.", ".5", "0x10", "1_000", "1e", "--1", "1e-9", "1e9",
    "99999999999999999999", "0.1e400",
]  # fmt: skip


def adversarial_value() -> st.SearchStrategy[str]:
    """Huge, tiny, negative, NaN, inf, long digit strings, empty, unicode, very long."""
    return st.one_of(
        st.sampled_from(ADVERSARIAL_NUMBERS),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-(10**40), 10**40).map(str),
        st.integers(20, 6000).map(lambda n: "9" * n),
        st.integers(20, 6000).map(lambda n: "+" + "0" * n + "7"),  # long, yet small
        st.integers(1000, 20000).map(lambda n: "a/" * (n // 2)),
        st.just(""),
        st.text(max_size=12),
        st.text(alphabet="éß中𝔘\u200b\u202e ", min_size=1, max_size=6),
    )


@st.composite
def mutation(draw: st.DrawFn, files: list[str]) -> tuple[str, list[tuple[int, str]]]:
    """A shipped file and 1 to 3 of its attributes (by index) with adversarial values."""
    name = draw(st.sampled_from(files))
    count = len(_attributes(_source_text(name)))
    picks = draw(
        st.lists(st.integers(0, count - 1), min_size=1, max_size=3, unique=True).flatmap(
            lambda idx: st.tuples(*(st.tuples(st.just(i), adversarial_value()) for i in idx))
        )
    )
    return name, list(picks)


def _check_validate_survives(library: Path, name: str, picks: list[tuple[int, str]]) -> None:
    path = library / name
    attrs = _attributes(path.read_text(encoding="utf-8"))
    edits = [(attrs[i][2], attrs[i][3], _escape(value)) for i, value in picks]
    with _mutated(path, edits):
        status, output = _validate(path, *(library / u for u in USERS.get(name, [])))
    event(f"validate exit {status}")
    assert status in (0, 2), output
    assert "Traceback" not in output, output
    assert "[internal-error]" not in output, output


SETTINGS_A = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@SETTINGS_A
@given(mutation(AIRCRAFT))
def test_validate_survives_mutated_aircraft(library, change):
    _check_validate_survives(library, *change)


@SETTINGS_A
@given(mutation(MISSIONS))
def test_validate_survives_mutated_missions(library, change):
    _check_validate_survives(library, *change)


@SETTINGS_A
@given(mutation(SCENARIOS))
def test_validate_survives_mutated_scenarios(library, change):
    _check_validate_survives(library, *change)


# -- (b) whatever validate accepts, a short dry-run runs --------------------------------------
# The file mutated -> the scenario dry-run: the track (every scenario element) and the lab
# (a visual-servoing mission with a pan-tilt camera).
DRY_RUN_FILES = {
    "track/aircraft.xml": "track/scenarios/props.xml",
    "track/straight-run.xml": "track/scenarios/props.xml",
    "track/scenarios/props.xml": "track/scenarios/props.xml",
    "lab/aircraft.xml": "lab/scenarios/clear-apron.xml",
    "lab/visual-servoing.xml": "lab/scenarios/clear-apron.xml",
}
SIMULATED_SECONDS = 4.0
RUN_TIMEOUT = 60.0  # wall-clock seconds for one short run: the hang detector
MEMORY_LIMIT = 3 << 30  # bytes of address space for the worker

WORKER = r"""
import json, sys, traceback
from executive.compiler import CompileError
from executive.dryrun import dry_run
from sim2d.scenario import load_scenario
print(json.dumps({"ready": True}), flush=True)
for line in sys.stdin:
    request = json.loads(line)
    try:
        run = dry_run(load_scenario(request["scenario"]), max_time=request["max_time"])
        answer = {"status": 0, "outcome": run.result.outcome}
    except CompileError as exc:  # bad input found late: the CLI's exit status 2
        answer = {"status": 2, "outcome": str(exc)}
    except BaseException:
        answer = {"status": "crash", "outcome": traceback.format_exc()}
    print(json.dumps(answer), flush=True)
"""


def _limit_memory() -> None:  # pragma: no cover - runs in the child
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


class DryRunWorker:
    """One process that dry-runs scenarios on request, bounded in time and memory."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", WORKER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            preexec_fn=_limit_memory,
        )
        assert self._answer(RUN_TIMEOUT) == {"ready": True}

    def _answer(self, timeout: float) -> dict:
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.close()
            pytest.fail(f"a {SIMULATED_SECONDS:g} s dry-run took more than {timeout:g} s")
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            pytest.fail(f"the dry-run worker died:\n{err}")
        return json.loads(line)

    def run(self, scenario: Path) -> dict:
        assert self.proc.stdin is not None
        request = {"scenario": str(scenario), "max_time": SIMULATED_SECONDS}
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        return self._answer(RUN_TIMEOUT)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


@pytest.fixture(scope="module")
def worker() -> Iterator[DryRunWorker]:
    w = DryRunWorker()
    yield w
    w.close()


def _range_of(name: str, element: str, attribute: str) -> Range | None:
    kind = "scenario" if "scenarios/" in name else name.rsplit("/", 1)[-1].split("-")[0]
    kind = kind if kind in ("aircraft", "scenario") else "mission"
    return attribute_ranges(schema_path(kind)).get((element, attribute))


@st.composite
def accepted_value(draw: st.DrawFn, wanted: Range | None) -> str:
    """Mostly values inside the attribute's range (its bounds above all), sometimes not."""
    if wanted is None or draw(st.integers(0, 9)) == 0:
        return draw(adversarial_value())
    low, high = wanted.low, wanted.high
    if wanted.integer:
        value: float = draw(
            st.sampled_from([low, high, low + 1, high - 1]) | st.integers(int(low), int(high))
        )
        return str(int(value))
    value = draw(
        st.sampled_from([low, high, (low + high) / 2.0])
        | st.floats(low, high, allow_nan=False, allow_infinity=False)
    )
    return repr(float(value))


@st.composite
def accepted_mutation(draw: st.DrawFn) -> tuple[str, list[tuple[int, str]]]:
    name = draw(st.sampled_from(sorted(DRY_RUN_FILES)))
    attrs = _attributes(_source_text(name))
    numeric = [i for i, (e, a, _, _) in enumerate(attrs) if _range_of(name, e, a) is not None]
    picks = draw(st.lists(st.sampled_from(numeric), min_size=1, max_size=3, unique=True))
    return name, [
        (i, draw(accepted_value(_range_of(name, attrs[i][0], attrs[i][1])))) for i in picks
    ]


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(accepted_mutation())
def test_what_validate_accepts_can_be_dry_run(library, worker, change):
    name, picks = change
    path = library / name
    scenario = library / DRY_RUN_FILES[name]
    attrs = _attributes(path.read_text(encoding="utf-8"))
    edits = [(attrs[i][2], attrs[i][3], _escape(value)) for i, value in picks]
    with _mutated(path, edits):
        status, output = _validate(scenario)
        assert status in (0, 2) and "Traceback" not in output, output
        assert "[internal-error]" not in output, output
        event(f"validate exit {status}")
        if status == 0:
            answer = worker.run(scenario)
            event(f"dry-run {answer['status']}")
            assert answer["status"] in (0, 2), answer["outcome"]


# -- every numeric attribute has a range --------------------------------------------------------
NUMERIC_BASES = {"xs:double", "xs:decimal", "xs:integer", "xs:positiveInteger"}
NUMERIC_BASES |= {"xs:nonNegativeInteger", "xs:float", "xs:int", "xs:long"}


@pytest.mark.parametrize("kind", ["aircraft", "mission", "scenario", "robot", "route"])
def test_every_numeric_attribute_has_a_physical_range(kind: str) -> None:
    """The XSDs are the one table of ranges: a numeric attribute without both bounds (a
    new attribute typed finiteDouble, say) fails here, named."""
    from lxml import etree

    xs = "{http://www.w3.org/2001/XMLSchema}"
    root = etree.parse(str(schema_path(kind))).getroot()
    simple = {t.get("name"): t for t in root.iter(f"{xs}simpleType")}

    def numeric(type_name: str) -> bool:
        while type_name in simple:
            restriction = simple[type_name].find(f"{xs}restriction")
            if restriction is None:
                return False
            type_name = restriction.get("base", "")
        return type_name in NUMERIC_BASES

    ranges = attribute_ranges(schema_path(kind))
    missing = []
    for complex_type in root.iter(f"{xs}complexType"):
        for attribute in complex_type.iter(f"{xs}attribute"):
            if not numeric(attribute.get("type", "")):
                continue
            elements = [
                e.get("name")
                for e in root.iter(f"{xs}element")
                if e.get("type") == complex_type.get("name")
            ]
            for element in elements:
                wanted = ranges.get((element, attribute.get("name")))
                if wanted is None or max(abs(wanted.low), abs(wanted.high)) > 1e12:
                    missing.append(f"<{element}> {attribute.get('name')}")
    assert not missing, f"numeric attributes without a physical range: {missing}"
