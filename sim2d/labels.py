"""Legends and text labels of the top views (issue #18): pictures that read well.

* **Legend.** Every mark drawn is tagged with its kind (:func:`tag`: the artist's gid,
  ``mark:<kind>``); :func:`kinds_legend` lists each kind drawn once, in drawing order,
  beside the axes (``fig.legend``, ``loc="outside right upper"`` of a constrained layout,
  then moved up against the plot by :func:`freeze_layout`), so it hides nothing and lists
  exactly what is in the picture.
* **Labels.** :func:`place_labels` puts each text label next to its anchor where it
  overlaps no other label: candidate offsets in 16 directions at growing distances, chosen
  greedily (the most crowded anchors first) to minimise the overlap, in display
  coordinates (pixels, measured with the figure's renderer), with the other labels'
  boxes, the anchors' markers and any other point marks, then the distance; a label set
  further than its marker carries a thin leader line. Labels stay inside the axes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.lines import Line2D
from matplotlib.text import Text

MARK = "mark:"
"""Prefix of the gid of an artist that is a mark of a kind listed in the legend."""
LEADER = "label-leader"
"""gid of the leader lines from labels to their anchors (part of the labels, not a mark)."""

LEGEND_MARKER_PT = 4.0
"""The smallest marker drawn in the legend (points)."""
LEGEND_PAD_PT = 6.0
"""Space between the plot and the legend beside it (points)."""

A = TypeVar("A", bound=Artist)


def tag(artist: A, kind: str) -> A:
    """Mark ``artist`` as one of the kind ``kind`` (its legend entry); returns it."""
    artist.set_gid(MARK + kind)
    return artist


def tag_all(artists: Iterable[Artist], kind: str) -> None:
    """Mark every one of ``artists`` (what ``ax.plot`` returns) as of the kind ``kind``."""
    for artist in artists:
        tag(artist, kind)


def _marks(ax: Axes) -> list[Artist]:
    """The data artists of ``ax`` (lines, patches, collections) in drawing order."""
    data = {id(a) for a in (*ax.lines, *ax.patches, *ax.collections)}
    return [a for a in ax.get_children() if id(a) in data]


def mark_kinds(ax: Axes) -> list[str]:
    """The kinds of the visible tagged marks of ``ax``, each once, in drawing order."""
    kinds: dict[str, None] = {}
    for a in _marks(ax):
        gid = a.get_gid() or ""
        if a.get_visible() and gid.startswith(MARK):
            kinds.setdefault(gid.removeprefix(MARK), None)
    return list(kinds)


def untagged_marks(ax: Axes) -> list[Artist]:
    """Data artists that are neither a tagged mark nor a label's leader line."""
    return [a for a in _marks(ax) if not (a.get_gid() or "").startswith((MARK, LEADER))]


def kinds_legend(fig: Figure, ax: Axes, *, fontsize: float = 7.0) -> Legend | None:
    """A legend beside the axes naming every kind of mark drawn on ``ax``, and only those
    (None when nothing is tagged). ``fig`` must use the constrained layout."""
    handles: dict[str, Artist] = {}
    for a in _marks(ax):
        gid = a.get_gid() or ""
        if a.get_visible() and gid.startswith(MARK):
            handles.setdefault(gid.removeprefix(MARK), a)
    if not handles:
        return None
    legend = fig.legend(
        list(handles.values()),
        list(handles),
        loc="outside right upper",
        fontsize=fontsize,
        frameon=True,
        handlelength=2.2,
    )
    for handle in legend.legend_handles:  # a scan's 1-pixel dots, legible in the legend
        if isinstance(handle, Line2D) and handle.get_marker() not in ("None", None, ""):
            handle.set_markersize(max(handle.get_markersize(), LEGEND_MARKER_PT))
    return legend


@dataclass(frozen=True)
class Label:
    """A text to write next to the point (x, y) of the data (metres)."""

    text: str
    x: float
    y: float
    fontsize: float = 6.0
    color: str = "black"


DIRECTIONS = 16
DISTANCES_PT = (2.0, 5.0, 10.0, 18.0, 28.0, 42.0, 60.0)
"""How far (points) from its anchor's marker a label may be set, nearest first."""
LEADER_FROM_PT = 9.0
"""Labels set further than this from their anchor get a leader line."""
MARKER_PT = 3.0
"""Half the side of the box kept free round each anchor and point mark (points)."""
GAP_PT = 1.0
"""Space kept between two labels (points): boxes that only touch read as one line."""


def _overlap(boxes: np.ndarray, others: np.ndarray) -> np.ndarray:
    """For each of ``boxes`` (n x 4: x0, y0, x1, y1), the total area of its intersections
    with ``others`` (m x 4)."""
    if not len(others):
        return np.zeros(len(boxes))
    b, o = boxes[:, None, :], others[None, :, :]
    w = np.minimum(b[..., 2], o[..., 2]) - np.maximum(b[..., 0], o[..., 0])
    h = np.minimum(b[..., 3], o[..., 3]) - np.maximum(b[..., 1], o[..., 1])
    return np.sum(np.clip(w, 0.0, None) * np.clip(h, 0.0, None), axis=1)


def _outside(boxes: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """How far (pixels) each of ``boxes`` sticks out of ``frame``."""
    return (
        np.clip(frame[0] - boxes[:, 0], 0.0, None)
        + np.clip(frame[1] - boxes[:, 1], 0.0, None)
        + np.clip(boxes[:, 2] - frame[2], 0.0, None)
        + np.clip(boxes[:, 3] - frame[3], 0.0, None)
    )


_ANGLES = 2 * np.pi * np.arange(DIRECTIONS) / DIRECTIONS
_COS, _SIN = np.cos(_ANGLES), np.sin(_ANGLES)
_SIDE_X = np.where(np.abs(_COS) > 1e-9, np.sign(_COS), 0.0)
_SIDE_Y = np.where(np.abs(_SIN) > 1e-9, np.sign(_SIN), 0.0)


def _candidates(anchor: np.ndarray, size: np.ndarray, px_per_pt: float) -> np.ndarray:
    """Boxes (n x 4) for a label of ``size`` (w, h) round ``anchor``, nearest first: on
    a circle of each distance, in each direction, the box's side facing the anchor
    touches the circle (its centre is pushed out by half its extent along the
    direction)."""
    w, h = size
    r = (np.array(DISTANCES_PT)[:, None] + MARKER_PT) * px_per_pt  # distances x directions
    cx = (anchor[0] + r * _COS + _SIDE_X * w / 2).ravel()
    cy = (anchor[1] + r * _SIN + _SIDE_Y * h / 2).ravel()
    return np.column_stack((cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2))


def fit_height(
    fig: Figure, ax: Axes, *, beside: float = 3.2, around: float = 1.3, least: float = 5.0
) -> None:
    """Set the figure's height to what the equal-aspect plot needs at the figure's width
    (``beside`` inches kept for the legend, ``around`` for the title and axis labels;
    between ``least`` and the width): a wide apron leaves no empty bands above and
    below the plot. Call it when the limits are set, before :func:`place_labels`."""
    width = fig.get_figwidth()
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    if x1 == x0:
        return
    height = (width - beside) * abs(y1 - y0) / abs(x1 - x0) + around
    fig.set_figheight(min(max(height, least), width))


def freeze_layout(fig: Figure, ax: Axes) -> None:
    """Lay ``fig`` out once (no drawing) and keep that layout when saving; the legend
    beside the plot then moves up against the axes (an equal-aspect plot narrower than
    its slot leaves it stranded at the figure's edge otherwise)."""
    renderer = fig.canvas.get_renderer()
    engine = fig.get_layout_engine()
    for _ in range(2 if engine is not None else 1):  # the second sees the final ticks
        if engine is not None:
            engine.execute(fig)
        for axes in fig.axes:
            axes.apply_aspect()
    fig.set_layout_engine("none")
    pad = LEGEND_PAD_PT * fig.dpi / 72.0
    for legend in fig.legends:
        width = legend.get_window_extent(renderer).width
        left = min(ax.bbox.x1 + pad, fig.bbox.x1 - width - pad / 2)
        legend.set_loc("upper left")
        to_figure = fig.transFigure.inverted()
        legend.set_bbox_to_anchor(
            tuple(to_figure.transform((left, ax.bbox.y1))), transform=fig.transFigure
        )
        box = legend.get_window_extent(renderer)  # off the anchor by its border pad
        anchor = (2 * left - box.x0, 2 * ax.bbox.y1 - box.y1)
        legend.set_bbox_to_anchor(tuple(to_figure.transform(anchor)), transform=fig.transFigure)


def place_labels(
    fig: Figure,
    ax: Axes,
    labels: Sequence[Label],
    *,
    avoid: Sequence[tuple[float, float]] = (),
) -> list[Text]:
    """Write ``labels`` on ``ax`` where they overlap each other (and the anchors and the
    ``avoid`` points, data coordinates) the least; returns the texts, in ``labels`` order.

    Call it last, when everything else is drawn and the limits are set: it lays the
    figure out once and freezes that layout (:func:`freeze_layout`), so the positions
    measured are those the figure is saved with.
    """
    freeze_layout(fig, ax)
    if not labels:
        return []
    renderer = fig.canvas.get_renderer()
    px_per_pt = fig.dpi / 72.0
    frame = np.array(ax.bbox.extents)
    to_px = ax.transData.transform
    anchors = to_px(np.array([(lab.x, lab.y) for lab in labels], dtype=float))
    points = to_px(np.array(avoid, dtype=float).reshape(-1, 2)) if len(avoid) else anchors[:0]
    m = MARKER_PT * px_per_pt
    marks = np.vstack((anchors, points))
    mark_boxes = np.column_stack((marks - m, marks + m))
    texts = [
        ax.text(
            0,
            0,
            lab.text,
            fontsize=lab.fontsize,
            color=lab.color,
            ha="left",
            va="bottom",
            bbox={"boxstyle": "square,pad=0", "fc": "white", "alpha": 0.6, "lw": 0},
        )
        for lab in labels
    ]
    sizes = []
    for t in texts:
        t.set_in_layout(False)
        b = t.get_window_extent(renderer)
        sizes.append(np.array([b.width, b.height]))
    # the most crowded anchors first: they have the fewest good places
    reach = 40.0 * px_per_pt
    crowd = [int(np.sum(np.hypot(*(anchors - a).T) < reach)) for a in anchors]
    order = sorted(range(len(labels)), key=lambda i: (-crowd[i], i))
    grow = GAP_PT * px_per_pt * np.array([-1.0, -1.0, 1.0, 1.0])
    placed: list[np.ndarray] = []
    chosen: dict[int, np.ndarray] = {}
    for i in order:
        others = np.delete(mark_boxes, i, axis=0)
        taken = np.array(placed).reshape(-1, 4)
        boxes = _candidates(anchors[i], sizes[i], px_per_pt)
        centres = (boxes[:, :2] + boxes[:, 2:]) / 2
        cost = (
            1e6 * _outside(boxes, frame)
            + 100.0 * _overlap(boxes + grow, taken)
            + 10.0 * _overlap(boxes, others)
            + np.hypot(*(centres - anchors[i]).T)
        )
        best = boxes[int(np.argmin(cost))]
        placed.append(best)
        chosen[i] = best
    inverse = ax.transData.inverted()
    leaders = []
    for i, t in enumerate(texts):
        box = chosen[i]
        t.set_position(inverse.transform((box[0], box[1])))
        # nearest point of the box to the anchor: where a leader line ends
        near = np.clip(anchors[i], box[:2], box[2:])
        if float(np.hypot(*(near - anchors[i]))) > (LEADER_FROM_PT + MARKER_PT) * px_per_pt:
            leaders.append(inverse.transform(np.array([anchors[i], near])))
    if leaders:
        ax.add_collection(
            LineCollection(leaders, colors="0.4", linewidths=0.4, zorder=8, gid=LEADER),
            autolim=False,
        )
    for t in texts:
        t.set_zorder(9)
    return texts
