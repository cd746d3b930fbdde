"""Views and exports of a compiled tree (executive.export): text, DOT, drawing, BT.CPP v4.

The BT.CPP export is checked twice: against the compiled tree node for node, and by a
real consumer, py_trees' own (experimental) BehaviorTree.CPP XML parser, which loads the
exported file back into a py_trees tree that is compared with the original.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import ClassVar

import matplotlib.image
import py_trees
import pydot
import pytest
from lxml import etree
from py_trees.parsers.behaviour_tree_xml import parse_behaviour_tree_xml
from py_trees.ports import PortInformation, PortsMixin

from behaviours.base import Controller, Guard, Node
from behaviours.guards.conditions import EmergencyStop
from behaviours.keys import COMMAND, OBSTACLES, POSE, PROGRESS
from executive.compiler import ResumableSequence, compile_mission
from executive.core.loader import load_mission
from executive.export import (
    BTCPP_BUILTINS,
    bt_port_name,
    layout,
    render,
    to_ascii,
    to_btcpp,
    to_dot,
)

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
def test_layout_spaces_leaves_and_centres_parents():
    root = small_tree(3)
    placed = layout(root)
    assert [n for n, _, _ in placed] == [n for n, _ in preorder(root)]
    where = {id(n): (x, d) for n, x, d in placed}
    leaves = [x for n, x, _ in placed if not n.children]
    assert leaves == [float(i) for i in range(len(leaves))]
    for node, x, depth in placed:
        if node.children:
            xs = [where[id(c)][0] for c in node.children]
            assert x == pytest.approx((xs[0] + xs[-1]) / 2)
            assert all(where[id(c)][1] == depth + 1 for c in node.children)
    for depth in {d for _, _, d in placed}:  # no two boxes of a level closer than a leaf step
        xs = sorted(x for _, x, d in placed if d == depth)
        assert all(b - a >= 1.0 for a, b in itertools.pairwise(xs))


def svg_size(path: Path) -> tuple[float, float]:
    svg = etree.parse(str(path)).getroot()
    assert svg.tag.endswith("svg")
    return tuple(float(svg.get(k).removesuffix("pt")) for k in ("width", "height"))


def test_render_png_and_svg_read_back_and_grow_with_the_tree(tmp_path):
    sizes = []
    for branches in (2, 8):
        root = small_tree(branches)
        png = render(root, tmp_path / f"t{branches}.png")
        svg = render(root, tmp_path / f"t{branches}.svg")
        image = matplotlib.image.imread(png)
        assert image.ndim == 3 and image.shape[0] > 100
        width, height = svg_size(svg)
        texts = "".join(etree.parse(str(svg)).getroot().itertext())
        assert "mission" in texts and "clear?" in texts  # text kept as text
        sizes.append((image.shape[1], image.shape[0], width, height))
    (w_small, h_small, sw_small, _), (w_big, h_big, sw_big, _) = sizes
    assert w_big > 2 * w_small and sw_big > 2 * sw_small  # 4x the branches
    assert h_big == h_small  # same depth, same height


def test_render_draws_any_name(tmp_path):
    svg = render(small_tree(2, nasty=True), tmp_path / "nasty.svg")  # "$": no mathtext
    texts = "".join(etree.parse(str(svg)).getroot().itertext())
    assert "for $5" in texts
    assert matplotlib.image.imread(render(small_tree(2, nasty=True), tmp_path / "n.png")).size


def test_render_wants_png_or_svg(tmp_path):
    with pytest.raises(ValueError, match=r"\.png or \.svg"):
        render(small_tree(), tmp_path / "tree.jpg")


@pytest.mark.slow
def test_render_a320_is_one_wide_legible_figure(a320_root, tmp_path):
    leaves = sum(1 for n, _ in preorder(a320_root) if not n.children)
    png = render(a320_root, tmp_path / "a320.png")
    image = matplotlib.image.imread(png)
    height, width = image.shape[:2]
    # 100 dpi and 1.25 in a leaf: the text keeps its size however big the tree, up to
    # Agg's 65536-pixel side (the A320 with its servo branches: ~990 leaves), where the
    # PNG's resolution is lowered and the figure stays as wide as a PNG can be
    assert width >= min(leaves * 100, 65000) and width <= 65536
    assert width > 20 * height
    svg_w, _ = svg_size(render(a320_root, tmp_path / "a320.svg"))
    assert svg_w >= leaves * 1.25 * 72


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


def parse_btcpp(text: str):
    document = etree.fromstring(text.encode())
    assert document.tag == "root"
    assert document.get("BTCPP_format") == "4"
    trees = document.findall("BehaviorTree")
    assert len(trees) == 1 and trees[0].get("ID") == document.get("main_tree_to_execute")
    assert len(elements(trees[0])) == 1
    models = document.findall("TreeNodesModel")
    assert len(models) == 1
    return elements(trees[0])[0], models[0]


def xml_preorder(element, depth=0, skip=()):
    if element.tag in skip:
        yield from xml_preorder(elements(element)[0], depth, skip)
        return
    yield element, depth
    for child in elements(element):
        yield from xml_preorder(child, depth + 1, skip)


PORT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


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


def assert_same_tree(ours, theirs, prefix=""):
    """Same names (theirs carry their parents' as a prefix), kinds, memory, order, depth."""
    assert theirs.name == prefix + ours.name
    assert same_kind(ours, theirs), (ours, theirs)
    assert len(theirs.children) == len(ours.children), ours.name
    for mine, parsed in zip(ours.children, theirs.children, strict=True):
        assert_same_tree(mine, parsed, theirs.name + ".")


def test_py_trees_parser_loads_the_a320_export(a320_root, tmp_path):
    text = to_btcpp(a320_root)
    parsed = load_with_py_trees(text, tmp_path)
    assert_same_tree(a320_root, parsed)
    assert len(list(parsed.iterate())) == len(list(a320_root.iterate()))
    # ports: blackboard ones land on the shared entries, parameters carry their values
    top, _ = parse_btcpp(text)
    exported = [e for e, _ in xml_preorder(top)]
    for element, (node, _) in zip(exported, preorder(parsed), strict=True):
        if not isinstance(node, PortsMixin):
            continue
        for attribute, value in element.attrib.items():
            if attribute == "name":
                continue
            if value.startswith("{"):
                assert node._get_blackboard_key(attribute) == "/" + value[1:-1]
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
