"""The campaign report (issue 16): ``report.html`` and its PNGs in a results folder.

* ``report.html`` — the campaign's id, seed and digest; the success rate with its 95 %
  Wilson interval overall and per (mission, scenario); failures grouped by cause (the
  dry-run's one-line causes, numbers folded by :func:`~executive.campaign.results.cause_group`)
  with their episodes and the commands that rerun each; the worst checkpoints; collisions
  and near misses with their episodes; crashed episodes with their folded traceback. One
  self-contained page (inline style, no script, nothing fetched) beside its PNGs; every
  text that comes from a run (causes, tracebacks, ids) is escaped.
* ``success_by_speed.png`` — success with Wilson 95 % error bars per bin of the episode's
  fastest mover (the episodes without movers in a bin of their own).
* ``success_by_movers.png`` — the same per number of movers.
* ``checkpoint_errors.png`` — the distribution (ECDF) over episodes of the worst
  checkpoint's position error, with the 2 cm line, and of the worst heading error, with
  the 0.5° line.

A plot without data is not drawn (an old file of that name is removed) and the page says
why. :func:`report_from_folder` reads a results folder (``results.jsonl`` and
``campaign.json``) and writes the report into it, for ``walkaround campaign report OUT``.
"""

from __future__ import annotations

import html
import io
import math
import re
import shlex
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from executive.campaign.results import (
    CAMPAIGN_FILE,
    RESULTS_FILE,
    Row,
    read_identity,
    read_rows,
    summarise,
    wilson,
)
from executive.core.files import write_atomic
from executive.core.problems import InvalidInputError, Problem, SourceLocation
from sim2d.world import STILL_SPEED

REPORT_FILE = "report.html"
SPEED_PLOT = "success_by_speed.png"
COUNT_PLOT = "success_by_movers.png"
ERROR_PLOT = "checkpoint_errors.png"
POSITION_LINE_M = 0.02
"""The position error line of the checkpoint plot: the 2 cm the airliner checkpoints are
finished within by visual servoing (issue 13)."""
HEADING_LINE_DEG = 0.5
"""The heading error line of the checkpoint plot (issue 13's 0.5°)."""
SPEED_WIDTHS = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0)
"""Bin widths (m/s) of the speed plot: the narrowest that gives at most
:data:`MAX_SPEED_BINS` bins over the drawn speeds."""
MAX_SPEED_BINS = 8
NO_MOVERS = "none"
"""The label of the bin of the episodes without movers."""

STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 75em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em 0; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left;
         vertical-align: top; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
pre { background: #f6f6f6; padding: 0.5em; overflow-x: auto; font-size: 90%; }
.note { color: #555; font-style: italic; }
.bad { color: #a00; }
img { max-width: 100%; border: 1px solid #ddd; }
code { background: #f3f3f3; }
"""


# -- success per bin ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RateBin:
    """Episodes of one bin of a plot and their success rate."""

    label: str
    episodes: tuple[int, ...]
    successes: int

    @property
    def n(self) -> int:
        return len(self.episodes)

    @property
    def rate(self) -> float:
        """The success rate (a fraction); 0 for an empty bin."""
        return self.successes / self.n if self.n else 0.0

    @property
    def ci(self) -> tuple[float, float] | None:
        """The 95 % Wilson interval (fractions), None for an empty bin."""
        return wilson(self.successes, self.n)

    def error_bar(self) -> tuple[float, float]:
        """The (below, above) extents of the Wilson interval around the rate."""
        ci = self.ci
        if ci is None:
            return 0.0, 0.0
        return max(self.rate - ci[0], 0.0), max(ci[1] - self.rate, 0.0)


def _number(value: object) -> float | None:
    """A finite int or float (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _episode(row: Mapping[str, object]) -> int:
    value = _number(row.get("episode"))
    return int(value) if value is not None else -1


def _movers(row: Mapping[str, object]) -> tuple[int, float | None] | None:
    """(mover count, fastest mover's speed) drawn for the episode, or None when the row
    records no drawn parameters (an episode that crashed before its draw)."""
    drawn = row.get("drawn")
    if not isinstance(drawn, dict):
        return None
    count = _number(drawn.get("movers"))
    if count is None:
        return None
    return int(count), _number(drawn.get("mover_max_speed"))


def _bin(label: str, rows: list[Mapping[str, object]]) -> RateBin:
    return RateBin(
        label,
        tuple(_episode(r) for r in rows),
        sum(bool(r.get("succeeded")) for r in rows),
    )


def _mover_speeds(rows: Iterable[Mapping[str, object]]) -> list[tuple[float, Mapping[str, object]]]:
    """(fastest mover's speed, row) of the episodes that had movers."""
    out = []
    for row in rows:
        drawn = _movers(row)
        if drawn is not None and drawn[0] > 0 and drawn[1] is not None:
            out.append((drawn[1], row))
    return out


def speed_width(speeds: Iterable[float]) -> float:
    """The bin width of the speed plot for these speeds (see :data:`SPEED_WIDTHS`)."""
    values = list(speeds)
    if not values:
        return SPEED_WIDTHS[0]
    low, high = min(values), max(values)
    for width in SPEED_WIDTHS:
        if math.floor(high / width + 1e-9) - math.floor(low / width + 1e-9) < MAX_SPEED_BINS:
            return width
    return SPEED_WIDTHS[-1]


def speed_bins(rows: Iterable[Mapping[str, object]]) -> list[RateBin]:
    """Success per bin of the fastest mover's speed: the episodes without movers first
    (label :data:`NO_MOVERS`), then the non-empty bins ``[a, b)`` m/s in order. Rows
    without drawn parameters are left out."""
    rows = list(rows)
    none = [r for r in rows if (drawn := _movers(r)) is not None and drawn[0] == 0]
    moving = _mover_speeds(rows)
    bins = [_bin(NO_MOVERS, none)] if none else []
    width = speed_width(s for s, _ in moving)
    by_index: dict[int, list[Mapping[str, object]]] = {}
    for speed, row in moving:
        by_index.setdefault(math.floor(speed / width + 1e-9), []).append(row)
    for index in sorted(by_index):
        label = f"{index * width:.4g}\u2013{(index + 1) * width:.4g}"
        bins.append(_bin(label, by_index[index]))
    return bins


def count_bins(rows: Iterable[Mapping[str, object]]) -> list[RateBin]:
    """Success per number of movers (rows without drawn parameters left out)."""
    by_count: dict[int, list[Mapping[str, object]]] = {}
    for row in rows:
        drawn = _movers(row)
        if drawn is not None:
            by_count.setdefault(drawn[0], []).append(row)
    return [_bin(str(count), by_count[count]) for count in sorted(by_count)]


# -- plots -------------------------------------------------------------------------------------
def _png(fig: plt.Figure) -> bytes:
    image = io.BytesIO()
    with warnings.catch_warnings():  # layout hints of a sparse plot are not the user's
        warnings.filterwarnings("ignore", category=UserWarning, module="matplotlib")
        fig.tight_layout()
        fig.savefig(image, format="png")
    plt.close(fig)
    return image.getvalue()


def rate_plot(bins: list[RateBin], xlabel: str, title: str) -> bytes:
    """A PNG of the success rate per bin with its Wilson 95 % error bars and n."""
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    x = np.arange(len(bins))
    rates = np.array([b.rate * 100.0 for b in bins])
    bars = np.array([b.error_bar() for b in bins]).T * 100.0
    ax.errorbar(x, rates, yerr=bars, fmt="o", capsize=5, color="tab:blue", ecolor="tab:blue")
    for xi, b, top in zip(x, bins, rates + bars[1], strict=True):
        ax.annotate(
            f"n={b.n}",
            (xi, top),
            xytext=(0, 4),
            textcoords="offset points",
            ha="center",
            fontsize=8,
        )
    lows = [ci[0] for b in bins if (ci := b.ci) is not None]
    bottom = max(0.0, math.floor(min(lows, default=0.0) * 10.0) * 10.0 - 10.0)
    ax.set_ylim(bottom, 106.0)
    ax.set_xlim(-0.6, len(bins) - 0.4)
    ax.set_xticks(x, [b.label for b in bins])
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success (%), Wilson 95 % interval")
    ax.set_title(title)
    ax.grid(True, axis="y", lw=0.3, alpha=0.6)
    return _png(fig)


def _worst(rows: Iterable[Mapping[str, object]], key: str, scale: float) -> list[float]:
    values = (_number(r.get(key)) for r in rows)
    return sorted(v * scale for v in values if v is not None)


def _ecdf_panel(ax: plt.Axes, values: list[float], line: float, unit: str, what: str) -> None:
    if not values:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)
        ax.set_title(what)
        return
    v = np.array(values)
    share = np.arange(1, len(v) + 1) / len(v) * 100.0
    ax.step(np.concatenate([[v[0]], v]), np.concatenate([[0.0], share]), where="post")
    within = float(np.mean(v <= line) * 100.0)
    ax.axvline(line, color="red", ls="--", lw=1, label=f"{line:g} {unit}: {within:.1f} % within")
    if v[0] > 0 and v[-1] / v[0] > 100.0:
        ax.set_xscale("log")
    ax.set_ylim(0, 102)
    ax.set_xlabel(f"{what} ({unit})")
    ax.set_ylabel("episodes (%, cumulative)")
    ax.set_title(f"{what}: {len(v)} episodes, max {v[-1]:.3g} {unit}")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, lw=0.3, alpha=0.6)


def error_plot(position_cm: list[float], heading_deg: list[float]) -> bytes:
    """A PNG of two ECDF panels: the worst checkpoint position error per episode (cm,
    2 cm line) and the worst heading error (degrees, 0.5° line)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), dpi=100)
    _ecdf_panel(axes[0], position_cm, POSITION_LINE_M * 100.0, "cm", "worst position error")
    _ecdf_panel(axes[1], heading_deg, HEADING_LINE_DEG, "deg", "worst heading error")
    return _png(fig)


# -- rerunning an episode ----------------------------------------------------------------------
@dataclass(frozen=True)
class Reruns:
    """What the commands that rerun an episode need: the campaign file as recorded, the
    seed to pass (None when it is the file's own), and each base scenario's mission file
    (known when the campaign file could be loaded)."""

    campaign_file: str
    campaign_id: str
    seed: int | None
    missions: dict[str, str]
    note: str = ""
    """Why the commands may not reproduce the episodes, or '' when they will."""

    def commands(self, episode: int, scenario: object) -> str:
        """The two shell commands: export episode's scenario, then dry-run it."""
        mission = self.missions.get(str(scenario))
        if mission is None and len(set(self.missions.values())) == 1:
            mission = next(iter(self.missions.values()))
        name = f"{re.sub(r'[^A-Za-z0-9_.-]', '_', self.campaign_id)}-episode-{episode}.xml"
        if mission is None:
            mission, target = "MISSION.xml", f"MISSION_DIR/scenarios/{name}"
        else:
            target = (Path(mission).parent / "scenarios" / name).as_posix()
        seed = [] if self.seed is None else ["--seed", str(self.seed)]
        export = ["walkaround", "campaign", self.campaign_file, *seed]
        export += ["--episode", str(episode), "--export-scenario", target]
        rerun = ["walkaround", "dry-run", mission, "--scenario", target]
        return f"{shlex.join(export)}\n{shlex.join(rerun)}"


def reruns(summary: Mapping[str, object]) -> Reruns:
    """The rerun commands' ingredients: the campaign file of ``summary`` is loaded (when it
    still can be) for its missions, its own seed and its digest."""
    from executive.campaign.spec import load_campaign

    file = str(summary.get("file") or "CAMPAIGN.xml")
    ident = str(summary.get("campaign") or "campaign")
    seed = summary.get("seed")
    seed = seed if isinstance(seed, int) and not isinstance(seed, bool) else None
    try:
        campaign = load_campaign(file)
    except Exception as exc:  # a moved or changed file must not cost the report
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        note = (
            f"The campaign file {file} could not be loaded here ({detail}): MISSION.xml "
            "and MISSION_DIR stand for the mission file and its folder; the exported "
            "scenario must lie beside the mission's scenarios. Relative paths are as "
            "recorded, relative to the folder the campaign ran in."
        )
        return Reruns(file, ident, seed, {}, note)
    missions = {b.scenario.id: b.scenario.mission.source for b in campaign.scenarios}
    note = ""
    if summary.get("digest") and campaign.digest != summary.get("digest"):
        note = (
            f"The campaign file {file} or one of its scenario files changed since this run "
            f"(digest now {campaign.digest}): the commands draw other episodes than these."
        )
    own_seed = None if seed == campaign.seed else seed
    return Reruns(file, ident, own_seed, missions, note)


# -- the page ----------------------------------------------------------------------------------
def _e(value: object) -> str:
    return html.escape(str(value), quote=True)


def _known(value: object) -> str:
    """An id, or a dash for the None of an episode that crashed before its draw."""
    return "\u2013" if value in (None, "None") else str(value)


def _pct(rate: object) -> str:
    value = _number(rate)
    return "\u2013" if value is None else f"{value * 100:.1f} %"


def _ci(ci: object) -> str:
    if not isinstance(ci, list | tuple) or len(ci) != 2:
        return "\u2013"
    return f"{_pct(ci[0])} \u2013 {_pct(ci[1])}"


def _fmt(value: object, scale: float = 1.0, digits: int = 2, unit: str = "") -> str:
    number = _number(value)
    if number is None:
        return "\u2013"
    return f"{number * scale:.{digits}f}{unit}"


def _table(head: list[str], body: list[list[str]], numeric: Iterable[int] = ()) -> str:
    """A table; ``body`` cells are HTML already (escaped by the caller)."""
    nums = set(numeric)
    out = ["<table>", "<tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>"]
    for cells in body:
        tds = (
            f'<td class="num">{c}</td>' if i in nums else f"<td>{c}</td>"
            for i, c in enumerate(cells)
        )
        out.append("<tr>" + "".join(tds) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _robot_motion(collision: Mapping[str, object]) -> str:
    """How the robot moved at a collision: 'moving at v m/s', 'moving away at v m/s'
    (struck while backing away from the contact) or 'standing still'."""
    speed = collision.get("robot_speed")
    if not isinstance(speed, int | float):
        return "-"  # a row from before the speed was recorded
    if not collision.get("robot_moving"):
        return "standing still"
    closing = collision.get("robot_closing")
    if isinstance(closing, int | float) and closing < STILL_SPEED:
        return f"moving away at {speed:.2f} m/s"
    return f"moving at {speed:.2f} m/s"


def _list(items: list[object]) -> str:
    return _e(", ".join(str(i) for i in items))


def _dicts(value: object) -> list[Mapping[str, object]]:
    return [v for v in value if isinstance(v, dict)] if isinstance(value, list) else []


class _Page:
    """The sections of ``report.html`` (module docstring)."""

    def __init__(self, rows: list[Row], summary: Mapping[str, object], rerun: Reruns) -> None:
        self.rows = sorted(rows, key=_episode)
        self.by_episode = {_episode(r): r for r in self.rows}
        self.summary = summary
        self.rerun = rerun

    def rerun_cell(self, episode: object, label: str = "rerun") -> str:
        number = _number(episode)
        if number is None:
            return "\u2013"
        row = self.by_episode.get(int(number), {})
        text = self.rerun.commands(int(number), row.get("scenario"))
        return f"<details><summary>{_e(label)}</summary><pre>{_e(text)}</pre></details>"

    def header(self) -> str:
        s = self.summary
        title = f"Campaign {s.get('campaign') or '?'}"
        outcomes = s.get("outcomes")
        counts = (
            ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
            if isinstance(outcomes, dict) and outcomes
            else "\u2013"
        )
        facts = [
            ("campaign file", s.get("file") or "\u2013"),
            ("seed", s.get("seed")),
            ("digest", s.get("digest") or "\u2013"),
            ("episodes", len(self.rows)),
            ("outcomes", counts),
        ]
        items = "".join(f"<li>{_e(k)}: <code>{_e(v)}</code></li>" for k, v in facts)
        return (
            f"<h1>{_e(title)} — seed {_e(s.get('seed'))}, digest "
            f"<code>{_e(str(s.get('digest') or '?')[:12])}</code></h1>\n<ul>{items}</ul>"
        )

    def success(self) -> str:
        s = self.summary
        overall = (
            f"<p><b>{_e(s.get('successes', 0))} of {_e(s.get('episodes', len(self.rows)))} "
            f"episodes succeeded: {_e(_pct(s.get('success_rate')))}</b> "
            f"(95 % Wilson interval {_e(_ci(s.get('ci95')))}).</p>"
        )
        body = [
            [
                _e(_known(g.get("mission"))),
                _e(_known(g.get("scenario"))),
                _e(g.get("episodes")),
                _e(g.get("successes")),
                _e(_pct(g.get("success_rate"))),
                _e(_ci(g.get("ci95"))),
            ]
            for g in _dicts(s.get("by_scenario"))
        ]
        head = ["mission", "scenario", "episodes", "successes", "success", "95 % interval"]
        return (
            "<h2>Success</h2>\n"
            + overall
            + "\n<h3>Per mission and scenario</h3>\n"
            + _table(head, body, numeric=(2, 3, 4, 5))
        )

    def failures(self) -> str:
        groups = _dicts(self.summary.get("failures_by_cause"))
        if not groups:
            return "<h2>Failures by cause</h2>\n<p>No failures.</p>"
        body = []
        for g in groups:
            listed = g.get("episodes")
            episodes = [e for e in listed if isinstance(e, int)] if isinstance(listed, list) else []
            cause = _e(g.get("example"))
            if g.get("cause") != g.get("example"):
                cause += f'<br><span class="note">grouped as: {_e(g.get("cause"))}</span>'
            commands = "\n\n".join(
                f"# episode {n}\n"
                + self.rerun.commands(n, self.by_episode.get(n, {}).get("scenario"))
                for n in episodes
            )
            body.append(
                [
                    cause,
                    _e(g.get("count")),
                    _list(episodes),
                    f"<details><summary>rerun each</summary><pre>{_e(commands)}</pre></details>",
                ]
            )
        return "<h2>Failures by cause</h2>\n" + _table(
            ["cause (first of the run)", "count", "episodes", "reproduce"], body, numeric=(1,)
        )

    def checkpoints(self) -> str:
        worst = _dicts(self.summary.get("worst_checkpoints"))
        if not worst:
            return "<h2>Worst checkpoints</h2>\n<p>No checkpoint was reached.</p>"
        body = [
            [
                _e(c.get("episode")),
                _e(c.get("scenario")),
                _e(c.get("checkpoint")),
                _e(_fmt(c.get("position_error"), 100.0, 2, " cm")),
                _e(c.get("heading_checkpoint")),
                _e(_fmt(c.get("heading_error_deg"), 1.0, 2, "°")),
                self.rerun_cell(c.get("episode")),
            ]
            for c in worst
        ]
        head = [
            "episode",
            "scenario",
            "checkpoint",
            "position error",
            "worst heading at",
            "heading error",
            "reproduce",
        ]
        return (
            "<h2>Worst checkpoints</h2>\n<p>The episodes whose worst reached checkpoint "
            "missed its pose by the most (ground truth).</p>\n"
            + _table(head, body, numeric=(0, 3, 5))
        )

    def safety(self) -> str:
        collisions = _dicts(self.summary.get("collisions"))
        parts = ["<h2>Collisions</h2>"]
        if collisions:
            body = [
                [
                    _e(c.get("episode")),
                    _e(_fmt(c.get("t"), 1.0, 2, " s")),
                    _e(c.get("with")),
                    _e(c.get("kind")),
                    _e(_robot_motion(c)),
                    self.rerun_cell(c.get("episode")),
                ]
                for c in collisions
            ]
            episodes = sorted({_episode(c) for c in collisions})
            moving = sorted({_episode(c) for c in collisions if c.get("robot_moving", True)})
            parts.append(
                f'<p class="bad">{len(collisions)} collision(s) in {len(episodes)} episode(s): '
                f"{_list(episodes)}; the robot was moving in {len(moving)} of them"
                f"{': ' + _list(moving) if moving else ''} (standing still, it was struck by "
                "a mover that does not avoid it).</p>"
            )
            head = ["episode", "time", "with", "kind", "the robot", "reproduce"]
            parts.append(_table(head, body, (0, 1)))
        else:
            parts.append("<p>No collision.</p>")
        near = _dicts(self.summary.get("near_misses"))
        parts.append("<h2>Near misses</h2>")
        if near:
            body = [
                [
                    _e(n.get("episode")),
                    _e(n.get("near_misses")),
                    _e(_fmt(n.get("min_clearance"), 1.0, 3, " m")),
                    self.rerun_cell(n.get("episode")),
                ]
                for n in near
            ]
            head = ["episode", "near misses", "minimum clearance", "reproduce"]
            parts.append(_table(head, body, (0, 1, 2)))
        else:
            parts.append("<p>No near miss.</p>")
        return "\n".join(parts)

    def crashed(self) -> str:
        crashed = [r for r in self.rows if r.get("outcome") == "crashed"]
        if not crashed:
            return "<h2>Crashed episodes</h2>\n<p>None.</p>"
        parts = ["<h2>Crashed episodes</h2>"]
        for row in crashed:
            n = _episode(row)
            parts.append(
                f"<h3>Episode {_e(n)}</h3>\n<p>{_e(row.get('first_cause'))}</p>\n"
                f"<details><summary>traceback</summary><pre>{_e(row.get('traceback') or '')}"
                f"</pre></details>\n{self.rerun_cell(n)}"
            )
        return "\n".join(parts)

    def plots(self, drawn: Mapping[str, bytes], notes: Mapping[str, str]) -> str:
        parts = ["<h2>Plots</h2>"]
        captions = {
            SPEED_PLOT: "Success against the fastest mover's speed (m/s)",
            COUNT_PLOT: "Success against the number of movers",
            ERROR_PLOT: "Worst checkpoint errors per episode",
        }
        for name, caption in captions.items():
            parts.append(f"<h3>{_e(caption)}</h3>")
            if name in drawn:
                parts.append(f'<p><img src="{_e(name)}" alt="{_e(caption)}"></p>')
            parts.append(notes.get(name, ""))
        return "\n".join(parts)


def _bins_table(bins: list[RateBin], what: str) -> str:
    """The numbers behind a success plot."""
    body = [[_e(b.label), _e(b.n), _e(b.successes), _e(_pct(b.rate)), _e(_ci(b.ci))] for b in bins]
    head = [what, "episodes", "successes", "success", "95 % interval"]
    return _table(head, body, numeric=(1, 2, 3, 4))


def _draw_plots(out: Path, rows: list[Row]) -> tuple[dict[str, bytes], dict[str, str]]:
    """Write the PNGs that have data (removing old ones that have none); return the
    images drawn and the note under each plot."""
    drawn: dict[str, bytes] = {}
    notes: dict[str, str] = {}
    no_draw = sum(_movers(r) is None for r in rows)
    left_out = (
        f'<p class="note">Left out: {no_draw} episode(s) without drawn parameters (crashed '
        "before their draw).</p>"
        if no_draw
        else ""
    )
    if not rows:
        reason = "No plot: no episodes."
        notes = {name: f"<p>{reason}</p>" for name in (SPEED_PLOT, COUNT_PLOT, ERROR_PLOT)}
    else:
        by_speed, by_count = speed_bins(rows), count_bins(rows)
        if any(b.label != NO_MOVERS for b in by_speed):
            width = speed_width(s for s, _ in _mover_speeds(rows))
            png = rate_plot(
                by_speed, f"fastest mover (m/s), bins of {width:g} m/s", "success by mover speed"
            )
            drawn[SPEED_PLOT] = png
            notes[SPEED_PLOT] = _bins_table(by_speed, "fastest mover (m/s)") + left_out
        else:
            notes[SPEED_PLOT] = "<p>No plot: no episode had movers.</p>"
        if any(b.label != "0" for b in by_count):
            drawn[COUNT_PLOT] = rate_plot(by_count, "movers", "success by mover count")
            notes[COUNT_PLOT] = _bins_table(by_count, "movers") + left_out
        else:
            notes[COUNT_PLOT] = "<p>No plot: no episode had movers.</p>"
        position = _worst(rows, "worst_position_error", 100.0)
        heading = _worst(rows, "worst_heading_error_deg", 1.0)
        if position or heading:
            drawn[ERROR_PLOT] = error_plot(position, heading)
            notes[ERROR_PLOT] = (
                f"<p>The worst reached checkpoint of each episode: position error of "
                f"{len(position)} episodes ({_within(position, POSITION_LINE_M * 100.0)} "
                f"within {POSITION_LINE_M * 100:g} cm), heading error of {len(heading)} "
                f"({_within(heading, HEADING_LINE_DEG)} within {HEADING_LINE_DEG:g}°); "
                "episodes that reached no checkpoint are not in it.</p>"
            )
        else:
            notes[ERROR_PLOT] = "<p>No plot: no episode reached a checkpoint.</p>"
    for name in (SPEED_PLOT, COUNT_PLOT, ERROR_PLOT):
        data = drawn.get(name)
        if data is not None:
            write_atomic(out / name, data)
        else:
            (out / name).unlink(missing_ok=True)  # an old plot would belie the page
    return drawn, notes


def _within(values: list[float], line: float) -> str:
    return f"{sum(v <= line for v in values) / len(values) * 100:.1f} %" if values else "\u2013"


def write_report(out: Path, rows: list[Row], summary: Mapping[str, object]) -> Path:
    """Write ``report.html`` and its PNGs into ``out`` (module docstring); returns the
    page's path. ``summary`` is :func:`~executive.campaign.results.summarise` of ``rows``.
    Every file is written whole or not at all; an OSError names the file."""
    out.mkdir(parents=True, exist_ok=True)
    rerun = reruns(summary)
    page = _Page(rows, summary, rerun)
    drawn, notes = _draw_plots(out, rows)
    title = f"Campaign {summary.get('campaign') or '?'} (seed {summary.get('seed')})"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        '<head><meta charset="utf-8">',
        f"<title>{_e(title)}</title>",
        f"<style>{STYLE}</style></head>",
        "<body>",
        page.header(),
    ]
    if not rows:
        parts.append("<p><b>No episodes in this folder yet: nothing to report.</b></p>")
        parts.append(page.plots(drawn, notes))
    else:
        if rerun.note:
            parts.append(f'<p class="note">{_e(rerun.note)}</p>')
        parts += [
            page.success(),
            page.plots(drawn, notes),
            page.failures(),
            page.checkpoints(),
            page.safety(),
            page.crashed(),
        ]
    parts += ["</body>", "</html>", ""]
    path = out / REPORT_FILE
    write_atomic(path, "\n".join(parts).encode("utf-8"))
    return path


def report_from_folder(out: Path) -> Path:
    """Write the report of the results folder ``out`` (``campaign.json`` and
    ``results.jsonl``; the summary is recomputed from the rows, so an interrupted run's
    report is current). Raises InvalidInputError when ``out`` is not a results folder or a
    file of it is unreadable."""
    identity = read_identity(out)
    if identity is None:
        where = SourceLocation(str(out / CAMPAIGN_FILE))
        problem = Problem(where, "not-a-results-folder", f"{out}: no {CAMPAIGN_FILE}")
        raise InvalidInputError([problem])
    rows = read_rows(out / RESULTS_FILE)
    rows.sort(key=_episode)
    return write_report(out, rows, summarise(identity, rows))
