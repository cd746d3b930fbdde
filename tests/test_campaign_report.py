"""The campaign report (issue 16, deliverable 3): report.html with its PNGs, failures by
cause with the commands that rerun each episode, escaped text from the runs, Wilson
error bars per bin, and a page for a folder without episodes."""

import html
import json
import random
import re
from pathlib import Path

import pytest
from matplotlib import image as mpimg

from executive.campaign.report import (
    COUNT_PLOT,
    ERROR_PLOT,
    NO_MOVERS,
    REPORT_FILE,
    SPEED_PLOT,
    count_bins,
    report_from_folder,
    speed_bins,
    write_report,
)
from executive.campaign.results import (
    CAMPAIGN_FILE,
    RESULTS_FILE,
    summarise,
    wilson,
    write_json,
)
from executive.campaign.runner import identity, run_campaign
from executive.campaign.spec import load_campaign
from executive.core.problems import InvalidInputError
from tests.conftest import MISSIONS

CAMPAIGN = MISSIONS / "campaigns" / "avoidance-leg.xml"
MISSION = "track-avoidance-leg"
HOSTILE = '<script>alert("x")</script> & co'
CRASH = "crashed: ValueError: bad <b>value</b> & more"


def _rows(n: int = 36, seed: int = 3) -> list[dict]:
    """Synthetic rows: varied movers and speeds, two hostile failure causes (numbers that
    group), a crashed episode without a draw, a collision and near misses."""
    rng = random.Random(seed)
    rows = []
    for k in range(n):
        movers = k % 3
        speed = round(rng.uniform(0.1, 0.6), 3) if movers else 0.0
        failed = k % 5 == 4
        cause = None
        if failed:
            cause = (
                f"timeout at {rng.uniform(10, 99):.1f} s: {HOSTILE}"
                if k % 2
                else f"CP03 missed by {rng.uniform(3, 9):.1f} cm & <stuck>"
            )
        rows.append(
            {
                "episode": k,
                "campaign": "avoidance-leg",
                "mission": MISSION,
                "scenario": MISSION,
                "outcome": "timeout" if failed else "succeeded",
                "succeeded": not failed,
                "first_cause": cause,
                "causes": [cause] if cause else [],
                "drawn": {"movers": movers, "mover_max_speed": speed, "clutter": 0},
                "worst_position_error": round(rng.uniform(0.001, 0.04), 4),
                "worst_position_checkpoint": "CP01",
                "worst_heading_error_deg": round(rng.uniform(0.01, 1.5), 3),
                "worst_heading_checkpoint": "CP01",
                "collisions": (
                    [{"t": 7.25, "with": "<img src=x onerror=alert(1)>", "kind": "person"}]
                    if k == 7
                    else [
                        {
                            "t": 3.5,
                            "with": "mover-1",
                            "kind": "trolley",
                            "robot_speed": 0.002,
                            "robot_moving": False,
                        }
                    ]
                    if k == 9
                    else []
                ),
                "near_misses": 2 if k in (2, 11) else 0,
                "min_clearance": 0.35 if k in (2, 11) else 1.2,
            }
        )
    rows.append(
        {
            "episode": n,
            "campaign": "avoidance-leg",
            "outcome": "crashed",
            "succeeded": False,
            "first_cause": CRASH,
            "causes": [],
            "traceback": 'Traceback (most recent call last):\n  File "<string>", line 1, in '
            "<module>\nValueError: bad <b>value</b> & more\n",
        }
    )
    return rows


@pytest.fixture(scope="module")
def ident() -> dict:
    return identity(load_campaign(CAMPAIGN))


def _row_of(page: str, needle: str) -> str:
    """The table row of ``page`` that holds ``needle``."""
    at = page.index(needle)
    return page[page.rindex("<tr>", 0, at) : page.index("</tr>", at)]


def _images(page: str, folder: Path) -> list[str]:
    names = re.findall(r'<img src="([^"]+)"', page)
    for name in names:
        path = folder / name
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        pixels = mpimg.imread(path)
        assert pixels.ndim == 3 and pixels.shape[0] > 100 and pixels.shape[1] > 100, name
    return names


def test_report_lists_causes_escapes_and_links_real_plots(tmp_path, ident):
    rows = _rows()
    summary = summarise(ident, rows)
    path = write_report(tmp_path, rows, summary)
    assert path == tmp_path / REPORT_FILE
    page = path.read_text(encoding="utf-8")

    assert f"<title>Campaign avoidance-leg (seed {ident['seed']})</title>" in page
    assert ident["digest"] in page and str(ident["file"]) in page
    assert f"{summary['successes']} of {len(rows)} episodes succeeded" in page

    # every cause group, with its count, its episodes and the commands that rerun them
    groups = summary["failures_by_cause"]
    assert len(groups) == 3  # timeouts, CP03 misses, the crash: numbers folded
    assert sum(g["count"] for g in groups) == sum(not r["succeeded"] for r in rows)
    for group in groups:
        row = _row_of(page, html.escape(group["example"]))
        assert f'<td class="num">{group["count"]}</td>' in row
        assert f"<td>{', '.join(map(str, group['episodes']))}</td>" in row
        for episode in group["episodes"]:
            assert (
                f"walkaround campaign {ident['file']} --episode {episode} --export-scenario "
                f"missions/track/scenarios/avoidance-leg-episode-{episode}.xml" in row
            )
            assert (
                "walkaround dry-run missions/track/avoidance-leg.xml --scenario "
                f"missions/track/scenarios/avoidance-leg-episode-{episode}.xml" in row
            )

    # nothing from the runs is markup; the page runs no script and fetches nothing
    for hostile in (HOSTILE, CRASH, "<img src=x onerror", "<b>value</b>", "<module>"):
        assert hostile not in page
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; co" in page
    assert "&lt;img src=x onerror=alert(1)&gt;" in page
    assert "<script" not in page and "http:" not in page and "https:" not in page

    # the crash's traceback folded, the collision and the near misses with their episodes
    assert re.search(
        r"<details><summary>traceback</summary><pre>Traceback[^<]*&lt;module&gt;", page
    )
    collision = _row_of(page, "&lt;img src=x onerror=alert(1)&gt;")
    assert '<td class="num">7</td>' in collision and "--episode 7 " in collision
    assert "<td>-</td>" in collision  # a row from before the robot's speed was kept
    struck = _row_of(page, "mover-1")
    assert "standing still" in struck and "--episode 9 " in struck
    assert "the robot was moving in 1 of them: 7 " in page
    for episode in (2, 11):
        near = _row_of(page, f'<tr><td class="num">{episode}</td><td class="num">2</td>')
        assert "0.350 m" in near and f"--episode {episode} " in near
    worst = max(rows[:-1], key=lambda r: r["worst_position_error"])
    assert f"{worst['worst_position_error'] * 100:.2f} cm" in page

    # the three plots exist, decode, and are the ones linked
    assert sorted(_images(page, tmp_path)) == sorted([SPEED_PLOT, COUNT_PLOT, ERROR_PLOT])


def test_wilson_bars_per_bin():
    rows = _rows()
    by_speed = speed_bins(rows)
    assert by_speed[0].label == NO_MOVERS
    drawn = [r for r in rows if "drawn" in r]
    assert sorted(by_speed[0].episodes) == [r["episode"] for r in drawn if not r["drawn"]["movers"]]
    assert sum(b.n for b in by_speed) == len(drawn)  # the crash before its draw is left out
    for b in by_speed[1:]:
        low, high = (float(x) for x in b.label.split("\u2013"))
        members = [
            r for r in drawn if r["drawn"]["movers"] and low <= r["drawn"]["mover_max_speed"] < high
        ]
        assert sorted(b.episodes) == [r["episode"] for r in members]
        k = sum(r["succeeded"] for r in members)
        assert b.successes == k and b.ci == wilson(k, len(members))
        below, above = b.error_bar()
        assert below == pytest.approx(k / len(members) - wilson(k, len(members))[0])
        assert above == pytest.approx(wilson(k, len(members))[1] - k / len(members))
    assert len(by_speed) > 3
    by_count = count_bins(rows)
    assert [b.label for b in by_count] == ["0", "1", "2"]
    for b in by_count:
        members = [r for r in drawn if r["drawn"]["movers"] == int(b.label)]
        k = sum(r["succeeded"] for r in members)
        assert b.n == len(members) and b.ci == wilson(k, len(members))


def test_plots_without_data_are_skipped_and_said(tmp_path, ident):
    rows = [
        r | {"drawn": {"movers": 0, "mover_max_speed": 0.0}, "worst_position_error": None}
        for r in _rows(12)[:-1]
    ]
    rows = [r | {"worst_heading_error_deg": None} for r in rows]
    (tmp_path / SPEED_PLOT).write_bytes(b"stale")
    page = write_report(tmp_path, rows, summarise(ident, rows)).read_text(encoding="utf-8")
    assert "<img" not in page
    assert page.count("No plot: no episode had movers.") == 2
    assert "No plot: no episode reached a checkpoint." in page
    assert not any((tmp_path / n).exists() for n in (SPEED_PLOT, COUNT_PLOT, ERROR_PLOT))


def test_a_folder_without_episodes_still_gets_a_page(tmp_path, ident):
    write_json(tmp_path / CAMPAIGN_FILE, ident | {"shard": None})
    (tmp_path / RESULTS_FILE).write_text("")
    (tmp_path / ERROR_PLOT).write_bytes(b"stale")
    page = report_from_folder(tmp_path).read_text(encoding="utf-8")
    assert "No episodes in this folder yet" in page
    assert "No plot: no episodes." in page and "<img" not in page
    assert not (tmp_path / ERROR_PLOT).exists()
    with pytest.raises(InvalidInputError, match=r"no campaign\.json"):
        report_from_folder(tmp_path / "nothing")


def test_report_from_folder_reads_the_rows(tmp_path, ident):
    rows = _rows(9)
    write_json(tmp_path / CAMPAIGN_FILE, ident | {"shard": None})
    (tmp_path / RESULTS_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    page = report_from_folder(tmp_path).read_text(encoding="utf-8")
    assert f"{sum(r['succeeded'] for r in rows)} of {len(rows)} episodes succeeded" in page
    assert sorted(_images(page, tmp_path)) == sorted([SPEED_PLOT, COUNT_PLOT, ERROR_PLOT])


def test_end_to_end_two_short_episodes(tmp_path):
    out = tmp_path / "out"
    rows = run_campaign(load_campaign(CAMPAIGN), out, 2, max_time=2.0)
    page = report_from_folder(out).read_text(encoding="utf-8")
    assert "Campaign avoidance-leg" in page and f"of {len(rows)} episodes succeeded" in page
    _images(page, out)
    for row in rows:
        if not row["succeeded"]:
            assert f"--episode {row['episode']} --export-scenario" in page


def test_rerun_commands_name_the_seed_and_survive_a_missing_campaign_file(tmp_path, ident):
    rows = _rows(6)
    page = write_report(tmp_path, rows, summarise(ident | {"seed": 99}, rows)).read_text()
    assert f"walkaround campaign {ident['file']} --seed 99 --episode 4 --export-scenario" in page
    gone = ident | {"file": str(tmp_path / "moved.xml")}
    page = write_report(tmp_path, rows, summarise(gone, rows)).read_text()
    assert "could not be loaded here" in page
    assert (
        "--episode 4 --export-scenario MISSION_DIR/scenarios/avoidance-leg-episode-4.xml\n"
        "walkaround dry-run MISSION.xml --scenario" in page
    )
