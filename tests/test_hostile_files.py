"""Hostile inputs through the real command line: nothing blocks, nothing reads without a
bound, and one file's failure never hides another file's report (issue 12, section 1).

FIFOs, devices, directories and huge files cannot live in the git corpus, so they are made
here in ``tmp_path``. Every case runs ``python -m executive.cli validate`` in a
subprocess with a 10 s timeout as the hang detector (a FIFO opened for reading without
``O_NONBLOCK`` would block for ever); no test asserts a wall-clock time.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

import executive.cli as cli
from executive.core.problems import (
    MAX_FILE_BYTES,
    MAX_PROBLEMS,
    Problem,
    SourceLocation,
    source_line,
)
from executive.core.xmlsafe import MAX_ELEMENTS

LIBRARY = Path(__file__).parent / "corpus" / "library"
BASE = LIBRARY / "base"
BROKEN = LIBRARY / "broken"
REPO = Path(__file__).resolve().parent.parent
HANG = 10.0  # seconds: a hang detector, not a performance assertion


def _memory_limit() -> None:  # pragma: no cover - runs in the child
    """At most 1 GiB of address space: reading a 1 GB file whole would fail."""
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def _validate(*files: Path | str, json: bool = False) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "executive.cli", "validate", *(["--json"] if json else [])]
    return subprocess.run(
        [*args, *map(str, files)],
        capture_output=True,
        text=True,
        timeout=HANG,
        cwd=REPO,
        preexec_fn=_memory_limit,
        check=False,
    )


def _fifo(tmp_path: Path) -> Path:
    path = tmp_path / "mission.xml"
    os.mkfifo(path)
    return path


def _directory(tmp_path: Path) -> Path:
    path = tmp_path / "mission.xml"
    path.mkdir()
    return path


def _huge(tmp_path: Path) -> Path:
    """A sparse 1 GB file: no disk used, but a whole read would need 1 GB of memory."""
    path = tmp_path / "mission.xml"
    with path.open("wb") as handle:
        handle.truncate(1 << 30)
    return path


def _just_too_large(tmp_path: Path) -> Path:
    """Valid-looking XML one byte over the limit, on a single line."""
    path = tmp_path / "mission.xml"
    head = b'<mission xmlns="urn:walkaround:mission:1" id="'
    tail = b'"/>'
    path.write_bytes(head + b"a" * (MAX_FILE_BYTES + 1 - len(head) - len(tail)) + tail)
    return path


# (what, make the input, expected code, expected message part)
SPECIAL: list[tuple[str, Callable[[Path], Path], str, str]] = [
    ("fifo", _fifo, "not-a-file", "is a FIFO (named pipe), not a regular XML file"),
    ("dev-zero", lambda _: Path("/dev/zero"), "not-a-file", "is a character device"),
    ("dev-null", lambda _: Path("/dev/null"), "not-a-file", "is a character device"),
    ("directory", _directory, "not-a-file", "is a directory, not a regular XML file"),
    ("huge-1gb", _huge, "too-large", f"larger than the limit of {MAX_FILE_BYTES} bytes"),
    ("one-byte-over", _just_too_large, "too-large", "larger than the limit"),
    ("missing", lambda p: p / "nope.xml", "not-found", "file not found"),
]


@pytest.mark.parametrize(
    ("make", "code", "message"), [pytest.param(*c[1:], id=c[0]) for c in SPECIAL]
)
def test_special_files_exit_2_at_once(tmp_path: Path, make, code: str, message: str) -> None:
    path = make(tmp_path)
    run = _validate(path, BASE / "mission.xml")  # the valid file is still reported
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stdout + run.stderr
    assert f"FAIL  {path}: 1 problem(s)" in run.stdout
    assert message in run.stdout and f"[{code}]" in run.stdout
    assert f"ok    {BASE / 'mission.xml'}" in run.stdout
    assert "1 valid, 1 invalid" in run.stdout


def _library_copy(tmp_path: Path) -> Path:
    """A private mission library: base/ copied, so its references can be replaced."""
    root = tmp_path / "library"
    shutil.copytree(BASE, root / "base")
    return root / "base"


@pytest.mark.parametrize("what", ["fifo", "directory", "dev-zero-link"])
def test_referenced_special_file_is_refused(tmp_path: Path, what: str) -> None:
    """A mission's aircraft and a scenario's mission get the same treatment."""
    base = _library_copy(tmp_path)
    (base / "aircraft.xml").unlink()
    (base / "mission.xml").unlink()
    for name in ("aircraft.xml", "mission.xml"):
        target = base / name
        if what == "fifo":
            os.mkfifo(target)
        elif what == "directory":
            target.mkdir()
        else:
            target.symlink_to("/dev/zero")
    text = (BASE / "mission.xml").read_text(encoding="utf-8")
    (base / "m.xml").write_text(text, "utf-8")
    scenario = (BASE / "scenario.xml").read_text(encoding="utf-8")
    (base / "s.xml").write_text(scenario, "utf-8")
    run = _validate(base / "m.xml", base / "s.xml")
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stdout + run.stderr
    kind = {"fifo": "a FIFO", "directory": "a directory", "dev-zero-link": "a character device"}
    if what == "dev-zero-link":  # the link leaves the library: refused for that first
        assert "leads outside the mission library root" in run.stdout
    else:
        assert f"aircraft file 'aircraft.xml' is {kind[what]}" in run.stdout
        assert f"mission file 'mission.xml' is {kind[what]}" in run.stdout
    assert "0 valid, 2 invalid" in run.stdout


def test_source_line_is_bounded_on_an_enormous_line(tmp_path: Path) -> None:
    """The caret printer never reads a huge line whole, nor past its budget."""
    path = tmp_path / "big.xml"
    path.write_bytes(b"<a>" + b"x" * (8 << 20) + b"\nsecond line\n")
    at_huge = Problem(SourceLocation(str(path), 1, 2), "test", "m")
    after_huge = Problem(SourceLocation(str(path), 2, 1), "test", "m")
    assert source_line(at_huge) is None
    assert source_line(after_huge, budget=1 << 20) is None  # the budget ends first
    assert source_line(after_huge, budget=16 << 20) == "    | second line\n    | ^"


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_source_line_never_reads_special_files(tmp_path: Path, special: str) -> None:
    path = special
    if special == "fifo":
        path = str(tmp_path / "f")
        os.mkfifo(path)
    assert source_line(Problem(SourceLocation(path, 3, 1), "test", "m")) is None


def test_source_line_shows_the_column(tmp_path: Path) -> None:
    path = tmp_path / "m.xml"
    path.write_text("one\n\ttwo three\n", encoding="utf-8")
    shown = source_line(Problem(SourceLocation(str(path), 2, 5), "test", "m"))
    assert shown == "    |  two three\n    |     ^"


# -- one file's failure never hides another's ------------------------------------------------
def test_namespaced_files_in_a_batch_each_get_their_report(tmp_path: Path) -> None:
    files = [
        BROKEN / "mission-foreign-attribute.xml",
        BASE / "aircraft.xml",
        BROKEN / "scenario-xinclude.xml",
        BASE / "scenario.xml",
        BROKEN / "aircraft-foreign-element.xml",
    ]
    run = _validate(*files)
    assert run.returncode == 2
    assert "Traceback" not in run.stdout + run.stderr
    assert run.stdout.count("[foreign-namespace]") == 3
    assert "2 valid, 3 invalid" in run.stdout


def test_an_internal_error_is_a_problem_of_its_file(monkeypatch, capsys) -> None:
    """A checker that crashes on one file: that file fails, the others are reported."""
    real = cli.check_scenario

    def crashing(path: Path, library: Path | None = None) -> list[Problem]:
        if Path(path).name == "scenario.xml":
            raise ZeroDivisionError("float division by zero")
        return real(path, library)

    monkeypatch.setattr(cli, "check_scenario", crashing)
    files = [BASE / "scenario.xml", BASE / "mission.xml", BROKEN / "mission-xinclude.xml"]
    assert cli.main(["validate", *map(str, files)]) == 2
    out = capsys.readouterr()
    assert "Traceback" not in out.out + out.err
    assert f"FAIL  {files[0]}: 1 problem(s)" in out.out
    assert "internal error while checking this file (ZeroDivisionError" in out.out
    assert f"ok    {files[1]}" in out.out
    assert "[foreign-namespace]" in out.out
    assert "1 valid, 2 invalid" in out.out


def test_an_internal_error_in_the_summary_is_a_problem_too(monkeypatch, capsys) -> None:
    def crashing(path: Path) -> str:
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(cli, "_describe", crashing)
    files = [BASE / "aircraft.xml", BASE / "mission.xml"]
    assert cli.main(["validate", "--json", *map(str, files)]) == 2
    out = capsys.readouterr().out
    assert out.count('"code": "internal-error"') == 2
    assert "Traceback" not in out


def test_long_digit_strings_within_range_load(tmp_path: Path) -> None:
    """``seed="000...07"`` is 7: no 4300-digit limit of int() turns it into a crash."""
    base = _library_copy(tmp_path)
    text = (base / "scenario.xml").read_text(encoding="utf-8")
    long_seed = text.replace('seed="7"', 'seed="+' + "0" * 5000 + '7"')
    long_count = long_seed.replace('count="3"', 'count="' + "0" * 5000 + '3"')
    (base / "scenario.xml").write_text(long_count, encoding="utf-8")
    run = _validate(base / "scenario.xml")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "seed 7" in run.stdout


def _many_checkpoints(tmp_path: Path, count: int, heading: str) -> Path:
    """The base mission with ``count`` more (identical) checkpoints."""
    base = _library_copy(tmp_path)
    text = (base / "mission.xml").read_text(encoding="utf-8")
    extra = f'<checkpoint id="c" x="1" y="1" heading-deg="{heading}"/>\n' * count
    (base / "mission.xml").write_text(text.replace("<inspection>", "<inspection>" + extra))
    return base / "mission.xml"


def test_too_many_elements_are_refused_before_the_schema(tmp_path: Path) -> None:
    run = _validate(_many_checkpoints(tmp_path, MAX_ELEMENTS, "0"))
    assert run.returncode == 2
    assert f"elements; the limit is {MAX_ELEMENTS}" in run.stdout
    assert "[too-many-elements]" in run.stdout and "Traceback" not in run.stderr


@pytest.mark.parametrize(
    ("heading", "last"),
    [
        ("400", "more schema problems not shown"),  # 9000 schema errors
        ("0", f"more than {MAX_PROBLEMS} problems: the rest are not listed"),  # duplicates
    ],
)
def test_thousands_of_mistakes_are_listed_up_to_a_bound(
    tmp_path: Path, heading: str, last: str
) -> None:
    """Locating and printing every mistake of a hostile file would take minutes."""
    run = _validate(_many_checkpoints(tmp_path, 9000, heading))
    assert run.returncode == 2, run.stderr
    assert last in run.stdout
    assert run.stdout.count(": error: ") <= MAX_PROBLEMS + 1


@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
@pytest.mark.parametrize(
    "command",
    [
        ["dry-run", "{input}", "--out", "{tmp}/out"],
        ["dry-run", str(REPO / "missions/track/straight-run.xml"), "--scenario", "{input}"],
        ["show", "{input}"],
        ["sim-view", "{input}", "--out", "{tmp}/world.png"],
    ],
    ids=["dry-run-mission", "dry-run-scenario", "show", "sim-view"],
)
def test_every_command_refuses_special_inputs_at_once(
    tmp_path: Path, special: str, command: list[str]
) -> None:
    """Every subcommand reads its XML through the same front end: no command blocks."""
    source = special
    if special == "fifo":
        source = str(_fifo(tmp_path))
    args = [a.format(input=source, tmp=tmp_path) for a in command]
    if args[0] == "dry-run" and "--out" not in args:
        args += ["--out", str(tmp_path / "out")]
    run = subprocess.run(
        [sys.executable, "-m", "executive.cli", *args],
        capture_output=True,
        text=True,
        timeout=HANG,
        cwd=REPO,
        preexec_fn=_memory_limit,
        check=False,
    )
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stdout + run.stderr
    assert "not a regular XML file [not-a-file]" in run.stderr


def test_symbolic_link_loops_are_problems_not_crashes(tmp_path: Path) -> None:
    """A file, or a file reference, that is a symbolic link loop."""
    base = _library_copy(tmp_path)
    (base / "aircraft.xml").unlink()
    (base / "aircraft.xml").symlink_to(base / "aircraft.xml")
    loop = tmp_path / "loop.xml"
    loop.symlink_to(loop)
    run = _validate(loop, base / "mission.xml")
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stdout + run.stderr
    assert f"FAIL  {loop}: 1 problem(s)" in run.stdout
    assert "[unreadable]" in run.stdout
    assert "aircraft path 'aircraft.xml' cannot be resolved" in run.stdout
    assert "0 valid, 2 invalid" in run.stdout
