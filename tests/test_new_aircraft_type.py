"""Issue 18, the mission engineer's day: `walkaround new TYPE`, validate of the current
folder's library, the missing-scenario error, defaults in every --help.

The scaffold is checked the way a new user would use it: `walkaround new`, then
`walkaround validate`, then `walkaround dry-run` of what was written, in a fresh folder;
the dry-run's metrics against the template's geometry (every checkpoint reached within
the mission's tolerance, every item inspected, no collision).
"""

import argparse
import json
import re
import shutil

import pytest
from lxml import etree

from executive.cli import build_parser, main
from executive.cli_help import subcommands
from executive.core.loader import load_aircraft, load_mission
from executive.core.resources import missions_dir, shipped_mission_files
from executive.scaffold import TEMPLATES, find_library, library_xml_files
from sim2d.scenario import load_scenario

SECTIONS = {
    "aircraft.xml": ("dimensions", "footprint", "outline", "features", "items"),
    "preflight.xml": ("airport", "approach", "inspection", "return"),
}


def _new(*args: str) -> int:
    return main(["new", *args])


def _todo_before(path, element: str) -> str:
    """The text of the comment right before the first <element> of ``path``."""
    root = etree.parse(str(path)).getroot()
    found = root.find(f"{{{etree.QName(root).namespace}}}{element}")
    assert found is not None, element
    comment = found.getprevious()
    assert isinstance(comment, etree._Comment), f"no comment before <{element}> in {path}"
    return comment.text


@pytest.mark.slow
def test_new_type_validates_and_dry_runs_as_written(tmp_path, monkeypatch, capsys):
    """The issue's user story: new, validate (no FILE: the current folder's library), dry-run
    (no --scenario: the clear-apron scenario `new` wrote where dry-run looks for it)."""
    monkeypatch.chdir(tmp_path)
    assert _new("A330-300") == 0  # default template: the lab mock-up, a short mission
    folder = tmp_path / "A330-300"
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()) == [
        "README.md",
        "aircraft.xml",
        "preflight.xml",
        "scenarios/clear-apron.xml",
    ]
    capsys.readouterr()

    assert main(["validate"]) == 0
    out = capsys.readouterr().out
    assert f"mission library of the current folder, {tmp_path.resolve()}" in out.splitlines()[0]
    assert "3 valid, 0 invalid" in out

    report = tmp_path / "report"
    run = ["dry-run", "A330-300/preflight.xml", "--out", str(report), "--quiet", "--no-record"]
    code = main(run)
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((report / "metrics.json").read_text())
    mission = load_mission(folder / "preflight.xml")
    assert metrics["mission"] == "A330-300-preflight"
    assert metrics["scenario"] == "A330-300-clear-apron"
    assert metrics["outcome"] == "completed" and metrics["succeeded"]
    assert metrics["checkpoints_reached"] == len(mission.checkpoints) == 3
    assert metrics["items_inspected"] == sum(len(c.items) for c in mission.checkpoints)
    assert metrics["collisions"] == [] or metrics["collisions"] == 0
    assert metrics["max_position_error"] <= mission.navigation.position_tolerance


@pytest.mark.parametrize("template", sorted(TEMPLATES))
def test_every_template_is_the_shipped_type_renamed(template, tmp_path, capsys):
    """Placeholders that validate: the template's own geometry, features, items and
    checkpoints under the new names, each section under a TODO comment."""
    folder = tmp_path / "lib" / "x-new"
    assert _new("X-new", "--from", template, "--dir", str(folder)) == 0
    files = sorted(folder.rglob("*.xml"))
    assert main(["validate", *map(str, files)]) == 0, capsys.readouterr().out

    source = missions_dir() / TEMPLATES[template].folder
    new, old = load_aircraft(folder / "aircraft.xml"), load_aircraft(source / "aircraft.xml")
    assert new.type == "X-new" != old.type
    assert (new.dimensions, new.footprint, new.outline) == (
        old.dimensions,
        old.footprint,
        old.outline,
    )
    assert dict(new.features) == dict(old.features) and dict(new.items) == dict(old.items)
    mission = load_mission(folder / "preflight.xml")
    shipped = load_mission(source / TEMPLATES[template].mission)
    assert (mission.id, mission.aircraft.type) == ("X-new-preflight", "X-new")
    assert mission.checkpoints == shipped.checkpoints
    assert mission.airport == shipped.airport
    scenario = load_scenario(folder / "scenarios" / "clear-apron.xml")
    assert scenario.id == "X-new-clear-apron" and scenario.mission.id == mission.id

    for name, elements in SECTIONS.items():
        for element in elements:
            assert "TODO" in _todo_before(folder / name, element)
        text = (folder / name).read_text()
        assert "EVERY FIGURE BELOW IS A PLACEHOLDER" in text or "PLACEHOLDERS" in text
    readme = (folder / "README.md").read_text()
    assert "walkaround validate" in readme and "walkaround dry-run preflight.xml" in readme


def test_airliner_template_dry_run_starts(tmp_path, capsys):
    """The a320 template's mission compiles and runs from its default scenario (cut
    short: the full 23-checkpoint mission is the shipped a320's own end-to-end test)."""
    folder = tmp_path / "a321"
    assert _new("a321", "--from", "a320", "--dir", str(folder)) == 0
    report = tmp_path / "report"
    short = ["--quiet", "--no-record", "--max-time", "5", "--rate", "10"]
    code = main(["dry-run", str(folder / "preflight.xml"), "--out", str(report), *short])
    assert code == 1  # ended by --max-time before the mission completed: a failure
    metrics = json.loads((report / "metrics.json").read_text())
    assert (metrics["mission"], metrics["scenario"]) == ("a321-preflight", "a321-clear-apron")
    assert metrics["outcome"] != "completed" and metrics["simulated_s"] == pytest.approx(5, abs=0.2)
    assert metrics["checkpoints_total"] == 23 and not metrics["collisions"]


def test_new_never_overwrites(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "A350").mkdir()
    assert _new("A350") == 2
    assert "already exists; nothing was written" in capsys.readouterr().err
    assert list((tmp_path / "A350").iterdir()) == []

    (tmp_path / "file").write_text("mine")
    assert _new("A350", "--dir", "file") == 2
    assert (tmp_path / "file").read_text() == "mine"

    assert _new("A350", "--dir", "fresh") == 0
    before = {p: p.read_bytes() for p in (tmp_path / "fresh").rglob("*") if p.is_file()}
    assert _new("A350", "--dir", "fresh", "--from", "a320") == 2
    assert {p: p.read_bytes() for p in (tmp_path / "fresh").rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("name", ["", "7E7", "a/b", "..", "A 330", "a" * 65, "-x"])
def test_new_refuses_a_bad_type_name(name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert _new("--", name) == 2
    assert list(tmp_path.iterdir()) == []


def test_new_goes_into_the_current_library(tmp_path, monkeypatch, capsys):
    """In a checkout's root (missions/*/aircraft.xml) or anywhere inside its library, the
    new type goes beside the others; outside any library, into ./TYPE."""
    lab = tmp_path / "repo" / "missions" / "lab"
    shutil.copytree(missions_dir() / "lab", lab)
    monkeypatch.chdir(tmp_path / "repo")
    assert _new("atr72") == 0
    assert (tmp_path / "repo" / "missions" / "atr72" / "aircraft.xml").is_file()
    monkeypatch.chdir(lab / "scenarios")
    assert _new("atr42") == 0
    assert (tmp_path / "repo" / "missions" / "atr42" / "preflight.xml").is_file()
    capsys.readouterr()


def test_find_library_rule(tmp_path):
    library = tmp_path / "repo" / "missions"
    (library / "a320" / "scenarios").mkdir(parents=True)
    (library / "a320" / "aircraft.xml").write_text("<aircraft/>")
    (tmp_path / "repo" / "docs").mkdir()
    assert find_library(tmp_path / "repo") == library  # a checkout's root
    assert find_library(tmp_path / "repo" / "docs") == library  # walking up
    assert find_library(library) == library
    assert find_library(library / "a320") == library  # a type folder: its parent
    assert find_library(library / "a320" / "scenarios") == library
    assert find_library(tmp_path) is None  # beside the repo, not in it
    plain = tmp_path / "plain"
    (plain / "b787").mkdir(parents=True)
    assert find_library(plain) is None
    (plain / "b787" / "aircraft.xml").write_text("<aircraft/>")
    assert find_library(plain) == plain  # where `walkaround new` put a type, outside a repo


def test_validate_without_files_says_which_library(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # in no library: the installed copy
    assert main(["validate", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["library"]["source"] == "installed"
    assert report["library"]["path"] == str(missions_dir())
    assert all(f["file"].startswith(str(missions_dir())) for f in report["files"])

    lab = tmp_path / "missions" / "lab"
    shutil.copytree(missions_dir() / "lab", lab)
    (lab / "scenarios" / "laser-link-drop.xml").write_text("<scenario>")  # broken
    assert main(["validate"]) == 2
    out = capsys.readouterr().out
    where = tmp_path.resolve() / "missions"
    assert out.splitlines()[0] == f"validating the mission library of the current folder, {where}"
    assert "FAIL" in out and "laser-link-drop.xml" in out
    assert main(["validate", "--json"]) == 2
    report = json.loads(capsys.readouterr().out)
    assert report["library"]["source"] == "current-folder"
    assert report["library"]["path"] == str(where)
    assert len(report["files"]) == len(list(lab.rglob("*.xml")))
    assert main(["validate", "--json", str(lab / "aircraft.xml")]) == 0  # files named: no key
    assert "library" not in json.loads(capsys.readouterr().out)


def test_validate_reads_only_the_library_layout(tmp_path, monkeypatch, capsys):
    """A home folder that became a library by holding one new type: its other XML files
    (not types, robots or campaigns) are none of validate's business."""
    assert library_xml_files(missions_dir()) == shipped_mission_files()
    monkeypatch.chdir(tmp_path)
    assert _new("E190") == 0
    (tmp_path / "settings.xml").write_text("<settings>")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "pom.xml").write_text("<project/>")
    capsys.readouterr()
    assert main(["validate", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["library"] == {
        "path": str(tmp_path.resolve()),
        "source": "current-folder",
        "said": f"validating the mission library of the current folder, {tmp_path.resolve()}",
    }
    assert sorted(f["file"] for f in report["files"]) == [
        str(tmp_path.resolve() / "E190" / name)
        for name in ("aircraft.xml", "preflight.xml", "scenarios/clear-apron.xml")
    ]


def test_missing_default_scenario_says_where_and_what_to_do(tmp_path, capsys):
    """The issue's report: a copied mission validates, then dry-run said only
    'scenarios/clear-apron.xml: file not found'."""
    for name in ("aircraft.xml", "visual-servoing.xml"):
        shutil.copy(missions_dir() / "lab" / name, tmp_path / name)
    mission = tmp_path / "visual-servoing.xml"
    out = tmp_path / "out"
    assert main(["dry-run", str(mission), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "scenarios" / "clear-apron.xml") in err  # where it looked
    assert "Without --scenario" in err  # why there
    assert "--scenario FILE" in err and 'mission attribute is "../visual-servoing.xml"' in err
    assert "walkaround new TYPE" in err  # the three ways out
    assert not out.exists()  # nothing was started

    given = tmp_path / "none.xml"  # a named scenario that is missing: the file's own error
    assert main(["dry-run", str(mission), "--scenario", str(given), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(given) in err and "Without --scenario" not in err


RANGE = re.compile(r"\d\s+to\s+\S|\bor more\b|\bat most\b|\bmore than\b|<=?|>=?")


def _option_helps(text: str) -> dict[str, str]:
    """Each option's help in a --help page, by its first option string, on one line."""
    helps: dict[str, str] = {}
    current = None
    for line in text.splitlines():
        match = re.match(r"  (-[-\w]+)", line)
        if match:
            current = match.group(1)
            helps[current] = line
        elif current and line.startswith("    "):
            helps[current] += " " + line.strip()
        else:
            current = None
    return {k: re.sub(r"\s+", " ", v) for k, v in helps.items()}


def _default_words(default: object) -> list[str]:
    if isinstance(default, float):
        return [f"{default:g}", str(default)]
    if isinstance(default, bool):
        return [str(default), "on" if default else "off"]
    return [str(default)]


@pytest.mark.parametrize("command", sorted(subcommands(build_parser())))
def test_every_help_names_defaults_and_ranges(command, monkeypatch, capsys):
    monkeypatch.setenv("COLUMNS", "2000")  # one line per option: no word cut at a hyphen
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"])
    assert stop.value.code == 0
    page = capsys.readouterr().out
    assert "(default: None)" not in page and "(default: False)" not in page
    helps = _option_helps(page)
    parser = subcommands(build_parser())[command]
    for action in parser._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        text = helps[action.option_strings[0]]
        flag = action.nargs == 0 and not isinstance(action, argparse.BooleanOptionalAction)
        if flag or action.required:
            continue  # off unless given / no default to name
        assert "default" in text, f"{command} {action.option_strings[0]}: no default in {text!r}"
        if action.default is not None:
            words = _default_words(action.default)
            assert any(w in text for w in words), f"{command}: {text!r} does not say {words}"
        if action.type in (int, float):
            assert RANGE.search(text), f"{command} {action.option_strings[0]}: no range {text!r}"


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf"])
def test_sim_robot_max_time_range_is_checked(value, tmp_path, capsys):
    """--help says "more than 0": a time that is not is refused before anything starts."""
    scenario = missions_dir() / "lab" / "scenarios" / "clear-apron.xml"
    robot = missions_dir() / "robots" / "hil-localhost.xml"
    out = tmp_path / "truth"
    args = ["sim-robot", str(scenario), "--robot", str(robot), "--out", str(out)]
    assert main([*args, "--max-time", value]) == 2
    assert "--max-time" in capsys.readouterr().err and not out.exists()
