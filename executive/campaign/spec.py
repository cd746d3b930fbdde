"""The campaign file (``schemas/campaign.xsd``, namespace ``urn:walkaround:campaign:1``).

:func:`load_campaign` reads one with the hardened front end every loader shares, loads
its base scenarios (and through them their missions), and reports every problem with
``file:line:column`` in one :class:`~executive.core.problems.InvalidInputError`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from executive.core.problems import InvalidInputError, Problem, ProblemSink, file_kind
from executive.core.xmlreader import (
    MAX_REFERENCE_CHARS,
    ElementReader,
    display_path,
    library_root_of,
    load_document,
    local_name,
    problems_of,
)
from executive.core.xmlsafe import XmlDocument
from sim2d.cameras import camera_rigs
from sim2d.scenario import Body, FaultKind, ObstacleKind, Scenario, load_scenario

CAMPAIGN_NS = "urn:walkaround:campaign:1"
DEFAULT_NEAR_MISS = 0.3
"""Metres of true clearance under which an approach counts as a near miss."""
DEFAULT_TIMING = 1.5
"""Seconds a crossing may reach its leg before or after the robot."""
DEFAULT_SPREAD = 10.0
"""Metres around the route's bounding box where clutter may stand."""


@dataclass(frozen=True, slots=True)
class Range:
    """A closed interval drawn uniformly (``lo == hi``: that value)."""

    lo: float
    hi: float

    def draw(self, rng: np.random.Generator) -> float:
        return self.lo if self.hi <= self.lo else float(rng.uniform(self.lo, self.hi))


@dataclass(frozen=True, slots=True)
class CountRange:
    """Whole numbers from ``lo`` to ``hi`` inclusive, drawn uniformly."""

    lo: int
    hi: int

    def draw(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.lo, self.hi + 1))


@dataclass(frozen=True, slots=True)
class BaseScenario:
    scenario: Scenario
    weight: float
    file: str
    """The path as written in the campaign (relative to it)."""


@dataclass(frozen=True, slots=True)
class ParkingOffsetDist:
    dx: Range
    dy: Range
    dheading_deg: Range


@dataclass(frozen=True, slots=True)
class MoverShape:
    kind: ObstacleKind
    body: Body
    height: float
    weight: float


@dataclass(frozen=True, slots=True)
class ChaserDist:
    share: float
    offset: Range
    trigger: Range
    pursuit: Range | None


@dataclass(frozen=True, slots=True)
class MoverDist:
    count: CountRange
    speed: Range
    clearance: float
    half_length: Range
    timing: float
    min_leg: float
    shapes: tuple[MoverShape, ...]
    chasers: ChaserDist | None = None


@dataclass(frozen=True, slots=True)
class StaticShape:
    """A drawn static obstacle: a disc (``radius``) or a box (``length`` x ``width``)."""

    kind: ObstacleKind
    weight: float
    height: float
    radius: Range | None = None
    length: Range | None = None
    width: Range | None = None


@dataclass(frozen=True, slots=True)
class ClutterDist:
    """Static obstacles off the route."""

    count: CountRange
    clearance: float
    spread: float
    shapes: tuple[StaticShape, ...]


@dataclass(frozen=True, slots=True)
class BlockerDist:
    """Static obstacles on the route's legs, leaving a passage."""

    count: CountRange
    lateral: float
    end_margin: float
    gap: float
    corridor: float
    min_leg: float
    shapes: tuple[StaticShape, ...]


@dataclass(frozen=True, slots=True)
class FaultDist:
    kind: FaultKind
    probability: float
    at: Range
    duration: Range
    target: str | None = None
    factor: Range | None = None


@dataclass(frozen=True, slots=True)
class Campaign:
    id: str
    seed: int
    episodes: int
    scenarios: tuple[BaseScenario, ...]
    duration: float | None = None
    near_miss: float = DEFAULT_NEAR_MISS
    parking_offset: ParkingOffsetDist | None = None
    movers: MoverDist | None = None
    clutter: ClutterDist | None = None
    blockers: BlockerDist | None = None
    noise_scale: Range | None = None
    faults: tuple[FaultDist, ...] = ()
    description: str = ""
    source: str = ""
    digest: str = ""
    """SHA-256 of the campaign file and its base scenario files: what a resume and a
    merge check to refuse results of another campaign."""

    def with_seed(self, seed: int) -> Campaign:
        return dataclasses.replace(self, seed=seed)


def default_library_root(campaign_path: Path) -> Path:
    """``<library>/campaigns/<name>.xml`` -> ``<library>`` (e.g. ``missions/``)."""
    return library_root_of(campaign_path, 2)


def load_campaign(path: Path | str, library_root: Path | str | None = None) -> Campaign:
    """Load and check a campaign and its scenarios; raise InvalidInputError on any problem."""
    return load_document(path, "campaign", CAMPAIGN_NS, _build, library_root, 2)


def check_campaign(path: Path | str, library_root: Path | str | None = None) -> list[Problem]:
    """Every problem of a campaign file (empty when valid); never raises."""
    return problems_of(lambda: load_campaign(path, library_root))


# -- building ----------------------------------------------------------------------------------
def _range(r: ElementReader, el: etree._Element, name: str) -> Range:
    lo, hi = r.num(el, f"{name}-min"), r.num(el, f"{name}-max")
    if lo > hi:
        r.problem(
            el,
            "min-above-max",
            f"{name}-min ({lo:g}) is above {name}-max ({hi:g})",
            f"{name}-min",
        )
    return Range(lo, hi)


def _opt_range(r: ElementReader, el: etree._Element, name: str) -> Range | None:
    has_lo, has_hi = el.get(f"{name}-min") is not None, el.get(f"{name}-max") is not None
    if has_lo != has_hi:
        r.problem(el, "incomplete-range", f"give both {name}-min and {name}-max, or neither")
        return None
    return _range(r, el, name) if has_lo else None


def _count(r: ElementReader, el: etree._Element) -> CountRange:
    lo, hi = r.integer(el, "count-min"), r.integer(el, "count-max")
    if lo > hi:
        r.problem(el, "min-above-max", f"count-min ({lo}) is above count-max ({hi})", "count-min")
    return CountRange(lo, hi)


def _mover_shape(r: ElementReader, el: etree._Element) -> MoverShape:
    radius = r.opt_num(el, "radius")
    length, width = r.opt_num(el, "length"), r.opt_num(el, "width")
    kind = ObstacleKind(r.str_(el, "kind"))
    if radius is not None and length is None and width is None:
        body = Body(radius=radius)
    elif radius is None and length is not None and width is not None:
        body = Body(length=length, width=width)
    else:
        r.problem(
            el,
            "mover-shape",
            f"mover '{kind}': give either 'radius' (a disc) or both 'length' and 'width' (a box)",
        )
        body = Body(radius=0.3)
    return MoverShape(kind, body, r.num(el, "height"), r.num(el, "weight", 1.0))


def _static_shape(r: ElementReader, el: etree._Element) -> StaticShape:
    kind = ObstacleKind(r.str_(el, "kind"))
    weight, height = r.num(el, "weight", 1.0), r.num(el, "height")
    if local_name(el) == "circle":
        return StaticShape(kind, weight, height, radius=_range(r, el, "radius"))
    return StaticShape(
        kind, weight, height, length=_range(r, el, "length"), width=_range(r, el, "width")
    )


def _movers(r: ElementReader, el: etree._Element) -> MoverDist:
    clearance = r.num(el, "clearance")
    half_length = _range(r, el, "half-length")
    if half_length.lo < clearance:
        r.problem(
            el,
            "crossing-inside-clearance",
            f"half-length-min ({half_length.lo:g} m) is below the clearance ({clearance:g} m): "
            "a crossing would start or end too close to the leg it crosses",
            "half-length-min",
        )
    chasers = None
    chaser_el = r.child(el, "chasers")
    if chaser_el is not None:
        offset = _range(r, chaser_el, "offset")
        if offset.lo < clearance:
            r.problem(
                chaser_el,
                "chaser-inside-clearance",
                f"offset-min ({offset.lo:g} m) is below the movers' clearance "
                f"({clearance:g} m): a chaser would wait too close to the route",
                "offset-min",
            )
        chasers = ChaserDist(
            share=r.num(chaser_el, "share"),
            offset=offset,
            trigger=_range(r, chaser_el, "trigger"),
            pursuit=_opt_range(r, chaser_el, "pursuit"),
        )
    return MoverDist(
        count=_count(r, el),
        speed=_range(r, el, "speed"),
        clearance=clearance,
        half_length=half_length,
        timing=r.num(el, "timing", DEFAULT_TIMING),
        min_leg=r.num(el, "min-leg", 0.0),
        shapes=tuple(_mover_shape(r, m) for m in r.children(el, "mover")),
        chasers=chasers,
    )


def _statics(r: ElementReader, el: etree._Element) -> tuple[StaticShape, ...]:
    return tuple(_static_shape(r, e) for e in r.elements(el))


def _fault(r: ElementReader, el: etree._Element) -> FaultDist:
    kind = FaultKind(local_name(el))
    target = el.get("laser") or el.get("camera") or el.get("bumper")
    needs = {
        FaultKind.LASER_DROPOUT: "laser",
        FaultKind.CAMERA_FREEZE: "camera",
        FaultKind.PTU_FREEZE: "camera",
        FaultKind.BUMPER_HIT: "bumper",
    }.get(kind)
    given = [a for a in ("laser", "camera", "bumper") if el.get(a) is not None]
    if needs is not None and given != [needs]:
        r.problem(el, "fault-target", f"<{kind}> names its device with '{needs}' (only)")
    return FaultDist(
        kind=kind,
        probability=r.num(el, "probability"),
        at=_range(r, el, "at"),
        duration=_range(r, el, "duration"),
        target=target.strip() if target else None,
        factor=_range(r, el, "factor") if kind is FaultKind.SLIP_BURST else None,
    )


def _scenario_ref(
    r: ElementReader, el: etree._Element, source: Path, library_root: Path
) -> Scenario | None:
    """The base scenario named by ``el``'s ``file``: relative to the campaign file and
    inside the mission library; its own problems are listed with its name."""
    ref = r.str_(el, "file")

    def complain(code: str, message: str) -> None:
        r.problem(el, f"scenario-{code}", message, "file")

    if len(ref) > MAX_REFERENCE_CHARS:
        complain("path", f"scenario path is {len(ref)} characters long")
        return None
    if Path(ref).is_absolute() or ref.startswith(("/", "\\")) or ":" in ref.split("/")[0]:
        complain("path", f"scenario path '{ref}' must be relative to the campaign file")
        return None
    try:
        library = library_root.resolve()
        target = (source.resolve().parent / ref).resolve()
    except (OSError, RuntimeError) as exc:
        complain("path", f"scenario path '{ref}' cannot be resolved: {exc}")
        return None
    if not target.is_relative_to(library):
        complain(
            "path",
            f"scenario path '{ref}' leads outside the mission library root "
            f"'{display_path(library)}'",
        )
        return None
    try:
        mode = target.stat().st_mode
    except OSError:
        complain("path", f"scenario file '{ref}' does not exist")
        return None
    if not stat.S_ISREG(mode):
        complain("path", f"scenario file '{ref}' is {file_kind(mode)}, not a regular file")
        return None
    try:
        return load_scenario(target)
    except InvalidInputError as exc:
        complain(
            "invalid",
            f"scenario file '{ref}' has {len(exc.problems)} problem(s), listed with its name",
        )
        r.sink.extend(exc.problems)
        return None


def _digest(paths: list[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def _build(doc: XmlDocument, sink: ProblemSink, path: Path, root_dir: Path) -> Campaign | None:
    r = ElementReader(doc, sink)
    root = doc.root
    scenario_el = r.children(root, "scenario")
    bases: list[BaseScenario] = []
    for el in scenario_el:
        scenario = _scenario_ref(r, el, path, root_dir)
        if scenario is not None:
            bases.append(BaseScenario(scenario, r.num(el, "weight", 1.0), r.str_(el, "file")))

    offset_el = r.child(root, "parking-offset")
    offset = (
        ParkingOffsetDist(
            _range(r, offset_el, "dx"),
            _range(r, offset_el, "dy"),
            _range(r, offset_el, "dheading-deg"),
        )
        if offset_el is not None
        else None
    )
    movers_el = r.child(root, "movers")
    clutter_el = r.child(root, "clutter")
    blockers_el = r.child(root, "blockers")
    noise_el = r.child(root, "noise")
    fault_el = r.elements(r.child(root, "faults"))
    clutter = (
        ClutterDist(
            _count(r, clutter_el),
            r.num(clutter_el, "clearance"),
            r.num(clutter_el, "spread", DEFAULT_SPREAD),
            _statics(r, clutter_el),
        )
        if clutter_el is not None
        else None
    )
    blockers = (
        BlockerDist(
            count=_count(r, blockers_el),
            lateral=r.num(blockers_el, "lateral"),
            end_margin=r.num(blockers_el, "end-margin"),
            gap=r.num(blockers_el, "gap"),
            corridor=r.num(blockers_el, "corridor"),
            min_leg=r.num(blockers_el, "min-leg", 0.0),
            shapes=_statics(r, blockers_el),
        )
        if blockers_el is not None
        else None
    )
    if blockers is not None and blockers.corridor * 2.0 < blockers.gap:
        r.problem(
            blockers_el,
            "corridor-too-narrow",
            f"the corridor ({blockers.corridor:g} m each side of the leg) cannot hold a "
            f"passage of {blockers.gap:g} m",
            "corridor",
        )
    faults = tuple(_fault(r, e) for e in fault_el)
    for el, fault in zip(fault_el, faults, strict=True):
        for base in bases:
            _check_fault_target(r, el, fault, base)
    campaign = Campaign(
        id=r.str_(root, "id"),
        seed=r.integer(root, "seed"),
        episodes=r.integer(root, "episodes"),
        scenarios=tuple(bases),
        duration=r.opt_num(root, "duration"),
        near_miss=r.num(root, "near-miss", DEFAULT_NEAR_MISS),
        parking_offset=offset,
        movers=_movers(r, movers_el) if movers_el is not None else None,
        clutter=clutter,
        blockers=blockers,
        noise_scale=_range(r, noise_el, "scale") if noise_el is not None else None,
        faults=faults,
        description=r.text(r.child(root, "description")),
        source=sink.file,
    )
    if sink:
        return None
    files = [path, *(Path(b.scenario.source) for b in bases)]
    return dataclasses.replace(campaign, digest=_digest(files))


def _check_fault_target(
    r: ElementReader, el: etree._Element, fault: FaultDist, base: BaseScenario
) -> None:
    """A laser or camera fault must name a device of every base scenario's platform."""
    platform = base.scenario.mission.platform
    known: list[str] | None = None
    if fault.kind is FaultKind.LASER_DROPOUT:
        known, attribute = list(platform.lasers), "laser"
    elif fault.kind is FaultKind.CAMERA_FREEZE:
        known, attribute = [rig.id for rig in camera_rigs(platform.cameras)], "camera"
    elif fault.kind is FaultKind.PTU_FREEZE:
        known, attribute = list(platform.cameras), "camera"
    if known is None or fault.target in known:
        return
    r.problem(
        el,
        "unknown-reference",
        f"{attribute} '{fault.target}' is not a {attribute} of the platform of scenario "
        f"'{base.file}' (known: {', '.join(known) or 'none'})",
        attribute,
    )
