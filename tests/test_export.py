"""Views and exports of a compiled tree (executive.export): text, DOT, drawing, BT.CPP v4.

The BT.CPP export is checked twice: against the compiled tree node for node, and by a
real consumer, py_trees' own (experimental) BehaviorTree.CPP XML parser, which loads the
exported file back into a py_trees tree that is compared with the original.
"""

from __future__ import annotations

import re
from collections import Counter
from copy import deepcopy
from pathlib import Path
from typing import ClassVar

import matplotlib.image
import py_trees
import pydot
import pytest
from lxml import etree
from matplotlib.backends.backend_agg import FigureCanvasAgg
from py_trees.parsers.behaviour_tree_xml import parse_behaviour_tree_xml
from py_trees.ports import PortInformation, PortsMixin

from behaviours.base import Controller, Guard, Node
from behaviours.guards.conditions import EmergencyStop
from behaviours.keys import COMMAND, OBSTACLES, POSE, PROGRESS
from executive.compiler import (
    CompileOptions,
    GuardSelector,
    ResumableSequence,
    compile_mission,
)
from executive.core.loader import load_mission
from executive.export import (
    BTCPP_BUILTINS,
    _one_line,
    bt_port_name,
    layout,
    mission_subtree_id,
    overview,
    render,
    to_ascii,
    to_btcpp,
    to_dot,
    tree_figure,
)
from tests.conftest import SHIPPED_MISSIONS

LAB = SHIPPED_MISSIONS["lab"]
Status = py_trees.common.Status
Sequence = py_trees.composites.Sequence
Selector = py_trees.composites.Selector
Parallel = py_trees.composites.Parallel


# -- trees ------------------------------------------------------------------------------------
class Clear(Guard):
    reads = (OBSTACLES,)

    def __init__(self, limit: float, name: str = "clear?") -> None:
        super().__init__(name)
        self.limit = limit

    def update(self) -> Status:
        return Status.FAILURE


class Drive(Controller):
    reads = (POSE,)
    writes = (COMMAND,)

    def __init__(self, speed: float, mode: str = "fast", name: str = "drive") -> None:
        super().__init__(name)
        self.speed = speed
        self.mode = mode

    def update(self) -> Status:
        return Status.RUNNING


class Mark(Node):
    reads = (PROGRESS,)
    writes = (PROGRESS,)

    def __init__(self, label: str, ids: tuple[str, ...] = (), name: str = "mark") -> None:
        super().__init__(name)
        self.label = label
        self.ids = ids

    def update(self) -> Status:
        return Status.SUCCESS


class Tuned(Controller):
    """Chooses its BT.CPP parameters itself (the ``bt_ports()`` convention)."""

    writes = (COMMAND,)

    def __init__(self, gain: float, name: str = "tuned") -> None:
        super().__init__(name)
        self.gain = gain

    def bt_ports(self) -> dict[str, object]:
        return {"gain_x100": round(self.gain * 100), "flag": True}

    def update(self) -> Status:
        return Status.RUNNING


NASTY = 'say "hi" <&> \\ it\'s {x} for $5'


def small_tree(branches: int = 2, nasty: bool = False) -> py_trees.behaviour.Behaviour:
    """The compiled tree's shape in miniature: Parallel [sensing, Selector [guarded, mission]]."""
    legs = []
    for i in range(branches):
        guards = Selector(
            f"guards {i}",
            memory=False,
            children=[
                Sequence(
                    f"stop {i}",
                    memory=False,
                    children=[Clear(0.5 + i), Drive(0.0, name=f"halt {i}")],
                ),
                Drive(1.0 + i, mode="cruise", name=NASTY if nasty and i == 0 else f"drive {i}"),
            ],
        )
        legs.append(
            Sequence(f"leg {i}", memory=True, children=[Mark("leg", ids=("a", "b")), guards])
        )
    mission = Sequence("mission", memory=True, children=[*legs, Mark("done", name="done")])
    mode = Selector(
        "mode",
        memory=False,
        children=[Sequence("manual", memory=False, children=[Clear(9.0), Tuned(0.25)]), mission],
    )
    sensing = Sequence("sensing", memory=False, children=[Mark("sense", name="sense")])
    policy = py_trees.common.ParallelPolicy.SuccessOnSelected([mode], synchronise=False)
    return Parallel("root", policy, children=[sensing, mode])


@pytest.fixture(scope="module")
def a320(a320_path):
    return compile_mission(load_mission(a320_path))


@pytest.fixture(scope="module")
def a320_root(a320):
    return a320.root


def preorder(node, depth=0):
    yield node, depth
    for child in node.children:
        yield from preorder(child, depth + 1)


# -- text -------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["small", "a320"])
def test_ascii_lists_every_behaviour_once_a_line(which, request):
    root = small_tree() if which == "small" else request.getfixturevalue("a320_root")
    text = to_ascii(root)
    lines = text.splitlines()
    nodes = list(preorder(root))
    assert len(lines) == len(nodes)
    for line, (node, depth) in zip(lines, nodes, strict=True):
        assert f" {node.name}  (" in line
        assert type(node).__name__ in line
        assert line.index(node.name) >= 4 * depth  # indented by depth
    assert text.isascii()


def test_ascii_marks_composite_types_and_memory():
    lines = to_ascii(small_tree()).splitlines()
    by_name = {}
    for line in lines:
        for node, _ in preorder(small_tree()):
            if f" {node.name}  (" in line:
                by_name[node.name] = line
    assert by_name["root"].startswith("[=>] root  (Parallel, SuccessOnSelected(mode))")
    assert "[->] sensing  (Sequence, reactive)" in by_name["sensing"]
    assert "[?] mode  (Selector, reactive)" in by_name["mode"]
    assert "[->] mission  (Sequence, memory)" in by_name["mission"]
    assert "(c) clear?  (Clear)" in by_name["clear?"]
    assert "[>] halt 0  (Drive)" in by_name["halt 0"]
    assert "[*] done  (Mark)" in by_name["done"]
    fancy = to_ascii(small_tree(), unicode=True)
    assert fancy.startswith("⇉ root")
    assert "→ mission  (Sequence, memory)" in fancy and "? mode" in fancy
    assert "◯ clear?" in fancy and "▶ halt 0" in fancy and "└── " in fancy


# -- DOT --------------------------------------------------------------------------------------
def dot_tokens(text: str) -> tuple[list[str], str]:
    """The decoded double-quoted strings of DOT text, and the text outside them."""
    strings, outside, i = [], [], 0
    while i < len(text):
        if text[i] == '"':
            i += 1
            buf = []
            while text[i] != '"':
                if text[i] == "\\" and text[i + 1] in '"\\':
                    buf.append(text[i + 1])
                    i += 2
                else:
                    buf.append(text[i])
                    i += 1
            strings.append("".join(buf))
            outside.append('""')
            i += 1
        else:
            outside.append(text[i])
            i += 1
    return strings, "".join(outside)


NODE_LINE = re.compile(r"^\s*(n\d+) \[(.*)\];$")
EDGE_LINE = re.compile(r"^\s*(n\d+) -> (n\d+);$")


@pytest.mark.filterwarnings("ignore:.*deprecated:DeprecationWarning")  # pydot's pyparsing use
@pytest.mark.parametrize("which", ["small", "nasty", "a320"])
def test_dot_is_well_formed(which, request):
    if which == "a320":
        root = request.getfixturevalue("a320_root")
    else:
        root = small_tree(3, nasty=which == "nasty")
    text = to_dot(root)
    strings, outside = dot_tokens(text)  # every string closes: the escaping holds
    assert outside.count("{") == outside.count("}") == 1
    assert outside.count("[") == outside.count("]")
    assert outside.lstrip().startswith("digraph")
    lines = text.splitlines()
    node_lines = [m for m in map(NODE_LINE.match, lines) if m]
    edge_lines = [m for m in map(EDGE_LINE.match, lines) if m]
    nodes = list(preorder(root))
    assert len(node_lines) == len(nodes)
    assert len(edge_lines) == len(nodes) - 1
    ids = [m.group(1) for m in node_lines]
    assert len(set(ids)) == len(ids)
    assert all(m.group(1) in ids and m.group(2) in ids for m in edge_lines)
    # each node line: its label carries the (escaped) name, its shape the node's role
    for m, (node, _) in zip(node_lines, nodes, strict=True):
        labels, _ = dot_tokens(m.group(2).split(", fillcolor")[0])
        assert node.name in labels[0]
        attrs = m.group(2)
        if isinstance(node, Guard):
            assert "shape=ellipse" in attrs
        elif isinstance(node, Controller):
            assert 'shape=box, style="rounded,filled"' in attrs
        elif node.children:
            assert "shape=box" in attrs and "rounded" not in attrs
            assert ("peripheries=2" in attrs) == bool(getattr(node, "memory", False))
    if which == "nasty":
        assert any(NASTY in s for s in strings)
    if which == "a320":
        return  # pydot takes seconds on 455 nodes: the small trees exercise the same code
    # and a DOT parser agrees (pydot, which py_trees depends on; pure Python, no graphviz)
    (graph,) = pydot.graph_from_dot_data(text)
    named = [n for n in graph.get_nodes() if n.get_name() not in ("graph", "node", "edge")]
    assert len(named) == len(nodes) and len(graph.get_edges()) == len(nodes) - 1


# -- drawing ----------------------------------------------------------------------------------
def overlapping(boxes, slack=0.0):
    """Pairs of ``(x0, y0, x1, y1)`` boxes that overlap by more than ``slack`` (sweep on x)."""
    order = sorted(range(len(boxes)), key=lambda i: boxes[i][0])
    found, active = [], []
    for i in order:
        x0, y0, _, y1 = boxes[i]
        active = [j for j in active if boxes[j][2] > x0 + slack]
        found += [(j, i) for j in active if min(y1, boxes[j][3]) - max(y0, boxes[j][1]) > slack]
        active.append(i)
    return found


def rect(p):
    return (p.x, p.y - p.height / 2, p.x + p.width, p.y + p.height / 2)


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the PNG's IHDR chunk."""
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n" and header[12:16] == b"IHDR"
    return int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")


def test_layout_columns_rows_and_centred_parents():
    root = small_tree(3)
    placed = layout(root)
    assert [p.node for p in placed] == [n for n, _ in preorder(root)]
    where = {id(p.node): p for p in placed}
    for p in placed:
        assert p.depth == next(d for n, d in preorder(root) if n is p.node)
        kids = [where[id(c)] for c in p.node.children]
        if kids:  # children in order below each other, one column to the right
            assert all(k.x > p.x + p.width for k in kids)
            assert [k.y for k in kids] == sorted(k.y for k in kids)
            assert kids[0].y <= p.y <= kids[-1].y
            if all(not k.node.children for k in kids) and len({k.height for k in kids}) == 1:
                assert p.y == pytest.approx((kids[0].y + kids[-1].y) / 2)
    lefts = {}
    for p in placed:  # one column per depth
        assert lefts.setdefault(p.depth, p.x) == p.x
    assert overlapping([rect(p) for p in placed]) == []


@pytest.mark.parametrize("which", ["lab", "a320"])
def test_full_layout_never_overlaps_and_boxes_hold_their_text(which, a320_root):
    root = a320_root if which == "a320" else compile_mission(load_mission(LAB)).root
    placed = layout(root)
    assert len(placed) == sum(1 for _ in preorder(root))
    assert overlapping([rect(p) for p in placed]) == []
    if which == "a320":
        return
    # the estimated text sizes hold what matplotlib draws (every distinct label of the lab)
    fig, drawn = tree_figure(root)
    renderer = FigureCanvasAgg(fig).get_renderer()
    seen = set()
    for text, p in zip(fig.axes[0].texts, drawn, strict=True):
        if p.label in seen:
            continue
        seen.add(p.label)
        text.update_bbox_position_size(renderer)
        extent = text.get_bbox_patch().get_window_extent(renderer)  # pixels
        scale = 72.0 / fig.dpi
        assert extent.width * scale <= p.width + 0.5, p.label
        assert extent.height * scale <= p.height + 0.5, p.label


def test_render_png_and_svg_read_back_and_grow_with_the_tree(tmp_path):
    sizes = []
    for branches in (2, 8):
        root = small_tree(branches)
        png = render(root, tmp_path / f"t{branches}.png")
        svg = render(root, tmp_path / f"t{branches}.svg")
        image = matplotlib.image.imread(png)
        assert image.ndim == 3 and image.shape[0] > 100
        assert png_size(png) == (image.shape[1], image.shape[0])
        width, height = svg_size(svg)
        texts = "".join(etree.parse(str(svg)).getroot().itertext())
        assert "mission" in texts and "clear?" in texts  # text kept as text
        sizes.append((image.shape[1], image.shape[0], width, height))
    (w_small, h_small, _, sh_small), (w_big, h_big, _, sh_big) = sizes
    assert h_big > 2.5 * h_small - 200 and sh_big > 2 * sh_small  # 4x the branches: rows
    assert w_big == w_small  # same depth, same columns


def svg_size(path: Path) -> tuple[float, float]:
    svg = etree.parse(str(path)).getroot()
    assert svg.tag.endswith("svg")
    return tuple(float(svg.get(k).removesuffix("pt")) for k in ("width", "height"))


def test_render_draws_any_name(tmp_path):
    svg = render(small_tree(2, nasty=True), tmp_path / "nasty.svg")  # "$": no mathtext
    texts = "".join(etree.parse(str(svg)).getroot().itertext())
    assert "for $5" in texts
    assert matplotlib.image.imread(render(small_tree(2, nasty=True), tmp_path / "n.png")).size


def test_render_wants_png_or_svg(tmp_path):
    with pytest.raises(ValueError, match=r"\.png or \.svg"):
        render(small_tree(), tmp_path / "tree.jpg")


@pytest.mark.parametrize("which", ["lab", "a320"])
def test_overview_folds_navigations_and_checkpoints_and_fits_a_screen(which, a320, tmp_path):
    compiled = a320 if which == "a320" else compile_mission(load_mission(LAB))
    root = compiled.root
    view = overview(root)
    total = sum(1 for _ in preorder(root))
    folded = {n.name for n in view.folded}
    assert {f"checkpoint {cp.id}" for cp in compiled.mission.checkpoints} <= folded
    # every navigation outside a checkpoint is folded, but one: the example, in full
    example = view.example
    assert example is not None and example.name.startswith("navigate ")
    assert isinstance(example.children[-1], GuardSelector)
    legs = [
        n
        for n, _ in preorder(root)
        if n.name.startswith("navigate ") and not any(n in list(c.iterate()) for c in view.folded)
    ]
    assert legs and [n for n in legs if n.name not in folded] == [example]
    placed = layout(root, folded=view.folded, notes={id(example): "example"})
    assert len(placed) <= {"lab": 75, "a320": 100}[which]  # of 230 and 1562
    assert len(placed) + sum(p.hidden for p in placed) == total  # nothing lost
    assert sum(1 for p in placed if p.hidden) == len(view.folded)
    assert any("example" in p.label for p in placed if p.node is example)
    png = render(root, tmp_path / "overview.png", folded=view.folded)
    width, height = png_size(png)
    assert 800 < width <= 4000 and height <= 4000
    # what is drawn: no two boxes overlap (their extents as matplotlib draws them)
    fig, drawn = tree_figure(root, folded=view.folded)
    renderer = FigureCanvasAgg(fig).get_renderer()
    boxes = []
    for text in fig.axes[0].texts:
        text.update_bbox_position_size(renderer)
        e = text.get_bbox_patch().get_window_extent(renderer)
        boxes.append((e.x0, e.y0, e.x1, e.y1))
    assert len(boxes) == len(drawn) and overlapping(boxes) == []


@pytest.mark.filterwarnings("ignore:.*deprecated:DeprecationWarning")  # pydot's pyparsing use
def test_dot_overview_folds_the_same_branches():
    root = compile_mission(load_mission(LAB)).root
    view = overview(root)
    text = to_dot(root, folded=view.folded, rankdir="LR")
    assert "rankdir=LR" in text
    lines = text.splitlines()
    node_lines = [m for m in map(NODE_LINE.match, lines) if m]
    edge_lines = [m for m in map(EDGE_LINE.match, lines) if m]
    shown = len(layout(root, folded=view.folded))
    assert len(node_lines) == shown and len(edge_lines) == shown - 1
    assert sum("penwidth=2.4" in m.group(2) for m in node_lines) == len(view.folded)
    (graph,) = pydot.graph_from_dot_data(text)
    assert len(graph.get_edges()) == shown - 1
    with pytest.raises(ValueError, match="rankdir"):
        to_dot(root, rankdir="up")


@pytest.mark.slow
def test_render_full_a320_is_complete_and_a_column_of_rows(a320_root, tmp_path):
    svg = render(a320_root, tmp_path / "a320.svg")
    width, height = svg_size(svg)
    nodes = list(preorder(a320_root))
    assert width < 30 * 72 and height > 20 * width  # ~2000 px wide at 100 dpi
    texts = [t for t in etree.parse(str(svg)).getroot().iter("{*}text")]
    names = Counter("".join(t.itertext()).split("\n")[0][2:] for t in texts)
    # every behaviour drawn (its first line: marker, space, name; long names wrap)
    short = Counter(_one_line(n.name) for n, _ in nodes if len(n.name) <= 40)
    assert all(names[name] >= count for name, count in short.items())
    assert len(texts) >= len(nodes)


# -- BehaviorTree.CPP v4 ------------------------------------------------------------------------
def expected_tag(node) -> str:
    """The mapping of the module docstring, restated."""
    if isinstance(node, ResumableSequence):
        return "SequenceWithMemory"
    if isinstance(node, Sequence):
        return "Sequence" if node.memory else "ReactiveSequence"
    if isinstance(node, Selector):
        return "Fallback" if node.memory else "ReactiveFallback"
    if isinstance(node, Parallel):
        return "Parallel"
    return type(node).__name__


def elements(element):
    """Child elements, without comments."""
    return [c for c in element if isinstance(c.tag, str)]


def btcpp_trees(text: str) -> tuple[dict[str, etree._Element], etree._Element]:
    """``{tree ID: its root element}`` (the main tree first) and the ``<TreeNodesModel>``,
    checked as BT.CPP checks them: one child per ``<BehaviorTree>``, IDs unique, every
    ``<SubTree>`` childless and naming a defined tree."""
    document = etree.fromstring(text.encode())
    assert document.tag == "root"
    assert document.get("BTCPP_format") == "4"
    trees = document.findall("BehaviorTree")
    assert trees and trees[0].get("ID") == document.get("main_tree_to_execute")
    ids = [tree.get("ID") for tree in trees]
    assert len(set(ids)) == len(ids)
    for tree in trees:
        assert len(elements(tree)) == 1
        assert MODEL_NAME.match(tree.get("ID")), tree.get("ID")
    for reference in document.iter("SubTree"):
        assert reference.get("ID") in ids and not elements(reference)
    models = document.findall("TreeNodesModel")
    assert len(models) == 1
    return {tree.get("ID"): elements(tree)[0] for tree in trees}, models[0]


def expand(element, trees):
    """A copy of ``element`` with every ``<SubTree>`` replaced by the tree it names."""
    if element.tag == "SubTree":
        return expand(trees[element.get("ID")], trees)
    copy = etree.Element(element.tag, dict(element.attrib))
    copy.text = element.text
    for child in element:
        copy.append(expand(child, trees) if isinstance(child.tag, str) else deepcopy(child))
    return copy


def parse_btcpp(text: str):
    """The main tree with its subtrees expanded, and the ``<TreeNodesModel>``."""
    trees, model = btcpp_trees(text)
    return expand(next(iter(trees.values())), trees), model


def xml_preorder(element, depth=0, skip=()):
    if element.tag in skip:
        yield from xml_preorder(elements(element)[0], depth, skip)
        return
    yield element, depth
    for child in elements(element):
        yield from xml_preorder(child, depth + 1, skip)


PORT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
MODEL_NAME = re.compile(r"^[^\s<>&\"'/\\:*?|.]+$")  # BT.CPP's findForbiddenChar


@pytest.mark.parametrize("which", ["small", "nasty", "a320"])
def test_btcpp_matches_the_tree_node_for_node(which, request):
    if which == "a320":
        root = request.getfixturevalue("a320_root")
    else:
        root = small_tree(3, nasty=which == "nasty")
    top, _ = parse_btcpp(to_btcpp(root))
    ours = list(preorder(root))
    theirs = list(xml_preorder(top))
    assert len(theirs) == len(ours)
    for (node, depth), (element, xml_depth) in zip(ours, theirs, strict=True):
        assert element.get("name") == node.name
        assert element.tag == expected_tag(node)
        assert xml_depth == depth
        assert len(elements(element)) == len(node.children)
        for attribute in element.attrib:
            assert attribute == "name" or PORT_NAME.match(attribute), attribute


def test_btcpp_tree_nodes_model_declares_exactly_the_custom_types(a320_root):
    top, model = parse_btcpp(to_btcpp(a320_root))
    used = {e.tag for e, _ in xml_preorder(top)} - BTCPP_BUILTINS
    declared = {entry.get("ID"): entry for entry in model}
    assert used == set(declared)
    assert len(declared) == len(model)  # each type once
    classes = {type(n).__name__: type(n) for n, _ in preorder(a320_root) if not n.children}
    assert used == set(classes)
    for ident, entry in declared.items():
        assert entry.tag == ("Condition" if issubclass(classes[ident], Guard) else "Action")
        for port in entry:
            assert port.tag in ("input_port", "output_port", "inout_port")
            assert PORT_NAME.match(port.get("name"))
    # every attribute of every instance is a declared port (BT.CPP rejects the others),
    # and every blackboard key a node reads or writes is a port in the right direction
    for element, _ in xml_preorder(top):
        if element.tag not in declared:
            continue
        ports = {p.get("name"): p.tag for p in declared[element.tag]}
        assert set(element.keys()) - {"name"} <= set(ports)
    for node, _ in preorder(a320_root):
        if not isinstance(node, Node):
            continue
        ports = {p.get("name"): p.tag for p in declared[type(node).__name__]}
        for key in {*node.reads, *node.writes}:
            expected = (
                "inout_port"
                if key in node.reads and key in node.writes
                else "input_port"
                if key in node.reads
                else "output_port"
            )
            assert ports[bt_port_name(key.name)] == expected


def test_btcpp_blackboard_ports_and_parameters(a320):
    top, _ = parse_btcpp(to_btcpp(a320.root))
    estops = [e for e, _ in xml_preorder(top) if e.tag == "EmergencyStop"]
    assert estops
    safety = a320.mission.safety
    for e in estops:
        assert e.get("name") == "e-stop?"
        assert float(e.get("r_es")) == safety.r_es
        assert float(e.get("hold")) == safety.estop_hold
        assert e.get("state_obstacles") == "{state_obstacles}"
        assert e.get("sensors_frame") == "{sensors_frame}"
        assert e.get("operator") == "{operator}"
    mark = next(
        e
        for e, _ in xml_preorder(parse_btcpp(to_btcpp(small_tree()))[0])
        if e.get("name") == "mark"
    )
    assert mark.get("label") == "leg" and mark.get("ids") == "a;b"
    assert mark.get("mission_progress") == "{mission_progress}"
    drive = next(
        e for e, _ in xml_preorder(parse_btcpp(to_btcpp(small_tree()))[0]) if e.tag == "Drive"
    )
    assert drive.get("speed") == "0.0" and drive.get("mode") == "fast"


def test_btcpp_bt_ports_convention_and_escaping():
    text = to_btcpp(small_tree(2, nasty=True))
    top, model = parse_btcpp(text)
    tuned = next(e for e, _ in xml_preorder(top) if e.tag == "Tuned")
    assert dict(tuned.attrib) == {
        "name": "tuned",
        "gain_x100": "25",
        "flag": "true",
        "command": "{command}",
    }
    entry = model.find("Action[@ID='Tuned']")
    assert {p.get("name"): p.get("type") for p in entry} == {
        "gain_x100": "int",
        "flag": "bool",
        "command": "VelocityCommand",
    }
    assert [e.get("name") for e, _ in xml_preorder(top)].count(NASTY) == 1


def test_btcpp_parallel_policies():
    def counts(policy):
        root = Parallel("p", policy, children=[Mark("a", name="a"), Mark("b", name="b")])
        top, _ = parse_btcpp(to_btcpp(root))
        return top.get("success_count"), top.get("failure_count")

    assert counts(py_trees.common.ParallelPolicy.SuccessOnAll()) == ("-1", "1")
    assert counts(py_trees.common.ParallelPolicy.SuccessOnOne()) == ("1", "1")
    root = small_tree()
    plain = etree.fromstring(to_btcpp(root).encode())
    parallel = plain.find("BehaviorTree/Parallel")
    assert (parallel.get("success_count"), parallel.get("failure_count")) == ("1", "1")
    assert "SuccessOnSelected(mode)" in parallel[0].text  # a comment says what is lost
    top, _ = parse_btcpp(to_btcpp(root, keep_running_unselected=True))
    sensing, mode = elements(top)
    assert sensing.tag == "KeepRunningUntilFailure" and mode.tag == "ReactiveFallback"
    assert elements(sensing)[0].get("name") == "sensing"
    ours = [(n.name, d) for n, d in preorder(root)]
    assert [
        (e.get("name"), d) for e, d in xml_preorder(top, skip={"KeepRunningUntilFailure"})
    ] == ours


def test_btcpp_decorators_and_renamed_builtins():
    class Sleep(Controller):  # a BT.CPP built-in's name
        writes = (COMMAND,)

        def update(self) -> Status:
            return Status.RUNNING

    root = Sequence(
        "s",
        memory=True,
        children=[py_trees.decorators.Inverter("not", child=Clear(1.0)), Sleep("nap")],
    )
    top, model = parse_btcpp(to_btcpp(root))
    assert [e.tag for e, _ in xml_preorder(top)] == [
        "Sequence",
        "Inverter",
        "Clear",
        "WalkaroundSleep",
    ]
    assert {entry.get("ID") for entry in model} == {"Clear", "WalkaroundSleep"}


def c14n(element) -> bytes:
    """Canonical XML of ``element``, without the pretty-printer's whitespace."""
    element = deepcopy(element)
    for e in element.iter():
        if e.text is not None and not e.text.strip():
            e.text = None
        e.tail = None
    return etree.tostring(element, method="c14n")


def signature(element) -> tuple:
    return (element.tag, tuple(sorted(element.attrib.items())))


def test_btcpp_subtrees_one_per_navigation_and_checkpoint(a320):
    root = a320.root
    text = to_btcpp(root)
    trees, model = btcpp_trees(text)
    main_id, *sub_ids = trees
    assert main_id == "MainTree"
    checkpoints = {f"Checkpoint_{cp.id}" for cp in a320.mission.checkpoints}
    navigations = [n for n, _ in preorder(root) if n.name.startswith("navigate ")]
    assert checkpoints <= set(sub_ids)
    assert {i for i in sub_ids if i.startswith("Navigate_")} == {
        "Navigate_" + re.sub(r"[^A-Za-z0-9_-]+", "_", n.name[9:]).strip("_") for n in navigations
    }
    assert len(sub_ids) == len(checkpoints) + len(navigations)
    # each subtree is referenced once, under the name of the branch it holds
    document = etree.fromstring(text.encode())
    references = list(document.iter("SubTree"))
    assert sorted(r.get("ID") for r in references) == sorted(sub_ids)
    for reference in references:
        assert reference.get("_autoremap") == "true"
        assert trees[reference.get("ID")].get("name") == reference.get("name")
    # a checkpoint's navigations are subtrees of its subtree: the main tree shows phases
    main = document.find("BehaviorTree")
    in_main = {r.get("ID") for r in main.iter("SubTree")}
    assert in_main >= checkpoints and not in_main & {
        f"Navigate_{cp.id}" for cp in a320.mission.checkpoints
    }
    assert 60 <= sum(1 for _ in main.iter()) <= 120  # ~1560 behaviours flat
    assert len(c14n(main)) < 12_000 < len(text) / 20
    # expanded, it is the flat export again, node for node and attribute for attribute
    flat_trees, flat_model = btcpp_trees(to_btcpp(root, subtrees=None))
    assert list(flat_trees) == ["MainTree"]
    expanded = expand(trees[main_id], trees)
    assert c14n(expanded) == c14n(flat_trees["MainTree"])
    assert Counter(map(signature, expanded.iter())) == Counter(
        map(signature, flat_trees["MainTree"].iter())
    )
    assert c14n(model) == c14n(flat_model)  # every custom node type, declared the same


def test_btcpp_subtrees_with_an_operator_and_runnable_parallel(a320_path):
    compiled = compile_mission(load_mission(a320_path), CompileOptions(ask_operator=True))
    text = to_btcpp(compiled.root, keep_running_unselected=True)
    trees, _ = btcpp_trees(text)
    checkpoint = trees["Checkpoint_CP01"]
    assert checkpoint.get("name") == "checkpoint CP01 or skip"
    assert not any(e.get("ID", "").startswith("Checkpoint_") for e in checkpoint.iter("SubTree"))
    assert {e.get("ID") for e in checkpoint.iter("SubTree")} >= {"Navigate_CP01"}
    main = trees["MainTree"]
    assert main.tag == "Parallel" and elements(main)[0].tag == "KeepRunningUntilFailure"
    flat, _ = btcpp_trees(to_btcpp(compiled.root, keep_running_unselected=True, subtrees=None))
    assert c14n(expand(main, trees)) == c14n(flat["MainTree"])


def test_btcpp_subtree_ids_are_unique_and_avoid_node_types():
    class Checkpoint_A(Controller):  # noqa: N801 - a class named like a subtree
        writes = (COMMAND,)

        def update(self) -> Status:
            return Status.RUNNING

    def leg(name):
        return Sequence(name, memory=False, children=[Checkpoint_A("x"), Mark("m")])

    root = Sequence(
        "s",
        memory=True,
        children=[leg("checkpoint A"), leg("navigate a/b"), leg("navigate a.b"), Mark("plain")],
    )
    trees, model = btcpp_trees(to_btcpp(root))
    assert list(trees) == ["MainTree", "Checkpoint_A_2", "Navigate_a_b", "Navigate_a_b_2"]
    assert {entry.get("ID") for entry in model} == {"Checkpoint_A", "Mark"}
    assert [e.get("name") for e in trees.values()][1:] == [
        "checkpoint A",
        "navigate a/b",
        "navigate a.b",
    ]


# -- a real consumer: py_trees' BehaviorTree.CPP XML parser ---------------------------------------
# py_trees 2.6 ships py_trees.parsers.behaviour_tree_xml.parse_behaviour_tree_xml. It knows
# the composites <Sequence>, <Selector>/<Fallback> (attribute memory="true|false", default
# true), <Parallel> (attribute policy, default success_on_one; success_count/failure_count
# are ignored), py_trees' own decorators by class name (<Inverter>), <SubTree> and
# <BehaviorTree>; it ignores <TreeNodesModel> and comments. It has no <ReactiveSequence>,
# <SequenceWithMemory>, <ReactiveFallback>, <KeepRunningUntilFailure>, nor <Action ID>/
# <Condition ID>: any other tag must be in its node_registry, a {tag: PortsMixin class}
# mapping. So the test gives it what Groot2 or BT.CPP would be given: the node types of
# <TreeNodesModel> (made into PortsMixin stubs with exactly the declared ports) and BT.CPP's
# reactive controls, SequenceWithMemory and KeepRunningUntilFailure as the py_trees classes
# they mean. Names come back dotted with
# their parents' names (parent.child), which the comparison strips.


class ReactiveSequence(PortsMixin, Sequence, register=False):
    INPUT_PORTS: ClassVar[dict] = {}
    OUTPUT_PORTS: ClassVar[dict] = {}

    def __init__(self, name, children=None, behaviour_class_name=None):
        super().__init__(
            name=name, memory=False, children=children, behaviour_class_name=behaviour_class_name
        )


class SequenceWithMemory(PortsMixin, Sequence, register=False):
    """BT.CPP's SequenceWithMemory: a memory sequence (that also keeps its place through a
    halt, which the py_trees parser cannot say)."""

    INPUT_PORTS: ClassVar[dict] = {}
    OUTPUT_PORTS: ClassVar[dict] = {}

    def __init__(self, name, children=None, behaviour_class_name=None):
        super().__init__(
            name=name, memory=True, children=children, behaviour_class_name=behaviour_class_name
        )


class ReactiveFallback(PortsMixin, Selector, register=False):
    INPUT_PORTS: ClassVar[dict] = {}
    OUTPUT_PORTS: ClassVar[dict] = {}

    def __init__(self, name, children=None, behaviour_class_name=None):
        super().__init__(
            name=name, memory=False, children=children, behaviour_class_name=behaviour_class_name
        )


class KeepRunningUntilFailure(PortsMixin, py_trees.decorators.SuccessIsRunning, register=False):
    INPUT_PORTS: ClassVar[dict] = {}
    OUTPUT_PORTS: ClassVar[dict] = {}

    def __init__(self, name, child, behaviour_class_name=None):
        super().__init__(name=name, child=child, behaviour_class_name=behaviour_class_name)


def stub_class(entry) -> type:
    """A py_trees leaf with the ports a <TreeNodesModel> entry declares."""

    def port(p):
        return PortInformation(data_type=str, required=False)

    inputs = {p.get("name"): port(p) for p in entry if p.tag in ("input_port", "inout_port")}
    outputs = {p.get("name"): port(p) for p in entry if p.tag == "output_port"}
    return type(
        entry.get("ID"),
        (PortsMixin, py_trees.behaviour.Behaviour),
        {
            "INPUT_PORTS": inputs,
            "OUTPUT_PORTS": outputs,
            "category": entry.tag,
            "update": lambda self: Status.SUCCESS,
        },
        register=False,
    )


def load_with_py_trees(text: str, tmp_path: Path):
    path = tmp_path / "tree.xml"
    path.write_text(text, encoding="utf-8")
    _, model = parse_btcpp(text)
    registry = {
        "ReactiveSequence": ReactiveSequence,
        "SequenceWithMemory": SequenceWithMemory,
        "ReactiveFallback": ReactiveFallback,
        "KeepRunningUntilFailure": KeepRunningUntilFailure,
    }
    registry.update({entry.get("ID"): stub_class(entry) for entry in model})
    return parse_behaviour_tree_xml(str(path), node_registry=registry)


@pytest.fixture(autouse=True)
def _forget_parsed_constants():
    """The parser stores parameter values on the global blackboard: remove them after."""
    blackboard = py_trees.blackboard.Blackboard
    before = set(blackboard.storage), set(blackboard.metadata)
    yield
    for key in set(blackboard.storage) - before[0]:
        del blackboard.storage[key]
    for key in set(blackboard.metadata) - before[1]:
        del blackboard.metadata[key]


def same_kind(ours, theirs) -> bool:
    for base in (Sequence, Selector, Parallel):
        if isinstance(ours, base):
            return isinstance(theirs, base) and getattr(ours, "memory", None) == getattr(
                theirs, "memory", None
            )
    if isinstance(ours, py_trees.decorators.Inverter):
        return isinstance(theirs, py_trees.decorators.Inverter)
    category = "Condition" if isinstance(ours, Guard) else "Action"
    return type(theirs).__name__ == type(ours).__name__ and theirs.category == category


def assert_same_tree(ours, theirs, prefix="", subtrees=frozenset()):
    """Same names (theirs carry their parents' as a prefix, and a subtree's root its
    <SubTree name> before its own), kinds, memory, order, depth."""
    own = ours.name + "." + ours.name if ours.name in subtrees else ours.name
    assert theirs.name == prefix + own
    assert same_kind(ours, theirs), (ours, theirs)
    assert len(theirs.children) == len(ours.children), ours.name
    for mine, parsed in zip(ours.children, theirs.children, strict=True):
        assert_same_tree(mine, parsed, theirs.name + ".", subtrees)


def namespaced(node, subtrees, namespace="/"):
    """``(node, blackboard namespace)`` in pre-order, as py_trees' parser scopes them: one
    namespace per <SubTree> instance, named after it (it has no ``_autoremap``)."""
    if node.name in subtrees:
        namespace = namespace.rstrip("/") + "/" + node.name
    yield node, namespace
    for child in node.children:
        yield from namespaced(child, subtrees, namespace)


@pytest.mark.parametrize("split", ["subtrees", "flat"])
def test_py_trees_parser_loads_the_a320_export(a320_root, tmp_path, split):
    text = to_btcpp(a320_root, subtrees=mission_subtree_id if split == "subtrees" else None)
    parsed = load_with_py_trees(text, tmp_path)
    subtrees = {e.get("name") for e in etree.fromstring(text.encode()).iter("SubTree")}
    branches = [n for n, _ in preorder(a320_root) if mission_subtree_id(n)]
    assert len(subtrees) == (len(branches) if split == "subtrees" else 0) and len(branches) > 70
    assert_same_tree(a320_root, parsed, subtrees=subtrees)
    assert len(list(parsed.iterate())) == len(list(a320_root.iterate()))
    # ports: blackboard ones land on the shared entries (with BT.CPP's _autoremap; the
    # py_trees parser puts a subtree's in its namespace), parameters carry their values
    top, _ = parse_btcpp(text)
    exported = [e for e, _ in xml_preorder(top)]
    walked = zip(exported, preorder(parsed), namespaced(a320_root, subtrees), strict=True)
    for element, (node, _), (_, namespace) in walked:
        if not isinstance(node, PortsMixin):
            continue
        for attribute, value in element.attrib.items():
            if attribute == "name":
                continue
            if value.startswith("{"):
                key = namespace.rstrip("/") + "/" + value[1:-1]
                assert node._get_blackboard_key(attribute) == key
            else:
                assert node.get_input(attribute) == value


def test_py_trees_parser_loads_small_exports(tmp_path):
    root = small_tree(3, nasty=False)
    assert_same_tree(root, load_with_py_trees(to_btcpp(root), tmp_path))
    wrapped = load_with_py_trees(to_btcpp(root, keep_running_unselected=True), tmp_path)
    sensing = wrapped.children[0]
    assert isinstance(sensing, py_trees.decorators.SuccessIsRunning)
    assert_same_tree(root.children[0], sensing.decorated, "root.keep running: sensing.")
    assert_same_tree(root.children[1], wrapped.children[1], "root.")
    inverted = Sequence(
        "s", memory=True, children=[py_trees.decorators.Inverter("not", Clear(1.0))]
    )
    assert_same_tree(inverted, load_with_py_trees(to_btcpp(inverted), tmp_path))


def test_emergency_stop_parameters_survive_the_round_trip(tmp_path):
    root = Sequence("s", memory=False, children=[EmergencyStop(0.75, 2.5)])
    parsed = load_with_py_trees(to_btcpp(root), tmp_path)
    leaf = parsed.children[0]
    assert type(leaf).__name__ == "EmergencyStop" and leaf.category == "Condition"
    assert (leaf.get_input("r_es"), leaf.get_input("hold")) == ("0.75", "2.5")
