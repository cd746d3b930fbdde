"""Reading schema-valid walkaround XML into models, with problems located in the source.

:func:`open_validated` is the front end every loader shares (hardened parse, root and
namespace, XSD); :class:`ElementReader` gives typed attribute access and records semantic
problems at the element or attribute they concern.
"""

from __future__ import annotations

import itertools
import math
import stat
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

from lxml import etree

from executive.core.frames import Pose2
from executive.core.geometry import polygon_problem
from executive.core.model import Circle, Polygon, Shape
from executive.core.problems import (
    InvalidInputError,
    Problem,
    ProblemSink,
    SourceLocation,
    file_kind,
)
from executive.core.resources import schema_path
from executive.core.xmlsafe import XmlDocument, parse_xml, validate_against

E = TypeVar("E")

MAX_REFERENCE_CHARS = 1024
"""Longest file reference (a mission's aircraft, a scenario's mission): real ones are a
few tens of characters; a longer one is refused before the file system sees it."""


def display_path(path: Path) -> str:
    """The path as the user will recognise it: relative to the working directory if inside."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError, RuntimeError):  # RuntimeError: a symbolic link loop
        return str(path)


def local_name(element: etree._Element) -> str:
    return etree.QName(element).localname


MIN_VERTEX_GAP = 1e-3
"""Metres between two vertices of a polygon: closer ones are the same point (a ring that
touches itself, which the simulator's ray caster refuses)."""


def _repeated_vertex(points: tuple[tuple[float, float], ...]) -> str | None:
    """Why a ring repeats a vertex (its closing point aside), or None."""
    ring = list(points)
    if len(ring) > 3 and math.dist(ring[0], ring[-1]) < MIN_VERTEX_GAP:
        ring.pop()  # an explicitly closed ring
    cells: dict[tuple[int, int], list[int]] = {}  # a millimetre grid: O(n), not O(n^2)
    for k, (x, y) in enumerate(ring):
        cx, cy = math.floor(x / MIN_VERTEX_GAP), math.floor(y / MIN_VERTEX_GAP)
        for dx, dy in itertools.product((-1, 0, 1), repeat=2):
            for j in cells.get((cx + dx, cy + dy), ()):
                if math.dist(ring[j], (x, y)) < MIN_VERTEX_GAP:
                    return (
                        f"point {k + 1} repeats point {j + 1} at ({x:g}, {y:g}); points "
                        f"must be at least {MIN_VERTEX_GAP * 1000:g} mm apart"
                    )
        cells.setdefault((cx, cy), []).append(k)
    return None


class ElementReader:
    """Typed attribute access on a schema-valid document, recording semantic problems."""

    def __init__(self, doc: XmlDocument, sink: ProblemSink) -> None:
        self.doc = doc
        self.sink = sink
        self.ns = etree.QName(doc.root).namespace or ""

    # locations ----------------------------------------------------------------------------
    def where(self, element: etree._Element, attribute: str | None = None) -> SourceLocation:
        line, column = self.doc.locate(element, attribute)
        return SourceLocation(self.sink.file, line, column)

    def problem(
        self, element: etree._Element, code: str, message: str, attribute: str | None = None
    ) -> None:
        line, column = self.doc.locate(element, attribute)
        self.sink.add(code, message, line, column)

    # navigation ----------------------------------------------------------------------------
    def child(self, element: etree._Element, name: str) -> etree._Element | None:
        return element.find(f"{{{self.ns}}}{name}")

    def children(self, element: etree._Element | None, name: str) -> list[etree._Element]:
        if element is None:
            return []
        return element.findall(f"{{{self.ns}}}{name}")

    def elements(self, element: etree._Element | None) -> list[etree._Element]:
        """The child elements of ``element`` (comments skipped); [] for None."""
        if element is None:
            return []
        return [e for e in element if isinstance(e.tag, str)]

    def text(self, element: etree._Element | None) -> str:
        if element is None:
            return ""
        return " ".join((element.text or "").split())

    # attributes (the XSD has checked presence and lexical types) -----------------------------
    def num(self, element: etree._Element, name: str, default: float | None = None) -> float:
        raw = element.get(name)
        if raw is None:
            if default is None:
                self.problem(element, "missing", f"<{local_name(element)}> needs '{name}'")
                return math.nan
            return default
        value = float(raw)
        if not math.isfinite(value):
            self.problem(
                element, "not-finite", f"'{name}' must be a finite number, not '{raw}'", name
            )
        return value

    def integer(self, element: etree._Element, name: str) -> int:
        """A whole number the XSD has checked (range included), read without Python's
        limit on long digit strings: leading zeros (``000...07``) are dropped first."""
        raw = self.str_(element, name).lstrip("+")
        digits = raw.lstrip("-").lstrip("0") or "0"
        if len(digits) > 40 or not digits.isdigit():  # the XSD bounds every integer
            self.problem(element, "not-a-number", f"'{name}' is not a whole number", name)
            return 0
        return -int(digits) if raw.startswith("-") else int(digits)

    def opt_num(self, element: etree._Element, name: str) -> float | None:
        return None if element.get(name) is None else self.num(element, name)

    def angle(self, element: etree._Element, name: str) -> float:
        return math.radians(self.num(element, name))

    def opt_angle(self, element: etree._Element, name: str) -> float | None:
        value = self.opt_num(element, name)
        return None if value is None else math.radians(value)

    def str_(self, element: etree._Element, name: str) -> str:
        return (element.get(name) or "").strip()

    def enum(self, element: etree._Element, name: str, kind: Callable[[str], E]) -> E:
        return kind(self.str_(element, name))

    # collections -----------------------------------------------------------------------------
    def unique(
        self,
        elements: Iterable[etree._Element],
        what: str,
        attribute: str = "id",
        template: str = "duplicate {what} id '{key}' (first defined at line {line})",
    ) -> None:
        """Report every element whose ``attribute`` repeats an earlier one."""
        seen: dict[str, etree._Element] = {}
        for element in elements:
            key = self.str_(element, attribute)
            if key in seen:
                line = self.where(seen[key]).line
                message = template.format(what=what, key=key, line=line)
                self.problem(element, "duplicate-id", message, attribute)
            else:
                seen[key] = element

    def polygon(self, element: etree._Element, pid: str) -> Polygon:
        points = tuple(
            (self.num(p, "x"), self.num(p, "y")) for p in self.children(element, "point")
        )
        reason = polygon_problem(points) or _repeated_vertex(points)
        if reason:
            self.problem(element, "invalid-polygon", f"polygon '{pid}': {reason}")
        return Polygon(pid, points)

    def circle(self, element: etree._Element, cid: str) -> Circle:
        return Circle(
            cid, self.num(element, "x"), self.num(element, "y"), self.num(element, "radius")
        )

    def shape(self, element: etree._Element, sid: str) -> Shape:
        if local_name(element) == "circle":
            return self.circle(element, sid)
        return self.polygon(element, sid)

    def pose(self, element: etree._Element) -> Pose2:
        return Pose2(
            self.num(element, "x"), self.num(element, "y"), self.angle(element, "heading-deg")
        )


def open_validated(
    path: Path, kind: str, namespace: str, xsd: Path, sink: ProblemSink
) -> XmlDocument | None:
    """Parse, check the root element ``kind`` in ``namespace``, and validate against ``xsd``."""
    doc = parse_xml(path, sink)
    if doc is None:
        return None
    root = doc.root
    qname = etree.QName(root)
    expected_ns = namespace
    if qname.localname != kind or qname.namespace != expected_ns:
        line, column = doc.locate(root)
        found = f"<{qname.localname}>" + (
            f" in namespace '{qname.namespace}'" if qname.namespace else " with no namespace"
        )
        sink.add(
            "wrong-root",
            f"expected <{kind}> in namespace '{expected_ns}', found {found}",
            line,
            column,
        )
        return None
    if not validate_against(doc, xsd, sink):
        return None
    return doc


M = TypeVar("M")

Builder = Callable[[XmlDocument, ProblemSink, Path, Path], "M | None"]
"""Builds the model of a validated document: (document, sink, its path, library root)."""


def library_root_of(path: Path, depth: int) -> Path:
    """The mission library a file ``depth`` folders below it belongs to (a mission,
    ``<library>/<type>/<mission>.xml``, is at depth 2). A path that cannot be resolved (a
    symbolic link loop) is taken as written: its problem is reported when it is read."""
    try:
        resolved = path.resolve()
    except (OSError, RuntimeError):
        resolved = path.absolute()
    for _ in range(depth):
        resolved = resolved.parent
    return resolved


def load_document(
    path: Path | str,
    kind: str,
    namespace: str,
    build: Builder[M],
    library_root: Path | str | None,
    depth: int,
) -> M:
    """Load a ``<kind>`` file of the mission library: parse, check its root, validate it
    against ``kind``'s schema, build its model with ``build``; raise
    :class:`InvalidInputError` with every problem (file:line:column) if there is any, so
    a caller never gets a half-built model. ``library_root`` defaults to
    :func:`library_root_of` (``path``, ``depth``)."""
    path = Path(path)
    root_dir = Path(library_root) if library_root is not None else library_root_of(path, depth)
    sink = ProblemSink(display_path(path))
    doc = open_validated(path, kind, namespace, schema_path(kind), sink)
    model = build(doc, sink, path, root_dir) if doc is not None else None
    sink.raise_if_any()
    assert model is not None  # a builder that returns None has recorded why
    return model


def problems_of(load: Callable[[], object]) -> list[Problem]:
    """Every problem ``load()`` raises (empty when it loads); never raises."""
    try:
        load()
    except InvalidInputError as exc:
        return list(exc.problems)
    return []


def load_reference(
    r: ElementReader,
    attribute: str,
    source: Path,
    library_root: Path,
    load: Callable[[Path], M],
    referrer: str,
    element: etree._Element | None = None,
    label: str | None = None,
) -> tuple[M | None, list[Problem]]:
    """Load the file named by ``element``'s (default: the root element's) ``attribute``
    (a path relative to ``source``, a ``referrer`` file such as a mission) with ``load``;
    it may not leave ``library_root``. ``label`` names the reference in codes and
    messages (default: ``attribute``).

    Returns the model, or None and the referenced file's own problems (a problem is also
    recorded at the attribute). Codes: ``<attribute>-path`` for where the path leads,
    ``<attribute>-invalid`` when the file has problems of its own.
    """
    root = r.doc.root if element is None else element
    ref = r.str_(root, attribute)
    rel = Path(ref)
    name = label or attribute

    def complain(code: str, message: str) -> tuple[None, list[Problem]]:
        r.problem(root, f"{name}-{code}", message, attribute)
        return None, []

    if len(ref) > MAX_REFERENCE_CHARS:
        return complain(
            "path",
            f"{name} path is {len(ref)} characters long; the limit is "
            f"{MAX_REFERENCE_CHARS} (a relative path inside the mission library)",
        )
    if rel.is_absolute() or ref.startswith(("/", "\\")) or ":" in ref.split("/")[0]:
        return complain("path", f"{name} path '{ref}' must be relative to the {referrer} file")
    try:
        library = library_root.resolve()
        target = (source.resolve().parent / rel).resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop, a component too long
        return complain("path", f"{name} path '{ref}' cannot be resolved: {exc}")
    if not target.is_relative_to(library):
        return complain(
            "path",
            f"{name} path '{ref}' leads outside the mission library root '{display_path(library)}'",
        )
    try:
        mode = target.stat().st_mode
    except OSError:
        return complain("path", f"{name} file '{ref}' does not exist")
    if not stat.S_ISREG(mode):
        what = file_kind(mode)
        return complain("path", f"{name} file '{ref}' is {what}, not a regular file")
    try:
        return load(target), []
    except InvalidInputError as exc:
        complain(
            "invalid",
            f"{name} file '{ref}' has {len(exc.problems)} problem(s), listed with its name",
        )
        return None, list(exc.problems)
