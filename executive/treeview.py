"""An interactive view of a compiled mission tree: one self-contained HTML file.

``walkaround show --format html`` writes it. The tree is nested ``<details>``/``<summary>``
elements, so it folds and unfolds in any browser without a line of script, offline (no
CDN, no network: the CSS and the small script are inline). The script adds what
``<details>`` cannot do alone: *expand all*, *collapse all*, *top levels* (the default
view) and a search box that highlights the behaviours whose name, class or SubTree ID
contains the text and opens the branches leading to them (Enter: the next match).

Each behaviour is one ``<li class="node KIND">`` with the marker and colour of the other
views (:mod:`executive.export`: Sequence ``→``, Selector ``?``, Parallel ``⇉``, decorator
``◇``, condition ``◯``, controller ``▶``, other action ``■``), its name, its class with
memory or policy, the number of behaviours below it, the BT.CPP SubTree it becomes
(:func:`executive.export.mission_subtree_id`) and, as a tooltip, the blackboard keys it
reads and writes (:mod:`behaviours.keys`). By default the first :data:`OPEN_DEPTH` levels
are open: the modes and the mission's phases, not the 1500 behaviours of an A320.
"""

from __future__ import annotations

import html

import py_trees

from behaviours.base import Node
from executive.export import (
    _COMPOSITES,
    _FILL,
    _MARKERS_UNICODE,
    _description,
    _kind,
    _one_line,
    mission_subtree_id,
)

Behaviour = py_trees.behaviour.Behaviour

__all__ = ["OPEN_DEPTH", "to_html"]

OPEN_DEPTH = 3
"""Levels open by default: the root, sensing and the mode selector, the modes (the
mission among them), so the mission's phases show, folded."""

_CSS = """
:root { font: 14px/1.35 "DejaVu Sans", system-ui, sans-serif; color: #1d1d1d; }
body { margin: 0; }
header { position: sticky; top: 0; background: #fafafa; border-bottom: 1px solid #ccc;
  padding: 8px 14px; z-index: 1; }
h1 { font-size: 17px; margin: 0 0 6px 0; }
.tools { display: flex; flex-wrap: wrap; gap: 6px; align-items: center; }
.tools input { min-width: 18em; padding: 3px 6px; }
.legend { margin-top: 6px; font-size: 12px; display: flex; flex-wrap: wrap; gap: 4px; }
.legend span { padding: 1px 6px; border: 1px solid #999; border-radius: 3px; }
main { padding: 8px 14px 40px 14px; }
ul.tree, ul.tree ul { list-style: none; margin: 0; padding-left: 18px; }
ul.tree { padding-left: 0; }
ul.tree ul { border-left: 1px dotted #999; margin-left: 7px; }
li.node { margin: 2px 0; }
summary, .leaf { cursor: default; padding: 1px 4px; border-radius: 3px;
  display: inline-block; border: 1px solid #888; }
summary { cursor: pointer; list-style: none; }
summary::-webkit-details-marker { display: none; }
summary::before { content: "\\25B8"; display: inline-block; width: 1em; color: #1f5fbf; }
details[open] > summary::before { content: "\\25BE"; }
summary:focus-visible { outline: 2px solid #1f5fbf; }
.icon { display: inline-block; min-width: 1.2em; text-align: center; font-weight: bold; }
.type { color: #555; font-size: 12px; margin-left: 6px; }
.below { color: #1f5fbf; font-size: 12px; margin-left: 6px; }
.subtree { font-size: 11px; margin-left: 6px; padding: 0 4px; border: 1px solid #1f5fbf;
  border-radius: 8px; color: #1f5fbf; }
.memory > summary { border-width: 2px; border-color: #222; }
.action > .leaf { border-style: dashed; }
.condition > .leaf { border-radius: 12px; }
li.match > summary, li.match > .leaf { outline: 3px solid #e0007a; }
li.current > summary, li.current > .leaf { background: #ffd0ea !important; }
#count { font-size: 12px; color: #555; }
"""

_SCRIPT = """
(function () {
  "use strict";
  const all = () => Array.from(document.querySelectorAll("#tree details"));
  function topLevels() {
    for (const d of all()) { d.open = Number(d.parentElement.dataset.depth) < OPEN_DEPTH; }
  }
  document.getElementById("expand").addEventListener("click", () => {
    for (const d of all()) { d.open = true; }
  });
  document.getElementById("collapse").addEventListener("click", () => {
    for (const d of all()) { d.open = false; }
  });
  document.getElementById("top").addEventListener("click", topLevels);
  const box = document.getElementById("search");
  const count = document.getElementById("count");
  let matches = [];
  let current = -1;
  function reveal(li) {
    for (let d = li.parentElement.closest("details"); d; d = d.parentElement.closest("details")) {
      d.open = true;
    }
  }
  function focus(i) {
    for (const li of document.querySelectorAll("li.current")) { li.classList.remove("current"); }
    if (!matches.length) { return; }
    current = (i + matches.length) % matches.length;
    const li = matches[current];
    li.classList.add("current");
    reveal(li);
    li.scrollIntoView({ block: "center" });
    count.textContent = (current + 1) + " / " + matches.length;
  }
  function search() {
    const text = box.value.trim().toLowerCase();
    for (const li of document.querySelectorAll("li.match")) { li.classList.remove("match"); }
    matches = [];
    current = -1;
    if (text) {
      for (const li of document.querySelectorAll("#tree li.node")) {
        if ((li.dataset.search || "").includes(text)) {
          li.classList.add("match");
          reveal(li);
          matches.push(li);
        }
      }
    }
    count.textContent = text ? matches.length + " found" : "";
  }
  box.addEventListener("input", search);
  box.addEventListener("keydown", (event) => {
    if (event.key === "Enter") { focus(current + (event.shiftKey ? -1 : 1)); }
  });
})();
"""


def _attribute(text: str) -> str:
    return html.escape(text, quote=True)


def _keys(node: Behaviour) -> str:
    if not isinstance(node, Node):
        return ""
    parts = []
    if node.reads:
        parts.append("reads " + ", ".join(k.name for k in node.reads))
    if node.writes:
        parts.append("writes " + ", ".join(k.name for k in node.writes))
    return "; ".join(parts)


def _node(node: Behaviour, depth: int, open_depth: int, out: list[str]) -> int:
    """Append ``node``'s ``<li>`` to ``out``; return the number of behaviours it holds."""
    kind = _kind(node)
    name = _one_line(node.name)
    description = _description(node)
    subtree = mission_subtree_id(node) if depth else None
    classes = ["node", kind]
    if getattr(node, "memory", False) and kind in _COMPOSITES:
        classes.append("memory")
    search = " ".join(x for x in (name, description, subtree or "") if x).lower()
    keys = _keys(node)
    head = (
        f'<span class="icon">{html.escape(_MARKERS_UNICODE[kind])}</span>'
        f'<span class="name">{html.escape(name)}</span>'
        f'<span class="type">{html.escape(description)}</span>'
    )
    if subtree:
        head += f'<span class="subtree" title="BT.CPP SubTree">{html.escape(subtree)}</span>'
    style = f"background:{_FILL[kind]}"
    tooltip = f' title="{_attribute(keys)}"' if keys else ""
    start = len(out)
    out.append("")  # the opening tag, once the count is known
    total = 1
    if node.children:
        out.append("<ul>")
        for child in node.children:
            total += _node(child, depth + 1, open_depth, out)
        out.append("</ul></details></li>")
        below = f'<span class="below">{total - 1} below</span>'
        opened = " open" if depth < open_depth else ""
        out[start] = (
            f'<li class="{" ".join(classes)}" data-depth="{depth}" '
            f'data-search="{_attribute(search)}"><details{opened}>'
            f'<summary style="{style}"{tooltip}>{head}{below}</summary>'
        )
    else:
        out[start] = (
            f'<li class="{" ".join(classes)}" data-depth="{depth}" '
            f'data-search="{_attribute(search)}"><span class="leaf" style="{style}"{tooltip}>'
            f"{head}</span></li>"
        )
    return total


def to_html(root: Behaviour, *, title: str = "walkaround", open_depth: int = OPEN_DEPTH) -> str:
    """The tree as one self-contained HTML page (see the module docstring): the first
    ``open_depth`` levels open, the rest folded; nothing is fetched from the network."""
    body: list[str] = []
    total = _node(root, 0, open_depth, body)
    legend = "".join(
        f'<span style="background:{_FILL[kind]}">{html.escape(_MARKERS_UNICODE[kind])} {text}'
        "</span>"
        for kind, text in (
            ("sequence", "Sequence"),
            ("selector", "Selector"),
            ("parallel", "Parallel"),
            ("decorator", "decorator"),
            ("condition", "condition"),
            ("controller", "controller"),
            ("action", "action"),
        )
    )
    script = _SCRIPT.replace("OPEN_DEPTH", str(int(open_depth)))
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en">',
            "<head>",
            '<meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{html.escape(title)}: behaviour tree</title>",
            f"<style>{_CSS}</style>",
            "</head>",
            "<body>",
            "<header>",
            f"<h1>{html.escape(title)}: {total} behaviours</h1>",
            '<div class="tools">',
            '<button type="button" id="expand">expand all</button>',
            '<button type="button" id="collapse">collapse all</button>',
            '<button type="button" id="top">top levels</button>',
            '<input type="search" id="search" placeholder="find a behaviour, class or SubTree"'
            ' aria-label="find">',
            '<span id="count"></span>',
            "</div>",
            f'<div class="legend">{legend}<span>bold border: memory</span>'
            "<span>hover: blackboard keys</span></div>",
            "</header>",
            '<main id="tree">',
            '<ul class="tree">',
            *body,
            "</ul>",
            "</main>",
            f"<script>{script}</script>",
            "</body>",
            "</html>",
        ]
    )
