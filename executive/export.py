"""Views and exports of a compiled mission tree (``compile_mission(...).root``).

* :func:`to_ascii` - an indented text tree with composite markers and memory;
* :func:`to_dot` - Graphviz DOT text, written here (no pydot, no graphviz binary), whole
  or folded as the overview;
* :func:`render` - a PNG or SVG drawn with matplotlib, left to right (:func:`layout`: a
  column per depth, a row per leaf, no two boxes overlapping), of the whole tree or of
  its :func:`overview` (each navigation and checkpoint folded into one box);
* :func:`to_btcpp` - BehaviorTree.CPP v4 XML that Groot2 can open, one SubTree per
  navigation and checkpoint.

Node roles, shared by every view: a :class:`~behaviours.base.Guard` is a *condition*, a
:class:`~behaviours.base.Controller` a *controller*, any other leaf an *action*.

BehaviorTree.CPP v4 mapping
---------------------------

=====================================  ============================================
py_trees                               BT.CPP v4
=====================================  ============================================
``Sequence(memory=True)``              ``<Sequence>`` (resumes at the running child,
                                       restarts after a failure)
a Sequence with ``btcpp_tag``          that tag: ``ResumableSequence`` (the mission's
                                       phases) is ``<SequenceWithMemory>``, which
                                       keeps its place through a halt
``Sequence(memory=False)``             ``<ReactiveSequence>`` (e.g. ``GuardedBranch``)
``Selector(memory=True)``              ``<Fallback>``
``Selector(memory=False)``             ``<ReactiveFallback>`` (e.g. ``GuardSelector``)
``Parallel(SuccessOnAll)``             ``<Parallel success_count="-1" failure_count="1">``
``Parallel(SuccessOnOne)``             ``<Parallel success_count="1" failure_count="1">``
``Parallel(SuccessOnSelected(s))``     ``<Parallel success_count="len(s)" failure_count="1">``
``decorators.Inverter``                ``<Inverter>``
``decorators.FailureIsSuccess``        ``<ForceSuccess>``
``decorators.SuccessIsFailure``        ``<ForceFailure>``
``decorators.SuccessIsRunning``        ``<KeepRunningUntilFailure>``
other decorator / composite            ``<ClassName>``, declared ``Decorator``/``Control``
leaf (Guard / other)                   ``<ClassName name=...>``, declared ``Condition`` /
                                       ``Action`` in ``<TreeNodesModel>``
=====================================  ============================================

BT.CPP v4 writes a custom leaf as its own tag (v3's ``<Condition ID="...">`` is not used).
The tag is the Python class name (renamed ``Walkaround<Name>`` if it clashes with a
BT.CPP built-in, ``<Name>_2``... if two classes share a name). Attributes:

* ``name`` - the behaviour's name (lxml escapes it);
* one port per blackboard :class:`~behaviours.keys.Key` the node declares: a key it only
  reads is an ``input_port``, one it only writes an ``output_port``, one it reads and
  writes an ``inout_port``. Port name and blackboard entry are the key name with its
  separators replaced by ``_``: ``/state/pose`` -> ``state_pose="{state_pose}"`` (BT.CPP
  remapping syntax; one blackboard shared by the whole tree, as in walkaround);
* the node's parameters as constant ``input_port`` values. A behaviour may define
  ``bt_ports() -> Mapping[str, object]`` to choose them; otherwise they are read from the
  arguments of its ``__init__`` (``name`` excepted): the attribute of that name on the
  node, or a field of that name of a dataclass attribute (``EmergencyStop.latch.r_es``).
  bool -> ``true``/``false``, numbers -> ``repr``, enums -> their value, sequences of
  simple values -> ``a;b;c`` (BT.CPP's convention), an object with a string ``id`` -> the
  id, a dataclass -> its simple fields as ``<param>_<field>``; callables, ``None`` and
  anything else are left out (braces become parentheses: ``{`` would mean a key).

SubTrees: by default every navigation (``navigate <label>``) and every checkpoint
(``checkpoint <id>``) is a ``<BehaviorTree>`` of its own, ``Navigate_<label>`` /
``Checkpoint_<id>`` (IDs made of letters, digits, ``-`` and ``_``, as BT.CPP wants a model
name), referenced once by ``<SubTree ID=... name=... _autoremap="true"/>`` where the branch
stood: the main tree (``MainTree``, ~90 elements for the A320 instead of ~1560) shows the
modes and phases, a checkpoint's subtree its navigations as SubTrees again. ``_autoremap``
gives every subtree its parent's blackboard entries, BT.CPP's way of saying what walkaround
does: one blackboard for the whole tree. Expanding the SubTrees gives back the flat export
(``subtrees=None``) element for element.

BT.CPP rejects an attribute its model does not declare, so ``<TreeNodesModel>`` declares
every custom type once, with the union of the ports its instances use (blackboard ports
with ``default="{entry}"`` so a node dropped in Groot2 comes wired).

What BT.CPP cannot say exactly: its ``Parallel`` does not tick a child again once it has
finished, and it counts successes over all children. py_trees' ``SuccessOnSelected``
(used by the walkaround root: sensing runs beside the mission, every tick) therefore has
no one-to-one equivalent. With ``keep_running_unselected=True`` the children outside the
selection are wrapped in ``<KeepRunningUntilFailure>`` (py_trees ``SuccessIsRunning``),
which restores the py_trees semantics at the cost of one extra node per child; by default
the tree is exported node for node and the Parallel carries an XML comment saying so.
``<SequenceWithMemory>`` differs from a ``ResumableSequence`` in two details: after a
failure it retries the failed child instead of starting over (a failed walkaround mission
ends the run, so this never shows), and it has no ``rewind_to`` (a checkpoint paused
after it was reached resumes at its navigation).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
import math
import re
import textwrap
from collections.abc import Callable, Collection, Iterator, Mapping
from pathlib import Path

import matplotlib
import py_trees
from lxml import etree
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties, findfont
from matplotlib.ft2font import FT2Font, LoadFlags
from matplotlib.patches import Patch

from behaviours.base import Controller, Guard, Node

Behaviour = py_trees.behaviour.Behaviour

__all__ = [
    "BTCPP_BUILTINS",
    "Overview",
    "Placed",
    "bt_port_name",
    "layout",
    "mission_subtree_id",
    "overview",
    "render",
    "to_ascii",
    "to_btcpp",
    "to_dot",
    "tree_figure",
]

# -- classification -------------------------------------------------------------------------
SEQUENCE, SELECTOR, PARALLEL, DECORATOR, COMPOSITE = (
    "sequence",
    "selector",
    "parallel",
    "decorator",
    "composite",
)
CONDITION, CONTROLLER, ACTION = "condition", "controller", "action"
_COMPOSITES = (SEQUENCE, SELECTOR, PARALLEL, COMPOSITE)


def _kind(node: Behaviour) -> str:
    if isinstance(node, py_trees.composites.Sequence):
        return SEQUENCE
    if isinstance(node, py_trees.composites.Selector):
        return SELECTOR
    if isinstance(node, py_trees.composites.Parallel):
        return PARALLEL
    if isinstance(node, py_trees.composites.Composite):
        return COMPOSITE
    if isinstance(node, py_trees.decorators.Decorator):
        return DECORATOR
    if isinstance(node, Guard):
        return CONDITION
    if isinstance(node, Controller):
        return CONTROLLER
    return ACTION


def _memory(node: Behaviour) -> bool | None:
    """True/False for a Sequence or Selector, None for anything else."""
    if _kind(node) in (SEQUENCE, SELECTOR):
        return bool(node.memory)
    return None


def _preorder(node: Behaviour, depth: int = 0) -> Iterator[tuple[Behaviour, int]]:
    yield node, depth
    for child in node.children:
        yield from _preorder(child, depth + 1)


def _one_line(text: str) -> str:
    """``text`` with control characters shown as escapes, so it stays on one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _policy(node: py_trees.composites.Parallel) -> str:
    policy = node.policy
    name = type(policy).__name__
    if isinstance(policy, py_trees.common.ParallelPolicy.SuccessOnSelected):
        name += "(" + ", ".join(child.name for child in policy.children) + ")"
    if getattr(policy, "synchronise", False):
        name += ", synchronised"
    return name


def _description(node: Behaviour) -> str:
    """Class name, memory or policy: the second line of every view."""
    cls = type(node).__name__
    memory = _memory(node)
    if memory is not None:
        return f"{cls}, {'memory' if memory else 'reactive'}"
    if _kind(node) == PARALLEL:
        return f"{cls}, {_policy(node)}"
    return cls


_MARKERS_UNICODE = {
    SEQUENCE: "→",
    SELECTOR: "?",
    PARALLEL: "⇉",
    DECORATOR: "◇",
    COMPOSITE: "▣",
    CONDITION: "◯",
    CONTROLLER: "▶",
    ACTION: "■",
}
_MARKERS_ASCII = {
    SEQUENCE: "[->]",
    SELECTOR: "[?]",
    PARALLEL: "[=>]",
    DECORATOR: "[<>]",
    COMPOSITE: "[+]",
    CONDITION: "(c)",
    CONTROLLER: "[>]",
    ACTION: "[*]",
}


# -- text -----------------------------------------------------------------------------------
def to_ascii(root: Behaviour, *, unicode: bool = False) -> str:
    """An indented tree, one behaviour a line: ``<marker> <name>  (<class>, <memory>)``.

    Markers (ASCII / ``unicode=True``): Sequence ``[->]``/``→``, Selector ``[?]``/``?``,
    Parallel ``[=>]``/``⇉``, decorator ``[<>]``/``◇``, condition ``(c)``/``◯``,
    controller ``[>]``/``▶``, other action ``[*]``/``■``. Sequences and selectors say
    ``memory`` or ``reactive``; a parallel its policy.
    """
    markers = _MARKERS_UNICODE if unicode else _MARKERS_ASCII
    tee, last, pipe, blank = (
        ("├── ", "└── ", "│   ", "    ") if unicode else ("|-- ", "`-- ", "|   ", "    ")
    )
    lines: list[str] = []

    def walk(node: Behaviour, lead: str, branch: str) -> None:
        lines.append(
            f"{lead}{branch}{markers[_kind(node)]} {_one_line(node.name)}  ({_description(node)})"
        )
        inner = lead + (blank if branch in ("", last) else pipe)
        for i, child in enumerate(node.children):
            walk(child, inner, last if i == len(node.children) - 1 else tee)

    walk(root, "", "")
    return "\n".join(lines) + "\n"


# -- Graphviz DOT ---------------------------------------------------------------------------
_FILL = {
    SEQUENCE: "#cfe2ff",
    SELECTOR: "#ffe2b8",
    PARALLEL: "#e2d4f0",
    DECORATOR: "#eeeeee",
    COMPOSITE: "#eeeeee",
    CONDITION: "#fff3a8",
    CONTROLLER: "#c8ecc8",
    ACTION: "#e4e4e4",
}


def _dot_escape(text: str) -> str:
    """Text for the inside of a DOT double-quoted label (backslash, quote, line breaks)."""
    text = text.replace("\\", "\\\\").replace('"', '\\"')
    text = text.replace("\r\n", "\n").replace("\r", "\n").replace("\n", "\\n")
    return "".join(c if c.isprintable() else " " for c in text)


def _unfolded(node: Behaviour, fold: set[int]) -> Iterator[Behaviour]:
    """Pre-order, not below the nodes of ``fold`` (``id``s)."""
    yield node
    if id(node) not in fold:
        for child in node.children:
            yield from _unfolded(child, fold)


def to_dot(
    root: Behaviour,
    *,
    graph_name: str = "walkaround",
    folded: Collection[Behaviour] = (),
    rankdir: str = "TB",
) -> str:
    """Graphviz DOT text of the tree: one ``nK [...]`` line per behaviour (pre-order), then
    one ``nP -> nC`` edge per parent-child pair.

    Composites are boxes labelled with their marker (Sequence ``→``, Selector ``?``,
    Parallel ``⇉``) and ``memory``/``reactive``; memory composites get a double border.
    Conditions (guards) are ellipses, controllers rounded boxes, other actions rounded
    dashed boxes, decorators hexagons. A ``folded`` branch (:func:`overview`) is one node,
    with a thick blue border and the count of behaviours below it. ``rankdir``: Graphviz's
    ``TB`` (root on top) or ``LR`` (root on the left, a long sequence reads downwards).
    """
    if rankdir not in ("TB", "LR", "BT", "RL"):
        raise ValueError(f"to_dot: rankdir {rankdir!r} is not TB, LR, BT or RL")
    fold = {id(node) for node in folded}
    ids: dict[int, str] = {}
    nodes: list[str] = []
    edges: list[str] = []
    for node in _unfolded(root, fold):
        ident = f"n{len(ids)}"
        ids[id(node)] = ident
        kind = _kind(node)
        info = _description(node)
        hidden = sum(1 for _ in _preorder(node)) - 1 if id(node) in fold else 0
        if hidden:
            info += f" ▸ {hidden} folded"
        label = _dot_escape(f"{_MARKERS_UNICODE[kind]} {node.name}") + "\\n" + _dot_escape(info)
        attrs = [f'label="{label}"', f'fillcolor="{_FILL[kind]}"']
        if kind in _COMPOSITES:
            attrs += ["shape=box", 'style="filled"']
            if _memory(node):
                attrs.append("peripheries=2")
        elif kind == DECORATOR:
            attrs += ["shape=hexagon", 'style="filled"']
        elif kind == CONDITION:
            attrs += ["shape=ellipse", 'style="filled"']
        elif kind == CONTROLLER:
            attrs += ["shape=box", 'style="rounded,filled"']
        else:
            attrs += ["shape=box", 'style="rounded,filled,dashed"']
        if hidden:
            attrs += [f'color="{_FOLDED_EDGE}"', "penwidth=2.4"]
        nodes.append(f"  {ident} [{', '.join(attrs)}];")
    for node in _unfolded(root, fold):
        if id(node) not in fold:
            edges += [f"  {ids[id(node)]} -> {ids[id(child)]};" for child in node.children]
    header = [
        f'digraph "{_dot_escape(graph_name)}" {{',
        f"  graph [rankdir={rankdir}, ordering=out, nodesep=0.15, ranksep=0.45];",
        '  node [fontname="Helvetica", fontsize=10, margin="0.08,0.04"];',
        "  edge [arrowhead=none];",
    ]
    return "\n".join([*header, *nodes, *edges, "}"]) + "\n"


# -- layered layout and matplotlib drawing ----------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Placed:
    """One box of a drawing, in points (1/72 in), y growing downwards from the top."""

    node: Behaviour
    depth: int
    x: float
    """Left edge of the box."""
    y: float
    """Vertical centre of the box."""
    width: float
    height: float
    hidden: int
    """Behaviours folded away below this one (0: drawn with its children)."""
    label: str


@dataclasses.dataclass(frozen=True)
class Overview:
    """What the collapsed drawing folds: each navigation and checkpoint (the branches the
    BT.CPP export writes as SubTrees) is one box, except ``example``, the first navigation,
    drawn in full once as a legend of what every navigation holds (its guard selector)."""

    folded: tuple[Behaviour, ...]
    example: Behaviour | None

    def notes(self) -> dict[int, str]:
        """The drawing's note on the example (:func:`layout`'s ``notes``)."""
        if self.example is None:
            return {}
        return {id(self.example): "every navigation is like this one"}


def overview(root: Behaviour, rule: SubtreeRule | None = None) -> Overview:
    """The branches the overview folds (:class:`Overview`); ``rule`` defaults to
    :func:`mission_subtree_id`. The root is never folded."""
    rule = rule or mission_subtree_id
    folded: list[Behaviour] = []
    example: Behaviour | None = None

    def walk(node: Behaviour, top: bool) -> None:
        nonlocal example
        ident = None if top else rule(node)
        if ident is not None:
            if example is None and ident.startswith("Navigate_"):
                example = node
                return  # drawn in full, nothing folded inside
            folded.append(node)
            return
        for child in node.children:
            walk(child, False)

    walk(root, True)
    return Overview(tuple(folded), example)


_FONT = 8.0  # points
_WRAP = 44  # characters per line of a box
_PAD = 0.3  # box padding, in font sizes
_ROW_GAP = 5.0  # points between two rows
_COLUMN_GAP = 26.0  # points between two depth columns
_MARGIN = 18.0
_MAX_PIXELS = 65000  # Agg's limit is 2**16 pixels a side


@functools.cache
def _font(size: float) -> tuple[FT2Font, dict[str, float]]:
    """DejaVu Sans (matplotlib's font) at ``size`` points, and a cache of its characters'
    advance widths in points."""
    font = FT2Font(findfont(FontProperties(family="DejaVu Sans")))
    font.set_size(size, 72)
    return font, {}


def _text_size(text: str, size: float = _FONT) -> tuple[float, float]:
    """Width and height (points) of ``text`` drawn at ``size`` points: advance widths summed
    (no kerning, so 4 % more), lines 1.2 font sizes apart as matplotlib spaces them. A
    thousand times faster than asking a renderer, and what a 1500-box tree needs."""
    font, advances = _font(size)
    widths: list[float] = []
    for line in text.split("\n"):
        total = 0.0
        for char in line:
            if char not in advances:
                glyph = font.load_char(ord(char), flags=LoadFlags.NO_HINTING)
                advances[char] = glyph.linearHoriAdvance / 65536.0
            total += advances[char]
        widths.append(total)
    return max(widths) * 1.04 + 1.0, size * (1.2 * (len(widths) - 1) + 1.27)


def _box_size(node: Behaviour, label: str) -> tuple[float, float]:
    """The drawn box around ``label``: text plus padding; an ellipse (a condition) is
    sqrt(2) larger, as matplotlib's ``ellipse`` box style draws it."""
    w, h = _text_size(label)
    pad = 2.0 * _PAD * _FONT
    w, h = w + pad, h + pad
    if _kind(node) == CONDITION:
        w, h = w * math.sqrt(2.0), h * math.sqrt(2.0)
    return w + 2.0, h + 2.0  # the edge line


def _box_label(node: Behaviour, hidden: int = 0, note: str = "") -> str:
    kind = _kind(node)
    name = textwrap.wrap(
        _one_line(node.name), _WRAP, break_long_words=True, break_on_hyphens=False
    ) or [""]
    info = _description(node) if kind in (SEQUENCE, SELECTOR) else type(node).__name__
    if hidden:
        info += f" ▸ {hidden} folded"
    if note:
        info += f" · {note}"
    return "\n".join([f"{_MARKERS_UNICODE[kind]} {name[0]}", *name[1:], info])


def layout(
    root: Behaviour,
    *,
    folded: Collection[Behaviour] = (),
    notes: Mapping[int, str] | None = None,
) -> list[Placed]:
    """The drawing's boxes in pre-order, left to right by depth (BT.CPP's and Groot2's
    reading order turned sideways: a sequence reads downwards).

    Every depth is a column as wide as its widest box; every leaf (or folded branch) gets
    a row as tall as its box; a parent is centred on the rows of its children, and gets
    more room if its own box is taller than theirs: no two boxes overlap. ``folded``
    branches are drawn as one box counting the behaviours below; ``notes`` (``id(node)``
    -> text) are added to a box's second line."""
    notes = notes or {}
    fold = {id(node) for node in folded}
    shown: list[tuple[Behaviour, int, int, str, tuple[float, float]]] = []
    span: dict[int, float] = {}

    def measure(node: Behaviour, depth: int) -> float:
        hidden = sum(1 for _ in _preorder(node)) - 1 if id(node) in fold else 0
        label = _box_label(node, hidden, notes.get(id(node), ""))
        size = _box_size(node, label)
        shown.append((node, depth, hidden, label, size))
        own = size[1] + _ROW_GAP
        if node.children and not hidden:
            own = max(own, sum(measure(child, depth + 1) for child in node.children))
        span[id(node)] = own
        return own

    measure(root, 0)
    columns: dict[int, float] = {}
    for _, depth, _, _, (w, _) in shown:
        columns[depth] = max(columns.get(depth, 0.0), w)
    left = {0: _MARGIN}
    for depth in range(1, len(columns)):
        left[depth] = left[depth - 1] + columns[depth - 1] + _COLUMN_GAP
    info = {id(n): (d, hidden, label, size) for n, d, hidden, label, size in shown}
    placed: list[Placed] = []

    def place(node: Behaviour, top: float) -> None:
        depth, hidden, label, (w, h) = info[id(node)]
        placed.append(
            Placed(node, depth, left[depth], top + span[id(node)] / 2.0, w, h, hidden, label)
        )
        if node.children and not hidden:
            block = sum(span[id(child)] for child in node.children)
            y = top + (span[id(node)] - block) / 2.0
            for child in node.children:
                place(child, y)
                y += span[id(child)]

    place(root, _MARGIN)
    return placed


def _box_style(node: Behaviour, hidden: int) -> dict:
    kind = _kind(node)
    style = {
        "facecolor": _FILL[kind],
        "edgecolor": "#333333",
        "linewidth": 0.8,
        "boxstyle": f"round,pad={_PAD}",
    }
    if kind in _COMPOSITES:
        style["boxstyle"] = f"square,pad={_PAD}"
        if _memory(node):
            style["linewidth"] = 2.0
    elif kind == CONDITION:
        style["boxstyle"] = f"ellipse,pad={_PAD}"
    elif kind == DECORATOR:
        style["boxstyle"] = f"round4,pad={_PAD}"
    elif kind == ACTION:
        style["linestyle"] = "--"
    if hidden:
        style["edgecolor"] = _FOLDED_EDGE
        style["linewidth"] = 2.4
    return style


_FOLDED_EDGE = "#1f5fbf"
_LEGEND = (
    (SEQUENCE, "→ Sequence"),
    (SELECTOR, "? Selector"),
    (PARALLEL, "⇉ Parallel"),
    ("memory", "memory"),
    ("folded", "▸ folded branch"),
    (CONDITION, "◯ condition"),
    (CONTROLLER, "▶ controller"),
    (ACTION, "■ action"),
)


def tree_figure(
    root: Behaviour,
    *,
    folded: Collection[Behaviour] = (),
    notes: Mapping[int, str] | None = None,
) -> tuple[Figure, list[Placed]]:
    """The drawing of :func:`layout`'s boxes on a figure of their size (one axes unit is
    one point), elbow edges from a parent's right side to its children's left sides."""
    placed = layout(root, folded=folded, notes=notes)
    columns = max(p.x + p.width for p in placed) + _MARGIN
    legend_cols = max(1, min(len(_LEGEND), int(columns // 95.0)))
    legend_h = 16.0 * math.ceil(len(_LEGEND) / legend_cols) + 8.0
    width = max(columns, 6 * 72.0)
    bottom = max(p.y + p.height / 2.0 for p in placed) + _MARGIN
    height = bottom + legend_h
    where = {id(p.node): p for p in placed}
    with matplotlib.rc_context({"svg.fonttype": "none", "font.family": "DejaVu Sans"}):
        fig = Figure(figsize=(width / 72.0, height / 72.0))
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.set_xlim(0.0, width)
        ax.set_ylim(height, 0.0)  # y down, from the top
        ax.set_axis_off()
        segments = []
        for p in placed:
            kids = [where[id(c)] for c in p.node.children if id(c) in where]
            if not kids:
                continue
            mid = kids[0].x - _COLUMN_GAP / 2.0
            segments.append(((p.x + p.width, legend_h + p.y), (mid, legend_h + p.y)))
            ys = [legend_h + k.y for k in kids] + [legend_h + p.y]
            segments.append(((mid, min(ys)), (mid, max(ys))))
            segments += [((mid, legend_h + k.y), (k.x, legend_h + k.y)) for k in kids]
        ax.add_collection(LineCollection(segments, colors="#777777", linewidths=0.7, zorder=1))
        for p in placed:
            ax.text(
                p.x + p.width / 2.0,
                legend_h + p.y,
                p.label,
                ha="center",
                va="center",
                fontsize=_FONT,
                zorder=3,
                bbox=_box_style(p.node, p.hidden),
                parse_math=False,  # a "$" in a name is a dollar sign
            )
        handles = []
        for kind, text in _LEGEND:
            if kind == "memory":
                handles.append(
                    Patch(facecolor="white", edgecolor="#333333", linewidth=2.0, label=text)
                )
            elif kind == "folded":
                handles.append(
                    Patch(facecolor="white", edgecolor=_FOLDED_EDGE, linewidth=2.4, label=text)
                )
            else:
                style = {"linestyle": "--"} if kind == ACTION else {}
                handles.append(
                    Patch(facecolor=_FILL[kind], edgecolor="#333333", label=text, **style)
                )
        ax.legend(
            handles=handles,
            loc="upper left",
            ncols=legend_cols,
            fontsize=_FONT,
            frameon=False,
            bbox_to_anchor=(_MARGIN / width, 1.0 - 2.0 / height),
        )
    return fig, placed


def render(
    root: Behaviour,
    path: Path,
    *,
    dpi: float = 100.0,
    folded: Collection[Behaviour] = (),
    notes: Mapping[int, str] | None = None,
) -> Path:
    """Draw the tree to ``path``, a ``.png`` or ``.svg`` (no graphviz needed): the boxes of
    :func:`layout`, left to right, at a constant text size.

    The whole A320 tree (~1560 behaviours, ~990 leaves) is a tall figure, a column of rows
    (a PNG's resolution is lowered only where it would exceed Agg's 65536-pixel limit); with
    :func:`overview`'s ``folded`` branches it is one screen wide. SVG text is kept as text
    (searchable)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".svg"):
        raise ValueError(f"render: {path.name} should end in .png or .svg")
    fig, _ = tree_figure(root, folded=folded, notes=notes)
    width, height = fig.get_size_inches()
    if suffix == ".png":
        dpi = min(dpi, _MAX_PIXELS / max(width, height))
    path.parent.mkdir(parents=True, exist_ok=True)
    with matplotlib.rc_context({"svg.fonttype": "none", "font.family": "DejaVu Sans"}):
        fig.savefig(path, dpi=dpi, format=suffix[1:])
    return path


# -- BehaviorTree.CPP v4 ----------------------------------------------------------------------
BTCPP_BUILTINS = frozenset(
    {
        # controls
        "Sequence",
        "SequenceWithMemory",
        "ReactiveSequence",
        "Fallback",
        "ReactiveFallback",
        "Parallel",
        "ParallelAll",
        "IfThenElse",
        "WhileDoElse",
        "Switch2",
        "Switch3",
        "Switch4",
        "Switch5",
        "Switch6",
        "ManualSelector",
        "TryCatch",
        # decorators
        "Inverter",
        "ForceSuccess",
        "ForceFailure",
        "KeepRunningUntilFailure",
        "Repeat",
        "RetryUntilSuccessful",
        "Timeout",
        "Delay",
        "RunOnce",
        "Precondition",
        "LoopInt",
        "LoopDouble",
        "LoopString",
        "LoopBool",
        "SkipUnlessUpdated",
        "WaitValueUpdate",
        "SubTree",
        # leaves
        "AlwaysSuccess",
        "AlwaysFailure",
        "Script",
        "ScriptCondition",
        "SetBlackboard",
        "UnsetBlackboard",
        "Sleep",
        "WasEntryUpdated",
        "TestNode",
        # not node types, but tags/IDs with a meaning in the file
        "root",
        "Root",
        "BehaviorTree",
        "TreeNodesModel",
        "Action",
        "Condition",
        "Control",
        "Decorator",
    }
)
"""Tags BT.CPP v4 (or its file format) already gives a meaning: not used for custom types."""

_DECORATORS = {
    py_trees.decorators.Inverter: "Inverter",
    py_trees.decorators.FailureIsSuccess: "ForceSuccess",
    py_trees.decorators.SuccessIsFailure: "ForceFailure",
    py_trees.decorators.SuccessIsRunning: "KeepRunningUntilFailure",
}
_RESERVED_PORTS = {"name", "ID"}
_MODEL_CATEGORY = {
    CONDITION: "Condition",
    CONTROLLER: "Action",
    ACTION: "Action",
    DECORATOR: "Decorator",
    COMPOSITE: "Control",
}


def bt_port_name(name: str) -> str:
    """A name BT.CPP accepts as a port or blackboard entry: letters, digits and ``_``,
    starting with a letter (``/state/pose`` -> ``state_pose``)."""
    clean = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")
    if not clean or not clean[0].isalpha():
        clean = "p_" + clean
    return clean


_SIMPLE = (bool, int, float, str)


def _is_simple(value: object) -> bool:
    if isinstance(value, enum.Enum):
        return isinstance(value.value, _SIMPLE)
    return isinstance(value, _SIMPLE)


def _text(value: object) -> str:
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    return str(value).replace("{", "(").replace("}", ")")


def _cpp_type(value: object) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "double"
    return "std::string"


def _param_values(name: str, value: object) -> list[tuple[str, object]]:
    """``(attribute, simple value)`` pairs for one parameter (see the module docstring)."""
    if value is None or (callable(value) and not dataclasses.is_dataclass(value)):
        return []
    if _is_simple(value):
        return [(name, value)]
    if isinstance(value, tuple | list) and all(_is_simple(v) for v in value):
        return [(name, ";".join(_text(v) for v in value))]
    ident = getattr(value, "id", None)
    if isinstance(ident, str):
        return [(name, ident)]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        # flattened only when every field is simple: a record of numbers and words, not a model
        pairs: list[tuple[str, object]] = []
        for f in dataclasses.fields(value):
            sub = getattr(value, f.name, None)
            if f.name.startswith("_") or not f.compare or sub is None:
                continue
            if _is_simple(sub):
                pairs.append((f"{name}_{f.name}", sub))
            elif isinstance(sub, tuple | list) and all(_is_simple(v) for v in sub):
                pairs.append((f"{name}_{f.name}", ";".join(_text(v) for v in sub)))
            else:
                return []
        return pairs
    return []


def _parameters(node: Behaviour) -> dict[str, object]:
    """The node's parameters as ``{attribute: simple value}``."""
    raw: list[tuple[str, object]] = []
    custom = getattr(node, "bt_ports", None)
    if callable(custom):
        for key, value in dict(custom()).items():
            raw += _param_values(str(key), value)
    else:
        try:
            signature = inspect.signature(type(node).__init__)
        except (TypeError, ValueError):
            signature = None
        params = [] if signature is None else list(signature.parameters.values())[1:]
        holders = [
            v
            for k, v in vars(node).items()
            if not k.startswith("_") and dataclasses.is_dataclass(v) and not isinstance(v, type)
        ]
        for p in params:
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) or p.name == "name":
                continue
            if p.name in vars(node):
                raw += _param_values(p.name, vars(node)[p.name])
                continue
            for holder in holders:
                if p.name in {f.name for f in dataclasses.fields(holder)}:
                    raw += _param_values(p.name, getattr(holder, p.name))
                    break
    params_out: dict[str, object] = {}
    for key, value in raw:
        port = bt_port_name(key)
        if port not in _RESERVED_PORTS and port not in params_out:
            params_out[port] = value
    return params_out


class _Model:
    """The ``<TreeNodesModel>`` being built: one entry per custom type."""

    def __init__(self) -> None:
        self.ids: dict[type, str] = {}
        self.category: dict[str, str] = {}
        self.ports: dict[str, dict[str, tuple[str, str, str, str | None]]] = {}
        self.key_ports: dict[str, str] = {}

    def type_id(self, cls: type) -> str:
        if cls not in self.ids:
            base = cls.__name__
            if base in BTCPP_BUILTINS:
                base = "Walkaround" + base
            ident, n = base, 1
            taken = set(self.ids.values())
            while ident in taken:
                n += 1
                ident = f"{base}_{n}"
            self.ids[cls] = ident
            self.ports[ident] = {}
        return self.ids[cls]

    def key_port(self, key_name: str) -> str:
        """The port (and blackboard entry) of a walkaround key; distinct keys stay distinct."""
        if key_name not in self.key_ports:
            base = bt_port_name(key_name)
            port, n = base, 1
            while port in self.key_ports.values():
                n += 1
                port = f"{base}_{n}"
            self.key_ports[key_name] = port
        return self.key_ports[key_name]

    def declare(
        self, ident: str, port: str, direction: str, type_: str, text: str, default: str | None
    ) -> None:
        ports = self.ports[ident]
        if port not in ports:
            ports[port] = (direction, type_, text, default)
        elif ports[port][1] != type_:
            direction, _, text, default = ports[port]
            ports[port] = (direction, "std::string", text, default)

    def element(self) -> etree._Element:
        model = etree.Element("TreeNodesModel")
        for ident, category in self.category.items():
            entry = etree.SubElement(model, category, ID=ident)
            for port, (direction, type_, text, default) in self.ports[ident].items():
                element = etree.SubElement(entry, direction, name=port, type=type_)
                if default is not None:
                    element.set("default", default)
                element.text = text
        return model


def _leaf_attributes(node: Behaviour, ident: str, model: _Model) -> dict[str, str]:
    attrs: dict[str, str] = {}
    params = _parameters(node)
    ports: dict[str, tuple[str, str]] = {}  # port -> (direction, key name)
    if isinstance(node, Node):
        reads = [k.name for k in node.reads]
        writes = [k.name for k in node.writes]
        for key in dict.fromkeys([*reads, *writes]):
            direction = (
                "inout_port"
                if key in reads and key in writes
                else ("input_port" if key in reads else "output_port")
            )
            ports[model.key_port(key)] = (direction, key)
    for port, value in params.items():
        if port in ports:
            continue  # a blackboard port of the same name wins
        attrs[port] = _text(value)
        model.declare(ident, port, "input_port", _cpp_type(value), "parameter", None)
    record_types = {}
    if isinstance(node, Node):
        record_types = {k.name: k.type.__name__ for k in (*node.reads, *node.writes)}
    for port, (direction, key) in ports.items():
        attrs[port] = "{" + port + "}"
        model.declare(
            ident,
            port,
            direction,
            record_types.get(key, "std::string"),
            f"blackboard {key}",
            "{" + port + "}",
        )
    return attrs


def _parallel_counts(node: py_trees.composites.Parallel) -> tuple[int, int]:
    policy = node.policy
    if isinstance(policy, py_trees.common.ParallelPolicy.SuccessOnAll):
        return -1, 1
    if isinstance(policy, py_trees.common.ParallelPolicy.SuccessOnOne):
        return 1, 1
    if isinstance(policy, py_trees.common.ParallelPolicy.SuccessOnSelected):
        return len(policy.children), 1
    raise TypeError(f"'{node.name}': no BT.CPP equivalent for {type(policy).__name__}")


SubtreeRule = Callable[[Behaviour], str | None]
"""Which branches the BT.CPP export writes as SubTrees: the subtree's ID for such a branch's
root, None for any other node."""

_CHECKPOINT = re.compile(r"checkpoint (?P<id>.+?)(?: or skip)?")
_NAVIGATION = re.compile(r"navigate (?P<label>.+)")


def _model_name(text: str) -> str:
    """Text BT.CPP accepts as a tree ID: no space, ``/``, ``.``, ``:``... (``-`` and ``_`` stay)."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", text).strip("_") or "tree"


def mission_subtree_id(node: Behaviour) -> str | None:
    """The compiler's navigations (``navigate <label>``: ``Navigate_<label>``) and
    checkpoints (``checkpoint <id>``, or ``checkpoint <id> or skip`` with an operator at
    hand: ``Checkpoint_<id>``), the branches the BT.CPP export writes as SubTrees."""
    if not node.children:
        return None
    match = _CHECKPOINT.fullmatch(node.name)
    if match:
        return "Checkpoint_" + _model_name(match["id"])
    match = _NAVIGATION.fullmatch(node.name)
    if match:
        return "Navigate_" + _model_name(match["label"])
    return None


class _Subtrees:
    """The ``<BehaviorTree>`` elements of the subtrees, in the order they are referenced."""

    def __init__(self, rule: SubtreeRule, taken: set[str]) -> None:
        self.rule = rule
        self.taken = set(taken)
        self.trees: list[etree._Element] = []

    def define(self, base: str) -> tuple[str, etree._Element]:
        """A new ``<BehaviorTree>`` with an unused ID made from ``base``."""
        ident, n = base, 1
        while ident in self.taken:
            n += 1
            ident = f"{base}_{n}"
        self.taken.add(ident)
        tree = etree.Element("BehaviorTree", ID=ident)
        self.trees.append(tree)
        return ident, tree


def _bt_child(
    node: Behaviour,
    model: _Model,
    keep_running_unselected: bool,
    split: _Subtrees | None,
    inside: str | None,
) -> etree._Element:
    """The element for ``node`` below its parent: ``<SubTree>`` if the rule says so (not
    again for the root of the subtree being written, ``inside``), the node otherwise."""
    base = split.rule(node) if split is not None else None
    if split is None or base is None or base == inside:
        return _bt_element(node, model, keep_running_unselected, split, inside)
    ident, tree = split.define(base)
    tree.append(_bt_element(node, model, keep_running_unselected, split, base))
    # one blackboard for the whole tree, as in walkaround: every entry of the subtree is
    # its parent's (BT.CPP v4's _autoremap; BT.CPP's own examples write it this way)
    return etree.Element("SubTree", ID=ident, name=node.name, _autoremap="true")


def _bt_element(
    node: Behaviour,
    model: _Model,
    keep_running_unselected: bool,
    split: _Subtrees | None = None,
    inside: str | None = None,
) -> etree._Element:
    kind = _kind(node)
    memory = _memory(node)
    if kind == SEQUENCE:
        tag = getattr(node, "btcpp_tag", None) or ("Sequence" if memory else "ReactiveSequence")
        element = etree.Element(tag, name=node.name)
    elif kind == SELECTOR:
        element = etree.Element("Fallback" if memory else "ReactiveFallback", name=node.name)
    elif kind == PARALLEL:
        success, failure = _parallel_counts(node)
        element = etree.Element(
            "Parallel",
            name=node.name,
            success_count=str(success),
            failure_count=str(failure),
        )
    elif kind == DECORATOR and type(node) in _DECORATORS:
        element = etree.Element(_DECORATORS[type(node)], name=node.name)
    else:
        ident = model.type_id(type(node))
        model.category.setdefault(ident, _MODEL_CATEGORY[kind])
        element = etree.Element(ident, name=node.name)
        if kind not in (DECORATOR, COMPOSITE):
            for port, value in _leaf_attributes(node, ident, model).items():
                element.set(port, value)

    selected: list[Behaviour] | None = None
    if kind == PARALLEL and isinstance(
        node.policy, py_trees.common.ParallelPolicy.SuccessOnSelected
    ):
        selected = list(node.policy.children)
        if not keep_running_unselected and len(selected) < len(node.children):
            names = ", ".join(_one_line(c.name) for c in selected)
            while "--" in names:
                names = names.replace("--", "- -")
            element.append(
                etree.Comment(
                    f" py_trees SuccessOnSelected({names}): BT.CPP's Parallel counts the"
                    " successes of any child and does not tick a finished child again; export"
                    " with keep_running_unselected=True for the py_trees semantics "
                )
            )
    for child in node.children:
        sub = _bt_child(child, model, keep_running_unselected, split, inside)
        if keep_running_unselected and selected is not None and child not in selected:
            wrapper = etree.Element("KeepRunningUntilFailure", name=f"keep running: {child.name}")
            wrapper.append(sub)
            sub = wrapper
        element.append(sub)
    return element


def to_btcpp(
    root: Behaviour,
    *,
    tree_id: str = "MainTree",
    keep_running_unselected: bool = False,
    subtrees: SubtreeRule | None = mission_subtree_id,
) -> str:
    """BehaviorTree.CPP v4 XML of the tree (mapping in the module docstring), pretty-printed,
    without an XML declaration (UTF-8). Groot2 opens it: every custom node type is declared
    once in ``<TreeNodesModel>`` with its ports.

    ``subtrees`` names the branches written as ``<BehaviorTree>`` of their own and referenced
    with ``<SubTree ID=... _autoremap="true"/>`` (by default :func:`mission_subtree_id`:
    every navigation and checkpoint); ``None`` writes one flat tree."""
    model = _Model()
    document = etree.Element("root", BTCPP_format="4", main_tree_to_execute=tree_id)
    tree = etree.SubElement(document, "BehaviorTree", ID=tree_id)
    split = None
    if subtrees is not None:
        taken = {tree_id, *BTCPP_BUILTINS}
        for node, _ in _preorder(root):
            taken |= {type(node).__name__, "Walkaround" + type(node).__name__}
        split = _Subtrees(subtrees, taken)
    tree.append(_bt_element(root, model, keep_running_unselected, split, None))
    if split is not None:
        document.extend(split.trees)
    document.append(model.element())
    return etree.tostring(document, pretty_print=True, encoding="unicode")
