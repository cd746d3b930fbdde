"""The HUD in a real headless Chromium against a live dry-run (issue 15 acceptance).

Debian's ``chromium`` driven by Playwright (``executable_path``: no browser download); the
dry-run runs at real time (``pace=1``) on a thread, the HUD server on another, as
``walkaround dry-run --live`` runs them. Ground truth is sim2d's robot.
"""

from __future__ import annotations

import math
import shutil
import time

import pytest

from executive.hud.live import LiveDryRun
from sim2d.scenario import load_scenario
from tests.conftest import MISSIONS, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("hil")]

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield b
        b.close()


def _pose(live: LiveDryRun) -> tuple[float, float, float]:
    p = live.sim.world.robot_pose
    return p.x, p.y, p.theta


def _moved(live: LiveDryRun, seconds: float) -> float:
    """How far (m) the robot really moved over ``seconds`` of wall time."""
    x0, y0, _ = _pose(live)
    time.sleep(seconds)
    x1, y1, _ = _pose(live)
    return math.hypot(x1 - x0, y1 - y0)


def _click(page, selector: str) -> None:
    page.click(selector)
    time.sleep(0.3)


def test_the_hud_drives_a_live_dry_run(browser, tmp_path):
    scenario = load_scenario(MISSIONS / "lab" / "scenarios" / "clear-apron.xml")
    with LiveDryRun(scenario, tmp_path / "live", pace=1.0, max_time=600.0) as live:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(live.server.url)
        page.wait_for_selector("#link.ok", timeout=10_000)
        page.wait_for_function("hud.tick !== null && hud.scene !== null", timeout=10_000)
        # the robot moves on the HUD and in the world
        t0 = page.evaluate("hud.tick.t")
        pose0 = page.evaluate("hud.tick.pose")
        assert _moved(live, 2.0) > 0.2
        page.wait_for_function(f"hud.tick.t > {t0 + 1.5}", timeout=5_000)
        pose1 = page.evaluate("hud.tick.pose")
        assert math.hypot(pose1["x"] - pose0["x"], pose1["y"] - pose0["y"]) > 0.2
        assert page.inner_text("#control") == "in control"
        # pause stops the robot; resume goes on
        _click(page, "#pause")
        time.sleep(1.0)  # the base decelerates within its limits
        assert _moved(live, 1.0) < 0.01
        _click(page, "#resume")
        assert _moved(live, 2.0) > 0.2
        # take over with the joystick: forward moves the robot; hand back resumes the mission
        _click(page, "#takeover")
        time.sleep(1.0)
        completed = page.evaluate("hud.tick.completed")
        goal = page.evaluate("hud.tick.checkpoint")
        box = page.locator("#joystick").bounding_box()
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(cx, cy)
        page.mouse.down()
        page.mouse.move(cx, cy - box["height"] * 0.3, steps=5)
        wait_until(lambda: live.state(0.0).joystick is not None, 2.0, "the joystick stream")
        x0, y0, th = _pose(live)
        time.sleep(1.5)
        x1, y1, _ = _pose(live)
        ahead = (x1 - x0) * math.cos(th) + (y1 - y0) * math.sin(th)
        assert ahead > 0.1, "the joystick drives the robot forward"
        # the stream stops (the tablet's page dies while the stick is held): the robot
        # stops within 0.5 s of the dead-man time
        page.close()
        t_stop = time.monotonic()
        wait_until(lambda: live.state(0.0).joystick is None, 1.0, "the dead-man")
        wait_until(lambda: _moved(live, 0.1) < 0.002, 2.0, "the robot to stop")
        assert time.monotonic() - t_stop < 0.5 + 0.3 + 0.2  # dead-man + braking + sampling
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(live.server.url)
        page.wait_for_function("hud.you === true && hud.tick !== null", timeout=10_000)
        _click(page, "#handback")
        assert _moved(live, 3.0) > 0.2
        # the mission goes on where it was: nothing completed twice or skipped, the same
        # checkpoint (or, taken over on the approach, the first one) next
        assert page.evaluate("hud.tick.completed")[: len(completed)] == completed
        order = [cp.id for cp in scenario.mission.checkpoints]
        assert page.evaluate("hud.tick.checkpoint") == (goal or order[len(completed)])
        page.screenshot(path=str(tmp_path / "hud.png"))
        assert (tmp_path / "hud.png").stat().st_size > 20_000
        page.close()


def test_a_page_without_the_token_is_refused(browser, tmp_path):
    scenario = load_scenario(MISSIONS / "lab" / "scenarios" / "clear-apron.xml")
    with LiveDryRun(scenario, tmp_path / "live", pace=1.0, max_time=30.0) as live:
        page = browser.new_page()
        response = page.goto(f"http://{live.server.host}:{live.server.port}/")
        assert response.status == 401 and "secret is required" in page.content()
        page.close()
        assert live.server.refused >= 1


def test_a_trapped_robot_asks_and_skip_skips_the_checkpoint(browser, tmp_path):
    """A vehicle parked on CP1: the robot is trapped, the HUD asks (wait, take over,
    skip); "skip" records CP1 completed and skipped in the journal and the mission goes on
    to CP2."""
    from executive.journal import read_journal
    from tests.sim2d_helpers import scenario_file

    mission = load_scenario(MISSIONS / "lab" / "scenarios" / "clear-apron.xml").mission
    cp1 = mission.nominal_placement().pose_to_airport(mission.checkpoints[0].pose)
    body = (
        f'<obstacles><box id="van" kind="vehicle" x="{cp1.x:.2f}" y="{cp1.y:.2f}" '
        'heading-deg="0" length="1.6" width="1.6" height="1.8"/></obstacles>'
    )
    scenario = load_scenario(
        scenario_file(tmp_path, body, mission_type="lab", mission="visual-servoing.xml")
    )
    out = tmp_path / "live"
    with LiveDryRun(scenario, out, pace=6.0, trapped_after=8.0, max_time=400.0) as live:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(live.server.url)
        page.wait_for_selector("#question:not([hidden])", timeout=90_000)
        assert "CP1" in page.inner_text("#question-text")
        assert "trapped" in page.inner_text("#question-text")
        assert live.sim.time > 8.0
        page.click("#question-choices button[data-choice='skip']")
        page.wait_for_function("hud.tick.completed.includes('CP1')", timeout=20_000)
        page.wait_for_function("hud.tick.checkpoint === 'CP2'", timeout=20_000)
        assert page.is_hidden("#question")
        page.close()
    journal = read_journal(out / "journal.jsonl")
    assert journal.progress.completed[0] == "CP1" and journal.progress.skipped == ("CP1",)
    assert not any(r.checkpoint == "CP1" for r in journal.progress.results)
