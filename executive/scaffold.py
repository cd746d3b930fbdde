"""Mission library folders: finding the current one, scaffolding a new aircraft type (issue 18).

A *mission library* is a folder of aircraft types, one sub-folder each
(``<library>/<type>/aircraft.xml``, its missions beside it, their scenarios in
``<type>/scenarios/``), as the shipped library (:func:`executive.core.resources.missions_dir`).
:func:`find_library` says which library the current folder belongs to;
:func:`scaffold` writes the folder of a new type from a shipped template: the template's
aircraft file, its mission (renamed ``preflight.xml``) and its clear-apron scenario, where
``walkaround dry-run`` looks for it, with the template's comments replaced by TODO
comments saying what to replace, plus a README.md of next steps. Everything it writes
validates and dry-runs as written: the placeholders are the template's real figures.
"""

from __future__ import annotations

import os
import re
import shutil
import textwrap
from dataclasses import dataclass
from pathlib import Path

from executive.core.resources import missions_dir

MISSION_FILE = "preflight.xml"
SCENARIO_FILE = Path("scenarios") / "clear-apron.xml"
"""Where ``walkaround dry-run MISSION`` looks for the scenario when none is given."""

TYPE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.\-]{0,63}")
"""A type name: an XML identifier (it makes the mission and scenario ids) and a folder name."""


@dataclass(frozen=True)
class Template:
    """A shipped aircraft type a new one starts from."""

    folder: str
    mission: str
    what: str
    frame: str


AIRLINER_FRAME = (
    "aircraft frame F: origin at the nose tip, x towards the tail, y towards the left "
    "(port) side, z towards the ground; heights h above the ground (z = origin-height - h)"
)
TEMPLATES: dict[str, Template] = {
    "a320": Template("a320", "preflight.xml", "the Airbus A320-200", AIRLINER_FRAME),
    "b737-800": Template("b737-800", "preflight.xml", "the Boeing 737-800", AIRLINER_FRAME),
    "lab": Template(
        "lab",
        "visual-servoing.xml",
        "the laboratory mock-up (an 8 m fence with targets, a duct, a tyre)",
        "the lab mock-up's frame: origin at the fence's left end, x along the fence, +y "
        "towards the robot side; a real aircraft uses the " + AIRLINER_FRAME,
    ),
}
DEFAULT_TEMPLATE = "lab"
"""The smallest template: 3 checkpoints, a full dry-run of it takes about 90 simulated s."""


class ScaffoldError(Exception):
    """The folder cannot be written (it exists, a bad name, an unwritable place)."""


# -- which library is this? --------------------------------------------------------------------
def _is_library(folder: Path) -> bool:
    """Whether ``folder`` holds aircraft types (``*/aircraft.xml``)."""
    try:
        return folder.is_dir() and any(p.is_file() for p in folder.glob("*/aircraft.xml"))
    except OSError:  # an unreadable folder is no library
        return False


def find_library(start: Path) -> Path | None:
    """The mission library of the folder ``start``, or None when it is in none.

    The rule, first match wins: ``start`` itself when it holds ``*/aircraft.xml`` (a
    library); its parent when ``start`` holds ``aircraft.xml`` (a type folder); else,
    walking up from ``start``, the first folder named ``missions`` that holds
    ``*/aircraft.xml`` (``start`` is somewhere inside it) or the first folder whose
    ``missions/`` sub-folder does (a checkout's root, or below it).
    """
    here = start.resolve()
    if _is_library(here):
        return here
    if (here / "aircraft.xml").is_file():
        return here.parent
    for folder in (here, *here.parents):
        if folder.name == "missions" and _is_library(folder):
            return folder
        if _is_library(folder / "missions"):
            return folder / "missions"
    return None


LIBRARY_FOLDERS = ("robots", "campaigns")
"""Folders of a library beside its types (robot files, campaign files)."""


def library_xml_files(library: Path) -> list[Path]:
    """The XML files of a library, sorted: each type folder's (``TYPE/*.xml``,
    ``TYPE/scenarios/*.xml`` and the taught routes' files under ``TYPE/routes/``, a type
    folder being one with an aircraft.xml) and those of robots/ and campaigns/. The
    shipped library has no other; in a folder that became a library by holding a type (a
    home folder after ``walkaround new``), nothing else of it is read."""
    files: list[Path] = []
    for folder in sorted(p for p in library.iterdir() if p.is_dir()):
        if (folder / "aircraft.xml").is_file():
            files += folder.glob("*.xml")
            files += (folder / "scenarios").glob("*.xml")
            files += (folder / "routes").rglob("*.xml")
        elif folder.name in LIBRARY_FOLDERS:
            files += folder.glob("*.xml")
    return sorted(p for p in files if p.is_file() or p.is_symlink())


def default_folder(type_name: str, cwd: Path) -> Path:
    """Where ``walkaround new TYPE`` writes without ``--dir``: in the current library, if any.

    ``LIBRARY/TYPE`` for the library of :func:`find_library` (./missions/TYPE at a
    checkout's root), else ``./TYPE``; relative to ``cwd`` when the library is below it.
    """
    library = find_library(cwd)
    if library is None:
        return Path(type_name)
    target = library / type_name
    try:
        return target.relative_to(cwd.resolve())
    except ValueError:
        return target


# -- the files of a new type ----------------------------------------------------------------------
# Text edits, not an XML round trip: the new files keep the templates' layout (one attribute
# group per line, aligned points) that the engineer edits next. Each edit must match once.
_COMMENT_LINES = re.compile(r"\n[ \t]*<!--.*?-->[ \t]*(?=\n)", re.S)
_DECLARATION = re.compile(r"\A<\?xml[^>]*\?>\n")


def _template_text(path: Path) -> str:
    """A template without its comments (they describe the template, not the new type)."""
    text = path.read_text(encoding="utf-8")
    text = _COMMENT_LINES.sub("", text)
    if "<!--" in text:
        raise ScaffoldError(f"template {path}: a comment shares a line with markup")
    return _DECLARATION.sub("", text).lstrip("\n")


def _once(pattern: str, text: str, replace: str, path: Path) -> str:
    new, count = re.subn(pattern, lambda _: replace, text, count=1, flags=re.S)
    if count != 1:
        raise ScaffoldError(f"template {path}: {pattern!r} not found")
    return new


def _set_attributes(text: str, root: str, values: dict[str, str], path: Path) -> str:
    """Set attributes of the root start tag (the first ``<root ...>``), keeping its layout."""
    match = re.search(rf"<{root}\b[^>]*>", text)
    if match is None:
        raise ScaffoldError(f"template {path}: no <{root}>")
    tag = match.group(0)
    for name, value in values.items():
        tag = _once(rf'(?<=\s){name}="[^"]*"', tag, f'{name}="{_escape(value)}"', path)
    return text[: match.start()] + tag + text[match.end() :]


def _set_description(text: str, description: str, path: Path) -> str:
    return _once(
        r"<description>.*?</description>",
        text,
        f"<description>{_escape(description)}</description>",
        path,
    )


def _todo(text: str, element: str, comment: str, path: Path) -> str:
    """``comment`` on the lines before the first ``<element``, indented like it."""
    match = re.search(rf"\n([ \t]*)<{element}\b", text)
    if match is None:
        raise ScaffoldError(f"template {path}: no <{element}>")
    indent = match.group(1)
    lines = comment.split("\n")
    body = f"\n{indent}     ".join(lines)
    return f"{text[: match.start()]}\n{indent}<!-- {body} -->{text[match.start() :]}"


def _escape(value: str) -> str:
    """``value`` as XML text or a double-quoted attribute."""
    return value.replace("&", "&amp;").replace("<", "&lt;").replace('"', "&quot;")


def _document(body: str, header: str) -> str:
    if "--" in header:
        raise ValueError("no double hyphen in an XML comment")
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<!--\n{header}\n-->\n{body}'


def _header(paragraphs: list[str]) -> str:
    """Paragraphs wrapped and indented for the comment at the top of a file."""
    return "\n\n".join(
        textwrap.fill(p, 88, initial_indent="  ", subsequent_indent="  ", break_on_hyphens=False)
        for p in paragraphs
    )


def _attribute(text: str, root: str, name: str, path: Path) -> str:
    match = re.search(rf'<{root}\b[^>]*?\s{name}="([^"]*)"', text)
    if match is None:
        raise ScaffoldError(f"template {path}: no {name}= on <{root}>")
    return match.group(1)


def aircraft_text(type_name: str, template: Template) -> str:
    """The new type's aircraft.xml: the template's geometry under TODO comments."""
    path = missions_dir() / template.folder / "aircraft.xml"
    text = _template_text(path)
    old_type = _attribute(text, "aircraft", "type", path)
    text = _set_attributes(text, "aircraft", {"type": type_name}, path)
    text = _set_description(
        text,
        f"TODO: {type_name}: variant, engines, where the figures come from.\n"
        f"The figures below are still {old_type}'s (walkaround new).",
        path,
    )
    src = f"{old_type}'s"
    for element, comment in (
        (
            "dimensions",
            f"TODO dimensions: {type_name}'s overall length, span, height and fuselage\n"
            "width, m (Aircraft Characteristics document or type certificate data sheet).\n"
            f"PLACEHOLDER: {src}.",
        ),
        (
            "footprint",
            "TODO footprint: what the robot can hit at laser height (0.3-0.5 m) or with\n"
            "its body: gear legs and wheels, low engine nacelles, as circles and polygons\n"
            "(x, y) in F. The route checks and the simulator keep the robot out of them:\n"
            f"too small and the robot hits the aircraft. PLACEHOLDER: {src}.",
        ),
        (
            "outline",
            "TODO outline: the top view (fuselage, wings, tailplane) projected on the\n"
            f"ground, polygons in F: GPS shadow and drawings. PLACEHOLDER: {src}.",
        ),
        (
            "features",
            "TODO features: what the cameras detect and servo on (gear, probes, ports,\n"
            "inlets): points (x, y, h) in F, the outward normal, the detection range,\n"
            "pbvs or ibvs. Checkpoints name them as target=, items as feature=.\n"
            f"PLACEHOLDER: {src}.",
        ),
        (
            "items",
            "TODO items: the checks of the type's walk-around, each on a feature. The\n"
            "mission's checkpoints inspect them by id: rename one here, rename it there.\n"
            f"PLACEHOLDER: {src}.",
        ),
    ):
        text = _todo(text, element, comment, path)
    header = _header(
        [
            f"Aircraft type {type_name}: written by `walkaround new` from the "
            f"{template.folder} template, {template.what}.",
            f"EVERY FIGURE BELOW IS A PLACEHOLDER: {old_type}'s. The file validates and the "
            "mission dry-runs as it is, but it describes the template, not this type. "
            "Replace each section marked TODO, then run `walkaround validate` and "
            "`walkaround dry-run` (README.md beside this file; walkaround's "
            "docs/new-aircraft-type.md walks through it).",
            f"FRAME: {template.frame}.",
            "Tag each figure with its source in a comment ([S n] sourced, [D n] derived, "
            "[M n] measured off a drawing, [E] estimate), as the shipped types do.",
        ]
    )
    return _document(text, header)


def mission_text(type_name: str, template: Template) -> str:
    """The new type's preflight.xml: the template's mission under TODO comments."""
    path = missions_dir() / template.folder / template.mission
    text = _template_text(path)
    old_type = _attribute(text, "mission", "aircraft-type", path)
    text = _set_attributes(
        text, "mission", {"id": f"{type_name}-preflight", "aircraft-type": type_name}, path
    )
    text = _set_description(
        text,
        f"TODO: {type_name} pre-flight walk-around: the order of the checkpoints, where\n"
        f"the robot starts. Still the {template.folder} template's mission (walkaround new).",
        path,
    )
    for element, comment in (
        (
            "platform",
            "The robot: the template's Air-Cobot (footprint, limits, camera and laser\n"
            "poses in the robot frame R). Keep it unless another robot runs this mission;\n"
            "its wires for `walkaround run` are in a robot file (docs/robot.md).",
        ),
        (
            "safety",
            "Safety distances: keep unless your site's rules differ (docs/mission-format.md).",
        ),
        ("navigation", "Speeds and tolerances: keep, or slow down near a smaller aircraft."),
        (
            "airport",
            "TODO airport, in the airport frame A (x east, y north, heading counter-\n"
            "clockwise from east): the robot's charging station, the parking pose (where\n"
            "F's origin stands, which way the nose points) and the zones the robot must\n"
            f"never enter. PLACEHOLDER: the {template.folder} template's.",
        ),
        (
            "approach",
            "TODO approach: where the robot leaves the apron for the aircraft, in A.",
        ),
        (
            "inspection",
            "TODO checkpoints: one robot pose (x, y in F, heading) per inspection position,\n"
            "in the order of the type's walk-around, each clear of the footprint (and so\n"
            "is the straight leg to the next one); each inspects items of aircraft.xml by\n"
            f"id. PLACEHOLDER: {old_type}'s checkpoints.",
        ),
        (
            "return",
            "TODO return: waypoints (in A) from the last checkpoint back to the handover.",
        ),
    ):
        text = _todo(text, element, comment, path)
    header = _header(
        [
            f"Pre-flight mission of {type_name}: written by `walkaround new` from the "
            f"{template.folder} template ({template.mission}, for {old_type}).",
            "The sections marked TODO are PLACEHOLDERS: they fit the template's aircraft and "
            "apron. Change them with aircraft.xml, then `walkaround validate` (every pose "
            "against the footprint), `walkaround show preflight.xml` (the tree) and "
            "`walkaround dry-run preflight.xml` (in sim2d, on scenarios/clear-apron.xml).",
            "Frames: checkpoint poses in the aircraft frame F (aircraft.xml); station, "
            "parking, handover and waypoints in the airport frame A (docs/mission-format.md).",
        ]
    )
    return _document(text, header)


def scenario_text(type_name: str, template: Template) -> str:
    """The new type's clear-apron scenario: the default one of ``walkaround dry-run``."""
    path = missions_dir() / template.folder / SCENARIO_FILE
    text = _template_text(path)
    text = _set_attributes(
        text,
        "scenario",
        {"id": f"{type_name}-clear-apron", "mission": f"../{MISSION_FILE}", "seed": "1"},
        path,
    )
    text = _set_description(
        text, "Reference run: nominal parking, empty apron, default noise, seed 1.", path
    )
    header = _header(
        [
            f"{type_name} pre-flight on a clear apron, the reference run: the aircraft stands "
            "exactly at the mission's parking pose, nothing else is on the apron, default "
            "noise and position fix. `walkaround dry-run ../preflight.xml` runs this file "
            "when it is given no other scenario (it looks for scenarios/clear-apron.xml "
            "beside the mission). Harder scenarios go beside it (docs/scenario-format.md).",
        ]
    )
    return _document(text, header)


def readme_text(type_name: str, template: Template) -> str:
    """The next steps, in the folder they apply to."""
    return f"""# {type_name}: a new aircraft type for walkaround

Written by `walkaround new {type_name} --from {template.folder}`. Every file here is
valid and the mission dry-runs as it is, but the figures are still those of the
{template.folder} template, {template.what}: replace them, keeping the files valid at
each step. walkaround's docs/new-aircraft-type.md walks through it with an example.

| file | what | default of |
|---|---|---|
| `aircraft.xml` | the type: dimensions, footprint, outline, features, items | |
| `{MISSION_FILE}` | the pre-flight mission: robot, apron, checkpoints | |
| `{SCENARIO_FILE.as_posix()}` | the clear-apron scenario | `walkaround dry-run {MISSION_FILE}` |

Next steps, from this folder:

1. `aircraft.xml`: replace each section marked TODO (the comments say what goes
   there, in which frame): dimensions, footprint, outline, features, items.
2. `walkaround validate aircraft.xml {MISSION_FILE} {SCENARIO_FILE.as_posix()}`: every
   problem comes with file:line:column and what to change. A checkpoint that the new
   footprint now covers, or an item the mission inspects that aircraft.xml no longer
   has, shows up here.
3. `{MISSION_FILE}`: the airport (station, parking pose, zones), the approach, the
   checkpoints (poses in the aircraft frame, the items each inspects), the return.
4. `walkaround show {MISSION_FILE}`: the behaviour tree the mission compiles into.
5. `walkaround sim-view {SCENARIO_FILE.as_posix()} --out world.png`: the apron, the
   aircraft, the route and checkpoints as the simulator sees them.
6. `walkaround dry-run {MISSION_FILE} --out dry-run`: the mission in the simulator;
   exit 0 when it succeeded. dry-run/trajectory.png and dry-run/metrics.json show
   where it went and how close each checkpoint was.
7. More scenarios beside `{SCENARIO_FILE.as_posix()}` (copy a shipped type's
   busy-apron.xml, offset-apron.xml, ...), then `walkaround dry-run {MISSION_FILE}
   --scenario scenarios/FILE.xml` and a campaign (docs/campaigns.md).
8. On the robot: `walkaround run {MISSION_FILE} --robot ROBOT.xml` with the robot file
   that wires your robot (docs/robot.md; the shipped missions/robots/air-cobot.xml).
"""


def files_of(type_name: str, template: Template) -> dict[Path, str]:
    """Every file of the new type's folder, by path in the folder."""
    return {
        Path("aircraft.xml"): aircraft_text(type_name, template),
        Path(MISSION_FILE): mission_text(type_name, template),
        SCENARIO_FILE: scenario_text(type_name, template),
        Path("README.md"): readme_text(type_name, template),
    }


def scaffold(type_name: str, template_name: str, folder: Path) -> list[Path]:
    """Write the folder of a new aircraft type; the paths written.

    Never overwrites: the folder must not exist (it is created with ``mkdir``, which
    refuses an existing one, so two runs cannot both write it). On an error half-way the
    folder is removed again: it is written whole or not at all.
    """
    if not TYPE_NAME.fullmatch(type_name):
        raise ScaffoldError(
            f"{type_name!r}: a type name starts with a letter, then letters, digits, "
            "'-', '_' or '.' (at most 64), e.g. A330-300 or atr72"
        )
    template = TEMPLATES.get(template_name)
    if template is None:
        raise ScaffoldError(
            f"--from {template_name}: no such template; one of {', '.join(TEMPLATES)}"
        )
    if folder.exists() or folder.is_symlink():
        raise ScaffoldError(f"{folder}: already exists; nothing was written (choose --dir)")
    contents = files_of(type_name, template)  # before anything is written
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        folder.mkdir()
    except FileExistsError:
        raise ScaffoldError(f"{folder}: already exists; nothing was written") from None
    except OSError as exc:
        raise ScaffoldError(f"{folder}: cannot create it ({exc.strerror or exc})") from None
    written = []
    try:
        for name, text in contents.items():
            path = folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "x", encoding="utf-8") as out:
                out.write(text)
            written.append(path)
    except OSError as exc:
        shutil.rmtree(folder, ignore_errors=True)
        raise ScaffoldError(
            f"{folder}: cannot write {exc.filename or folder} ({exc.strerror or exc}); "
            "nothing was left behind"
        ) from None
    return written


def relative(path: Path) -> str:
    """``path`` as the user would type it from the current folder."""
    try:
        return os.path.relpath(path)
    except ValueError:  # another drive
        return str(path)
