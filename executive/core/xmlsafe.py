"""Hardened XML parsing and XSD validation with precise problem locations.

Every walkaround XML file (aircraft, mission, scenario) goes through :func:`parse_xml`:

* no DTD is loaded and no entity is resolved, internal or external; a document with a
  ``<!DOCTYPE`` at all is refused, so XXE and entity-expansion bombs never expand;
* no network access, no huge trees (libxml2's default limits), at most
  :data:`MAX_FILE_BYTES` bytes and :data:`MAX_DEPTH` levels;
* every problem carries ``file:line:column``. libxml2 gives element line numbers only
  (the line where the start tag *ends*), so columns are recovered from the source text.
"""

from __future__ import annotations

import codecs
import functools
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

from executive.core.problems import (
    MAX_FILE_BYTES,
    NotRegularFileError,
    ProblemSink,
    open_regular,
)

__all__ = ["MAX_DEPTH", "MAX_FILE_BYTES", "XmlDocument", "parse_bytes", "parse_xml"]

MAX_DEPTH = 32
"""Deepest accepted element nesting; the formats need fewer than 8 levels."""

MAX_ELEMENTS = 10_000
"""Most elements in one file: the biggest shipped file (an A320 aircraft) has about 400.
Every later stage (XSD, geometry, the simulator) is linear or worse in this number."""

MAX_SCHEMA_PROBLEMS = 50
"""Schema problems reported per file; the rest are counted in one last problem."""

_DOCTYPE = re.compile(r"<!DOCTYPE", re.IGNORECASE)
_NS_BRACES = re.compile(r"\{[^}'\s]*\}")  # {namespace-uri}, not {'a', 'b'} sets


def _hardened_parser() -> etree.XMLParser:
    """A new parser (parsers keep state, so one per parse) with every risky feature off."""
    return etree.XMLParser(
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        collect_ids=False,
        remove_comments=False,
    )


@dataclass
class XmlDocument:
    """A parsed, not yet validated XML file and the text needed to locate its nodes."""

    path: Path
    display: str
    root: etree._Element
    text: str
    _line_starts: list[int] = field(default_factory=list, repr=False)
    _by_tag_line: dict[tuple[str, int], list[etree._Element]] | None = field(
        default=None, repr=False
    )

    def __post_init__(self) -> None:
        starts = [0]
        for m in re.finditer("\n", self.text):
            starts.append(m.end())
        self._line_starts = starts

    # -- locating nodes -------------------------------------------------------------
    def _offset(self, line: int, column: int = 1) -> int:
        line = min(max(line, 1), len(self._line_starts))
        return self._line_starts[line - 1] + max(column, 1) - 1

    def _line_col(self, offset: int) -> tuple[int, int]:
        lo, hi = 0, len(self._line_starts) - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if self._line_starts[mid] <= offset:
                lo = mid
            else:
                hi = mid - 1
        return lo + 1, offset - self._line_starts[lo] + 1

    def _start_tag_offset(self, element: etree._Element) -> int | None:
        """Offset of ``<name`` for ``element``: libxml2 reports the line where the tag ends."""
        line = element.sourceline or 0
        if line <= 0:
            return None
        name = etree.QName(element).localname
        pattern = re.compile(r"<(?:[A-Za-z_][\w.\-]*:)?" + re.escape(name) + r"(?=[\s/>])")
        # The nth element of that name whose start tag ends on this line (an index built
        # once: locating every problem of a big file stays linear).
        if self._by_tag_line is None:
            self._by_tag_line = {}
            for e in self.root.iter(etree.Element):
                self._by_tag_line.setdefault((e.tag, e.sourceline or 0), []).append(e)
        same_line = self._by_tag_line.get((element.tag, line), [])
        nth = same_line.index(element) if element in same_line else 0
        end = self._offset(line + 1)
        # Search backwards line by line for a start tag that can end on `line`.
        for first in range(line, max(line - 50, 0), -1):
            matches = list(pattern.finditer(self.text, self._offset(first), end))
            if matches:
                if first == line:
                    return matches[min(nth, len(matches) - 1)].start()
                return matches[-1].start()
        return None

    def locate(self, element: etree._Element, attribute: str | None = None) -> tuple[int, int]:
        """(line, column) of ``element``'s start tag, or of one of its attributes."""
        start = self._start_tag_offset(element)
        if start is None:
            return element.sourceline or 0, 0
        if attribute is not None:
            tag_end = self.text.find(">", start)
            tag_end = len(self.text) if tag_end < 0 else tag_end
            m = re.compile(r"\s(" + re.escape(attribute) + r")\s*=").search(
                self.text, start, tag_end
            )
            if m:
                return self._line_col(m.start(1))
        return self._line_col(start)

    def iter_elements(self) -> Iterator[etree._Element]:
        """Every element, in document order (comments and processing instructions skipped)."""
        return self.root.iter(etree.Element)


def _read_limited(path: Path, sink: ProblemSink) -> bytes | None:
    """The file's bytes, if it is a regular file of at most :data:`MAX_FILE_BYTES` bytes.

    Never blocks (a FIFO is refused, not opened for reading) and never reads more than
    the limit plus one byte, whatever ``stat`` claims (``/proc`` files report size 0).
    """
    try:
        with open_regular(path) as handle:
            data = handle.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        sink.add("not-found", "file not found")
        return None
    except NotRegularFileError as exc:
        sink.add("not-a-file", f"is {exc.strerror}, not a regular XML file")
        return None
    except OSError as exc:
        sink.add("unreadable", f"cannot read the file: {exc.strerror or exc}")
        return None
    if len(data) > MAX_FILE_BYTES:
        sink.add(
            "too-large",
            f"file is larger than the limit of {MAX_FILE_BYTES} bytes "
            "(walkaround files are a few tens of kilobytes)",
            1,
            1,
        )
        return None
    return data


def parse_xml(path: Path, sink: ProblemSink) -> XmlDocument | None:
    """Parse ``path`` with the hardened parser; on failure record problems and return None."""
    data = _read_limited(path, sink)
    if data is None:
        return None
    return parse_bytes(data, path, sink)


_BOMS = (  # UTF-32 first: its little-endian BOM starts with UTF-16's
    (codecs.BOM_UTF32_LE, "utf-32"),
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF8, "utf-8-sig"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)
_NO_BOM = (  # XML 1.0 appendix F: "<" or "<?" in a wide encoding without a BOM
    (b"\x00\x00\x00<", "utf-32-be"),
    (b"<\x00\x00\x00", "utf-32-le"),
    (b"\x00<\x00?", "utf-16-be"),
    (b"<\x00?\x00", "utf-16-le"),
)
_DECLARATION = re.compile(r"""^(\s*<\?xml[^>]*?\sencoding\s*=\s*)(["'])([A-Za-z][\w.\-]*)\2""")


def _decode(data: bytes, sink: ProblemSink) -> str | None:
    """The document as text, decoded *before* libxml2 sees it.

    Decoding first means the DOCTYPE guard below sees every encoding (a byte scan misses
    UTF-16, and libxml2 would process the internal subset before any later check).
    """
    codec = next((c for bom, c in _BOMS if data.startswith(bom)), None)
    if codec is None:
        codec = next((c for head, c in _NO_BOM if data.startswith(head)), None)
    if codec is None:
        declared = _DECLARATION.match(data[:200].decode("latin-1"))
        if data.lstrip()[:1] != b"<":
            sink.add("xml-syntax", "not an XML document (it does not start with '<')", 1, 1)
            return None
        codec = declared.group(3) if declared else "utf-8"
        try:
            codecs.lookup(codec)
        except LookupError:
            sink.add("encoding", f"unknown character encoding '{codec}'", 1, 1)
            return None
    try:
        return data.decode(codec)
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        what = "not an XML document: " if exc.start < 64 else ""
        sink.add(
            "xml-syntax",
            f"{what}not valid {codec.upper()} text (byte 0x{data[exc.start]:02x})",
            line,
            column,
        )
        return None


def parse_bytes(data: bytes, path: Path, sink: ProblemSink) -> XmlDocument | None:
    """Parse XML ``data`` read from ``path`` (used for messages only)."""
    if len(data) > MAX_FILE_BYTES:
        sink.add("too-large", f"input is larger than {MAX_FILE_BYTES} bytes", 1, 1)
        return None
    if not data.strip():
        sink.add("empty", "file is empty; expected an XML document", 1, 1)
        return None
    text = _decode(data, sink)
    if text is None:
        return None
    text = text.removeprefix("\ufeff")
    if not text.strip():
        sink.add("empty", "file is empty; expected an XML document", 1, 1)
        return None
    doctype = _DOCTYPE.search(text)
    if doctype:
        line = text.count("\n", 0, doctype.start()) + 1
        col = doctype.start() - (text.rfind("\n", 0, doctype.start()) + 1) + 1
        sink.add(
            "doctype",
            "DOCTYPE declarations are not allowed: walkaround files use no DTD and no "
            "entities (this also blocks external-entity and entity-expansion attacks)",
            line,
            col,
        )
        return None
    # libxml2 parses the UTF-8 re-encoding; lines are unchanged (only the declaration's
    # encoding name is rewritten), and columns are recovered from `text`.
    text = _DECLARATION.sub(lambda m: f"{m.group(1)}{m.group(2)}UTF-8{m.group(2)}", text, 1)
    parser = _hardened_parser()
    try:
        root = etree.fromstring(text.encode("utf-8"), parser)
    except etree.XMLSyntaxError:
        entries = [e for e in parser.error_log if e.level >= etree.ErrorLevels.ERROR]
        if not entries:
            sink.add("xml-syntax", "not well-formed XML", 1, 1)
        for entry in entries[:10]:
            message = entry.message.strip() or "not well-formed XML"
            if message == "Document is empty" or message.startswith("Start tag expected"):
                message = "not an XML document (no root element found)"
            sink.add("xml-syntax", message, entry.line, entry.column)
        return None
    except (ValueError, etree.LxmlError) as exc:
        sink.add("xml-syntax", f"cannot parse the file: {exc}", 1, 1)
        return None
    doc = XmlDocument(path=path, display=sink.file, root=root, text=text)
    if root.getroottree().docinfo.doctype:  # unreachable after the text scan; kept as a guard
        sink.add("doctype", "DOCTYPE declarations are not allowed", *doc.locate(root))
        return None
    count = sum(1 for _ in root.iter())
    if count > MAX_ELEMENTS:
        sink.add(
            "too-many-elements",
            f"the file has {count} elements; the limit is {MAX_ELEMENTS} (walkaround files "
            "have a few hundred)",
            1,
            1,
        )
        return None
    deep = _first_too_deep(root)
    if deep is not None:
        line, column = doc.locate(deep)
        sink.add("too-deep", f"elements are nested more than {MAX_DEPTH} levels deep", line, column)
        return None
    for node in root.iter(etree.Entity):  # undeclared references cannot survive parsing,
        line, col = doc.locate(node.getparent())  # but keep the guarantee explicit
        sink.add("entity", "entity references are not allowed", line, col)
    _foreign_namespaces(doc, sink)
    return None if sink else doc


MAX_FOREIGN_REPORTED = 20
"""Foreign-namespace problems reported per file (a file full of them says so once)."""


def _foreign_namespaces(doc: XmlDocument, sink: ProblemSink) -> None:
    """Report every element outside the root's namespace and every namespaced attribute.

    walkaround formats have no extension points: a prefixed ``<x:foo>``, an XInclude
    ``<xi:include>`` (never processed) or an ``x:bar="..."`` attribute is a mistake, found
    here with its location before the XSD (whose error paths name prefixes that XPath
    cannot resolve) sees it.
    """
    namespace = etree.QName(doc.root).namespace
    found = 0
    for element in doc.iter_elements():
        qname = etree.QName(element)
        bad: list[tuple[str | None, str]] = []
        if element is not doc.root and qname.namespace not in (namespace, None):
            where = f"namespace '{qname.namespace}'" if qname.namespace else "no namespace"
            what = "an XInclude" if qname.namespace in _XINCLUDE else "an element"
            bad.append(
                (
                    None,
                    f"<{_prefixed(element, element.tag)}> is {what} in {where}; walkaround "
                    f"files allow only elements of '{namespace or 'no namespace'}' "
                    "(XInclude and extensions are not processed)",
                )
            )
        for name in element.attrib:
            if etree.QName(name).namespace is not None:
                shown = _prefixed(element, name)
                bad.append(
                    (
                        shown,
                        f"<{qname.localname}> attribute '{shown}' is in namespace "
                        f"'{etree.QName(name).namespace}'; walkaround attributes have no "
                        "namespace",
                    )
                )
        for attribute, message in bad:
            found += 1
            if found <= MAX_FOREIGN_REPORTED:
                sink.add("foreign-namespace", message, *doc.locate(element, attribute))
    if found > MAX_FOREIGN_REPORTED:
        sink.add(
            "foreign-namespace",
            f"{found - MAX_FOREIGN_REPORTED} more elements or attributes in foreign namespaces",
            *doc.locate(doc.root),
        )


_XINCLUDE = {"http://www.w3.org/2001/XInclude", "http://www.w3.org/2003/XInclude"}


def _prefixed(element: etree._Element, tag: str) -> str:
    """``prefix:local`` as written in the source for a ``{uri}local`` name."""
    qname = etree.QName(tag)
    if qname.namespace is None:
        return qname.localname
    if qname.namespace == "http://www.w3.org/XML/1998/namespace":
        return f"xml:{qname.localname}"
    for prefix, uri in (element.nsmap or {}).items():
        if uri == qname.namespace and prefix:
            return f"{prefix}:{qname.localname}"
    return qname.localname


def _first_too_deep(root: etree._Element) -> etree._Element | None:
    """The first element (in document order) nested deeper than :data:`MAX_DEPTH`."""
    stack = [(root, 1)]
    while stack:
        element, depth = stack.pop()
        if depth > MAX_DEPTH:
            return element
        stack.extend((child, depth + 1) for child in reversed(element))
    return None


# -- XSD ------------------------------------------------------------------------------
@functools.cache
def load_schema(xsd_path: Path) -> etree.XMLSchema:
    """Compile (once) one of walkaround's own XSD files."""
    tree = etree.parse(str(xsd_path), _hardened_parser())
    return etree.XMLSchema(tree)


_TYPE_WORDS = {
    "xs:double": "a number",
    "finiteDouble": "a finite number",
    "positiveLength": "a number greater than 0",
    "positiveDouble": "a number greater than 0",
    "nonNegative": "a number of at least 0",
    "angleDeg": "an angle in degrees between -360 and 360",
    "fovDeg": "an angle in degrees between 0 and 360",
    "identifier": "an identifier (a letter, then letters, digits, '_', '.' or '-')",
    "nonEmptyToken": "a non-empty name",
    "relativePath": "a relative file path",
    "xs:positiveInteger": "a whole number greater than 0",
    "xs:integer": "a whole number",
    "xs:token": "a name",
}


def _plain_facet(text: str) -> str:
    """Reword libxml2's ``[facet '...']`` sentences."""
    m = re.match(r"\[facet '(\w+)'\] The value '([^']*)' (.*)", text, re.S)
    if not m:
        return text
    facet, value, rest = m.groups()
    if value.strip().lstrip("+-").lower() in {"nan", "inf", "infinity"}:
        return f"'{value}' is not a finite number"
    if facet == "enumeration":
        options = re.findall(r"'([^']*)'", rest)
        return f"'{value}' is not one of: {', '.join(options)}"
    bounds = re.findall(r"'([^']*)'", rest)  # "... the maximum value ('360')."
    limit = bounds[-1] if bounds else ""
    wording = {
        "minExclusive": f"must be greater than {limit}",
        "maxExclusive": f"must be smaller than {limit}",
        "minInclusive": f"must be at least {limit}",
        "maxInclusive": f"must be at most {limit}",
    }.get(facet)
    if wording:
        return f"{wording}, not {value}"
    if facet in ("maxLength", "minLength"):
        what = "at most" if facet == "maxLength" else "at least"
        return f"is {len(value)} characters long; it must be {what} {limit}"
    if facet == "pattern":
        if "A-Za-z0-9_" in rest:
            return f"'{value}' is not {_TYPE_WORDS['identifier']}"
        return f"'{value}' is not in the expected form"
    return f"'{value}' {rest}".rstrip(".")


def _plain_schema_message(message: str) -> tuple[str, str | None]:
    """A shorter, namespace-free wording of a libxml2 validity message, and the attribute."""
    text = _NS_BRACES.sub("", message).strip()
    attribute = None
    m = re.match(r"Element '([^']+)', attribute '([^']+)': (.*)", text, re.S)
    if m:
        element, attribute, rest = m.groups()
        type_m = re.match(r"'(.*)' is not a valid value of the atomic type '([^']+)'\.", rest)
        if type_m:
            value, type_name = type_m.groups()
            wanted = _TYPE_WORDS.get(type_name, f"a valid {type_name}")
            rest = f"'{value}' is not {wanted}"
        elif rest.startswith("The attribute") and "is not allowed" in rest:
            rest = "unknown attribute"
        else:
            rest = _plain_facet(rest)
        text = f"<{element}> attribute '{attribute}': {rest}"
        return text.rstrip("."), attribute
    m = re.match(r"Element '([^']+)': (.*)", text, re.S)
    if m:
        element, rest = m.groups()
        missing = re.match(r"The attribute '([^']+)' is required but missing\.", rest)
        if missing:
            return f"<{element}> is missing the required attribute '{missing.group(1)}'", None
        unexpected = re.match(r"This element is not expected\.(?: Expected is (.*))?", rest, re.S)
        if unexpected:
            expected = unexpected.group(1)
            if expected:
                names = re.findall(r"[\w\-]+", expected.strip(" ().").replace("##other", ""))
                wanted = ", ".join(f"<{n}>" for n in names)
                return f"<{element}> is not expected here; expected {wanted}", None
            return f"<{element}> is not expected here", None
        missing_child = re.match(r"Missing child element\(s\)\. Expected is (.*)", rest, re.S)
        if missing_child:
            names = re.findall(r"[\w\-]+", missing_child.group(1))
            wanted = ", ".join(f"<{n}>" for n in names)
            return f"<{element}> is incomplete: missing {wanted}", None
        return f"<{element}>: {rest}".rstrip("."), None
    return text.rstrip("."), None


@dataclass(frozen=True)
class Range:
    """The physical range of a numeric XSD type: its facets and its unit (xs:appinfo)."""

    low: float
    low_inclusive: bool
    high: float
    high_inclusive: bool
    unit: str
    integer: bool = False

    def __str__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        low = _number(self.low) + ("" if self.low_inclusive else " (excluded)")
        high = _number(self.high) + ("" if self.high_inclusive else " (excluded)")
        return f"between {low} and {high}{unit}"


_XS = "{http://www.w3.org/2001/XMLSchema}"


def _number(value: float) -> str:
    """A bound as written in the XSD: whole numbers in full (a seed's 4294967295)."""
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else f"{value:g}"


@functools.cache
def attribute_ranges(xsd_path: Path) -> dict[tuple[str, str], Range]:
    """(element name, attribute name) -> the attribute's range, read from the XSD's facets.

    The ranges are written once, as facets of named types in the XSD; this reads them
    back so that a value out of range is reported with the whole range and its unit.
    Element names whose declarations disagree on an attribute's range are left out.
    """
    root = etree.parse(str(xsd_path), _hardened_parser()).getroot()
    simple = {t.get("name"): t for t in root.iter(f"{_XS}simpleType") if t.get("name")}

    def type_range(name: str) -> Range | None:
        bounds: dict[str, float] = {}
        unit = ""
        integer = name.endswith("Integer")
        while name in simple:
            node = simple[name]
            info = node.find(f"{_XS}annotation/{_XS}appinfo")
            if info is not None and not unit:
                unit = (info.text or "").strip()
            restriction = node.find(f"{_XS}restriction")
            if restriction is None:
                return None
            for facet in restriction:
                tag = etree.QName(facet).localname if isinstance(facet.tag, str) else ""
                if tag.startswith(("min", "max")) and tag not in bounds:
                    bounds[tag] = float(facet.get("value", "nan"))
            name = restriction.get("base", "")
            integer = integer or name.endswith("Integer")
        low = [(v, k == "minInclusive") for k, v in bounds.items() if k.startswith("min")]
        high = [(v, k == "maxInclusive") for k, v in bounds.items() if k.startswith("max")]
        if not low or not high or abs(high[0][0]) > 1e300:
            return None
        return Range(low[0][0], low[0][1], high[0][0], high[0][1], unit, integer)

    by_type: dict[str, dict[str, Range]] = {}
    for complex_type in root.iter(f"{_XS}complexType"):
        attrs: dict[str, Range] = {}
        for attribute in complex_type.iter(f"{_XS}attribute"):
            found = type_range(attribute.get("type", ""))
            if found is not None:
                attrs[attribute.get("name", "")] = found
        by_type[complex_type.get("name", "")] = attrs
    ranges: dict[tuple[str, str], Range] = {}
    ambiguous: set[tuple[str, str]] = set()
    for element in root.iter(f"{_XS}element"):
        for attribute, found in by_type.get(element.get("type", ""), {}).items():
            key = (element.get("name", ""), attribute)
            if ranges.setdefault(key, found) != found:
                ambiguous.add(key)
    return {k: v for k, v in ranges.items() if k not in ambiguous}


_OUT_OF_RANGE = re.compile(
    r"Element '(?:\{[^}]*\})?([\w.\-]+)', attribute '([\w.\-]+)': (?:\[facet '(?:min|max)"
    r"(?:In|Ex)clusive'\] The value '([^']*)'|'([^']*)' is not a valid value of the atomic type)",
    re.S,
)


def _range_message(raw: str, ranges: dict[tuple[str, str], Range]) -> str | None:
    """``<e> attribute 'a': must be between L and H unit, not V`` for an out-of-range or
    non-numeric value of an attribute with a known range, else None."""
    m = _OUT_OF_RANGE.match(raw)
    if not m or (m.group(1), m.group(2)) not in ranges:
        return None
    element, attribute = m.group(1), m.group(2)
    value = m.group(3) if m.group(3) is not None else m.group(4)
    wanted = ranges[(element, attribute)]
    if value.strip().lstrip("+-").lower() in {"nan", "inf", "infinity"}:
        what = "is not a finite number"
    elif m.group(3) is None:
        what = "is not a whole number" if wanted.integer else "is not a number"
    else:
        what = "is out of range"
    return f"<{element}> attribute '{attribute}': '{value}' {what}; it must be {wanted}"


_LONG_QUOTED = re.compile(r"'([^']{61,})'")


def _shorten(match: re.Match[str]) -> str:
    """A quoted value cut to a readable length: messages never echo a huge value whole."""
    value = match.group(1)
    return f"'{value[:40]}...' ({len(value)} characters)"


def validate_against(doc: XmlDocument, xsd_path: Path, sink: ProblemSink) -> bool:
    """Validate ``doc`` against an XSD; record every violation with its location."""
    schema = load_schema(xsd_path)
    if schema.validate(doc.root):
        return True
    tree = doc.root.getroottree()
    seen: set[tuple[int, int]] = set()
    ranges = attribute_ranges(xsd_path)
    entries = list(schema.error_log)
    for n, entry in enumerate(entries):
        if len(seen) >= MAX_SCHEMA_PROBLEMS:
            sink.add(
                "schema",
                f"{len(entries) - n} more schema problems not shown (the first "
                f"{MAX_SCHEMA_PROBLEMS} are listed)",
                entry.line,
                0,
            )
            break
        message, attribute = _plain_schema_message(entry.message)
        message = _range_message(entry.message, ranges) or message
        message = _LONG_QUOTED.sub(_shorten, message)
        line, column = entry.line, entry.column
        try:
            nodes = tree.xpath(entry.path) if entry.path else []
        except (etree.XPathError, ValueError):  # a path that does not evaluate: use the line
            nodes = []
        if nodes and isinstance(nodes[0], etree._Element):
            line, column = doc.locate(nodes[0], attribute)
        if (line, column) in seen:  # libxml2 follows a failed facet with its consequences
            continue
        seen.add((line, column))
        sink.add("schema", message, line, column)
    return False
