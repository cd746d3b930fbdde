"""Readable trees at A320 scale (issue #18): the interactive HTML view
(executive.treeview) and ``walkaround show``'s overview, full drawing, html and SubTrees.

The HTML is parsed with lxml's HTML parser and compared with the compiled tree node for
node; a headless Debian Chromium (as tests/test_hud_browser.py drives it) clicks it.
"""

from __future__ import annotations

import shutil

import pytest
from lxml import etree, html

from executive.cli import main
from executive.compiler import compile_mission
from executive.core.loader import load_mission
from executive.export import _description, _one_line, overview
from executive.treeview import OPEN_DEPTH, to_html
from tests.conftest import SHIPPED_MISSIONS
from tests.test_export import NASTY, NODE_LINE, btcpp_trees, expand, png_size, preorder, small_tree

A320 = SHIPPED_MISSIONS["a320"]
LAB = SHIPPED_MISSIONS["lab"]


@pytest.fixture(scope="module")
def roots():
    return {
        name: compile_mission(load_mission(SHIPPED_MISSIONS[name])).root for name in ("a320", "lab")
    }


def nodes_of(page):
    """The ``<li class="node ...">`` elements of the page, in document (pre-)order."""
    return [li for li in page.iter("li") if "node" in li.get("class", "").split()]


def own(li, cls):
    """The text of ``li``'s own element of class ``cls`` (not its descendants')."""
    head = li.find("details/summary") if li.find("details") is not None else li.find("span")
    found = [e for e in head.iter() if cls in (e.get("class") or "").split()]
    return found[0].text_content() if found else None


@pytest.mark.parametrize("which", ["lab", "a320", "nasty"])
def test_html_lists_every_behaviour_once_in_order(which, roots):
    root = small_tree(3, nasty=True) if which == "nasty" else roots[which]
    text = to_html(root, title=which)
    page = html.document_fromstring(text)
    ours = list(preorder(root))
    lis = nodes_of(page)
    assert len(lis) == len(ours)
    for li, (node, depth) in zip(lis, ours, strict=True):
        assert own(li, "name") == _one_line(node.name)
        assert own(li, "type") == _description(node)
        assert int(li.get("data-depth")) == depth
        details = li.find("details")
        assert (details is not None) == bool(node.children)
        # nesting: a node's children are the <li> of its <details><ul>
        if node.children:
            kids = [c for c in details.find("ul") if c.tag == "li"]
            assert len(kids) == len(node.children)
            below = sum(1 for _ in preorder(node)) - 1
            assert own(li, "below") == f"{below} below"
    if which == "nasty":
        assert [own(li, "name") for li in lis].count(NASTY) == 1
    assert f"{len(ours)} behaviours" in page.find(".//h1").text_content()


def test_html_opens_the_top_levels_only_and_marks_subtrees(roots):
    root = roots["a320"]
    page = html.document_fromstring(to_html(root))
    open_names = []
    for li, (node, depth) in zip(nodes_of(page), preorder(root), strict=True):
        details = li.find("details")
        if details is None:
            continue
        assert (details.get("open") is not None) == (depth < OPEN_DEPTH)
        if details.get("open") is not None:
            open_names.append(node.name)
        subtree = own(li, "subtree")
        if node.name.startswith("checkpoint "):
            assert subtree == "Checkpoint_" + node.name.split()[1]
        elif node.name.startswith("navigate "):
            assert subtree and subtree.startswith("Navigate_")
        else:
            assert subtree is None
    # shown at first: the modes and the mission's phases, folded
    assert open_names == [
        "walkaround",
        "sensing",
        "mode",
        "collaborative",
        "abort: back to P",
        "rejoin: back to P",
        "mission",
    ]
    # searchable text and blackboard keys on the node
    estop = next(li for li in nodes_of(page) if own(li, "type") == "EmergencyStop")
    assert "e-stop?" in estop.get("data-search") and "emergencystop" in estop.get("data-search")
    assert "reads /state/obstacles" in estop.find("span").get("title")


def test_html_is_self_contained(roots):
    text = to_html(roots["lab"])
    page = html.document_fromstring(text)
    assert page.find(".//script").get("src") is None and page.find(".//script").text.strip()
    assert page.find(".//style").text.strip()
    for element in page.iter():
        if not isinstance(element.tag, str):
            continue
        for attribute in ("src", "href", "action", "data", "srcset"):
            assert element.get(attribute) is None, (element.tag, attribute)
    assert "http://" not in text and "https://" not in text and "@import" not in text
    assert page.find(".//link") is None and page.find(".//iframe") is None


# -- walkaround show --------------------------------------------------------------------------
def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return code, captured.out + captured.err


@pytest.mark.parametrize("which", ["lab", "a320"])
def test_show_draws_the_overview_by_default_and_everything_with_full(which, tmp_path, capsys):
    mission = SHIPPED_MISSIONS[which]
    root = compile_mission(load_mission(mission)).root
    code, _ = run(capsys, "show", mission, "--format", "png", "--out", tmp_path / "o.png")
    assert code == 0
    width, height = png_size(tmp_path / "o.png")
    assert width <= 4000 and height <= 4000
    code, out = run(capsys, "show", mission, "--format", "dot")
    assert code == 0 and "rankdir=LR" in out
    shown = sum(1 for line in out.splitlines() if NODE_LINE.match(line))
    assert shown <= 100 and shown + sum(
        sum(1 for _ in preorder(n)) - 1 for n in overview(root).folded
    ) == sum(1 for _ in preorder(root))
    code, out = run(capsys, "show", mission, "--format", "dot", "--full")
    full = sum(1 for line in out.splitlines() if NODE_LINE.match(line))
    assert code == 0 and full == sum(1 for _ in preorder(root))
    if which == "lab":  # the full drawing (the A320's: tests/test_export.py, slow)
        code, _ = run(
            capsys, "show", mission, "--format", "svg", "--full", "--out", tmp_path / "f.svg"
        )
        assert code == 0
        svg = etree.parse(str(tmp_path / "f.svg")).getroot()
        drawn = "".join(svg.itertext())
        assert all(_one_line(n.name)[:20] in drawn for n, _ in preorder(root))


def test_show_html_and_subtree_btcpp(tmp_path, capsys):
    code, out = run(capsys, "show", LAB, "--format", "html", "--out", tmp_path / "t.html")
    assert code == 0 and "wrote" in out
    page = html.document_fromstring((tmp_path / "t.html").read_text(encoding="utf-8"))
    root = compile_mission(load_mission(LAB)).root
    assert len(nodes_of(page)) == sum(1 for _ in preorder(root))
    code, out = run(capsys, "show", LAB, "--format", "html", "--out", tmp_path / "t.png")
    assert code == 2 and ".html" in out
    for runnable in ((), ("--bt-runnable",)):
        code, out = run(capsys, "show", LAB, "--format", "btcpp", *runnable)
        assert code == 0
        trees, _ = btcpp_trees(out)
        assert len(trees) > 1 and "MainTree" in trees
        main_tree = trees["MainTree"]
        assert (main_tree[0].tag == "KeepRunningUntilFailure") == bool(runnable)
        assert sum(1 for _ in expand(main_tree, trees).iter()) > 3 * sum(
            1 for _ in main_tree.iter()
        )


# -- in a browser -----------------------------------------------------------------------------
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"  # .ci/run installs Debian's


@pytest.mark.slow
@pytest.mark.xdist_group("hil")
def test_html_folds_and_finds_in_chromium(tmp_path, roots):
    from playwright.sync_api import sync_playwright

    path = tmp_path / "a320.html"
    path.write_text(to_html(roots["a320"], title="a320"), encoding="utf-8")
    flags = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=flags)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 800})
            requests = []
            page.on("request", lambda r: requests.append(r.url))
            page.goto(path.as_uri())
            inspection = page.locator(
                "li.node:has(> details > summary > .name:text-is('inspection'))"
            )
            cp01 = page.locator(
                "li.node:has(> details > summary > .name:text-is('checkpoint CP01'))"
            )
            assert not cp01.is_visible()  # the phases show, folded
            inspection.locator("> details > summary").click()
            assert cp01.is_visible()  # a click unfolds the branch
            inspection.locator("> details > summary").click()
            assert not cp01.is_visible()
            # the search opens the path to what it finds
            page.fill("#search", "relocalise CP07 servo start")
            found = page.locator("li.match")
            assert found.count() == 1 and found.first.is_visible()
            assert page.inner_text("#count") == "1 found"
            page.fill("#search", "")
            assert page.locator("li.match").count() == 0
            page.click("#expand")
            assert page.locator("details:not([open])").count() == 0
            page.click("#collapse")
            assert page.locator("details[open]").count() == 0
            page.click("#top")
            assert page.locator("details[open]").count() == 7
            assert requests == [path.as_uri()]  # nothing fetched: self-contained
        finally:
            browser.close()
